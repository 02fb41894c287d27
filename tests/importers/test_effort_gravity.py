"""Issue [hands], finding: an effort-interface trajectory controller sags under gravity on the twin.

A ROS effort JTC is a PID whose robot driver (or simulator) carries the arm's weight; hild's PID alone stopped a
two-link arm 0.03 rad short and reported ``succeeded`` (the YAML gives no goal tolerance). The importer now sets
``gravity_compensation: true`` on every effort JTC, and the supervisor adds the model's gravity torque to the
PID's effort: the goal is reached within 0.005 rad. The same config with it off still stops short.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hild.config import load_config
from hild.controllers.joint_trajectory import JointTrajectoryParams
from hild.cycle.engine import Engine
from hild.importers.ros2_control.importer import GRAVITY_ON_EFFORT
from tests.importers.helpers import import_robot, lockstep, run_goal, waypoints
from tests.importers.small_arms import Link, write_arm

JOINTS = ["shoulder", "elbow"]
# A shoulder carrying an elbow, both swinging in the vertical plane, started leaning forward: gravity loads both.
LINKS = [Link("shoulder", mass=2.0, effort=60.0, start=0.8), Link("elbow", mass=1.0, effort=30.0, start=0.3)]
PID = {"shoulder": {"p": 300.0, "d": 20.0}, "elbow": {"p": 60.0, "d": 1.0}}  # P-D only: nothing integrates the sag
MOVE = [0.3, 0.4]


def imported(tmp_path: Path) -> Path:
    urdf, controllers = write_arm(tmp_path / "src", "arm", LINKS, "effort", ["effort"], gains=PID)
    result = import_robot(urdf, controllers, tmp_path / "arm.yaml")
    texts = [f.text for f in result.report.findings]
    assert f"arm_controller: {GRAVITY_ON_EFFORT}" in texts
    assert "real arm's driver" in GRAVITY_ON_EFFORT and "robot.model" in GRAVITY_ON_EFFORT
    return result.config


def move(engine: Engine) -> tuple[str, np.ndarray]:
    """Hold 1 s, run the move, settle 1 s: the result and each joint's error from the goal."""
    engine.run_cycles(int(engine.update_rate))
    start = engine.state.position.copy()
    result = run_goal(engine, "arm_controller", waypoints(JOINTS, start, [MOVE]))
    engine.run_cycles(int(engine.update_rate))
    return str(result.status), engine.state.position - (start + np.asarray(MOVE))


def test_an_imported_effort_jtc_reaches_its_goal_with_the_models_gravity_on_top(tmp_path: Path) -> None:
    config = imported(tmp_path)
    params = load_config(config).config.controllers["arm_controller"].params
    assert params["command_interfaces"] == ["effort"] and params["gravity_compensation"] is True
    status, error = move(lockstep(config))
    assert status == "succeeded"
    assert (np.abs(error) < 0.005).all(), error


def test_without_gravity_on_top_the_pid_alone_stops_short_and_still_reports_success(tmp_path: Path) -> None:
    config = imported(tmp_path)
    config.write_text(config.read_text().replace("gravity_compensation: true", "gravity_compensation: false"))
    status, error = move(lockstep(config))
    assert status == "succeeded"  # no goal tolerance in the YAML: the sag goes unnoticed
    assert (np.abs(error) > 0.02).all(), error  # gravity / p: ≈ 0.03 rad on both joints


def test_gravity_compensation_is_for_the_effort_interface_only() -> None:
    base = {"joints": JOINTS, "gravity_compensation": True}
    with pytest.raises(ValueError, match="gravity_compensation is for the effort interface"):
        JointTrajectoryParams.model_validate({**base, "command_interfaces": ["position", "velocity"]})
    params = JointTrajectoryParams.model_validate({**base, "command_interfaces": ["effort"], "gains": PID})
    assert (
        params.gravity_compensation
        and not JointTrajectoryParams.model_validate({"joints": JOINTS}).gravity_compensation
    )
