"""Issue [hands], finding: the importer's gains were not checked against the robot's own dynamics and the YAML's
tolerances — a joint resting further from its target than the goal tolerance allows (friction against a soft
spring), a heavy shoulder lagging past its path tolerance mid-move — and nothing in the report warned.

Now the report's "Tracking" section says it: the static rule (friction / kp against the goal tolerance) raises the
importer's own stiffness within the gain rules or names the tolerance that cannot be met and why, and a short
lockstep run of a full-speed goal of each trajectory controller on the twin says whether it succeeds or which joint
breaks which tolerance by how much. Each description is the test's own (tests/importers/small_arms.py).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from hild.action import ErrorCode
from hild.cli import main
from hild.config import load_config
from hild.importers.ros2_control.importer import ImportResult
from hild.importers.ros2_control.tracking import HOLD_S, REMEDIES, JointTracking, Tracking, simulate
from tests.importers.helpers import import_robot, lockstep, run_goal
from tests.importers.small_arms import Link, write_arm

# ---- friction + a low kp vs a tight goal tolerance -----------------------------------------------------------------
# Light links whose default 5 Hz gains come out at kp 24–43, 1 N·m of friction each, and a YAML demanding 0.01 rad.
FRICTION_ARM = [
    Link("j1", mass=0.4, length=0.25, friction=1.0, effort=20.0, axis="0 0 1"),
    Link("j2", mass=0.3, length=0.25, friction=1.0, effort=20.0, start=0.4),
    Link("j3", mass=0.3, length=0.2, friction=1.0, effort=10.0, start=0.5),
]
TIGHT = {"goal": 0.01, "trajectory": 0.2, "stopped_velocity": 0.05, "goal_time": 1.0}


def tracking(result: ImportResult) -> list[str]:
    return [f.text for f in result.report.of("tracking")]


def test_friction_against_a_tight_goal_tolerance_raises_the_importers_stiffness(tmp_path: Path) -> None:
    urdf, controllers = write_arm(tmp_path / "src", "arm", FRICTION_ARM, "position", ["position", "velocity"], **TIGHT)
    result = import_robot(urdf, controllers, tmp_path / "arm.yaml")
    raised = {
        f.text.split(":")[0]: f.text for f in result.report.of("approximated") if "friction 1 N·m rested" in f.text
    }
    assert set(raised) == {"j1", "j2", "j3"}, raised
    assert "hold kp 43.43 → 200" in raised["j2"] and "0.5 × the goal tolerance 0.01 of arm_controller" in raised["j2"]
    joints = load_config(result.config).config.joints
    assert all(joints[j].hold.kp * 0.01 * 0.5 >= 1.0 for j in ("j1", "j2", "j3"))  # friction / kp ≤ half of 0.01
    assert not [t for t in tracking(result) if "cannot be met" in t]
    [verdict] = tracking(result)
    assert verdict.startswith("arm_controller: a full-speed goal on the twin succeeds: out (j1 ")


def test_a_goal_tolerance_the_gain_rules_cannot_reach_is_reported_with_why(tmp_path: Path) -> None:
    weak = [Link("j1", mass=0.4, length=0.25, friction=1.0, effort=6.0, axis="0 0 1"), *FRICTION_ARM[1:]]
    urdf, controllers = write_arm(tmp_path / "src", "arm", weak, "position", ["position", "velocity"], **TIGHT)
    result = import_robot(urdf, controllers, tmp_path / "arm.yaml")
    [cannot] = [t for t in tracking(result) if "cannot be met" in t]
    found = re.fullmatch(
        r"goal tolerance 0.01 of arm_controller on j1 cannot be met on a real arm: friction 1 N·m against kp "
        r"(?P<kp>[\d.]+) \(the most hild check's gain rules allow with effort limit 6 N·m\) rests up to "
        r"(?P<rest>[\d.]+) rad from the target; loosen it to ≥ (?P<loose>[\d.]+), or raise the effort limit",
        cannot,
    )
    assert found, cannot
    kp = float(found["kp"])
    assert kp == load_config(result.config).config.joints["j1"].hold.kp and kp < 100  # raised only as far as allowed
    assert float(found["rest"]) == pytest.approx(1.0 / kp, rel=1e-2) and float(found["rest"]) > 0.01


def test_a_users_soft_effort_pid_is_reported_never_changed(tmp_path: Path) -> None:
    pid = {j.joint: {"p": 40.0, "d": 1.0} for j in FRICTION_ARM}
    urdf, controllers = write_arm(tmp_path / "src", "arm", FRICTION_ARM, "effort", ["effort"], gains=pid, **TIGHT)
    result = import_robot(urdf, controllers, tmp_path / "arm.yaml")
    cannot = [t for t in tracking(result) if "cannot be met by your gains" in t]
    assert len(cannot) == 3, tracking(result)
    assert "friction 1 N·m against p 40 rests up to 0.025 rad from the target; p ≥ 200" in cannot[0]
    gains = load_config(result.config).config.controllers["arm_controller"].params["gains"]
    assert {j: g["p"] for j, g in gains.items()} == {"j1": 40, "j2": 40, "j3": 40}


# ---- a heavy shoulder vs the path tolerance ----------------------------------------------------------------------
# A 4 kg upper arm carrying a 2 kg forearm on a 34 N·m shoulder: its gains are capped at 0.7 Hz by the effort limit,
# and at full speed it lags past the YAML's path tolerance of 0.2 rad.
HEAVY_ARM = [
    Link("pan", mass=2.0, length=0.2, effort=80.0, axis="0 0 1"),
    Link("shoulder", mass=4.0, length=0.5, effort=34.0, start=0.3),
    Link("elbow", mass=2.0, length=0.4, effort=40.0, start=0.6),
    Link("wrist", mass=0.5, length=0.1, effort=10.0),
]
PATH = {"goal": 0.02, "trajectory": 0.2, "stopped_velocity": 0.05, "goal_time": 1.0}


def test_a_heavy_shoulder_lagging_past_its_path_tolerance_is_reported_and_the_goal_really_aborts(
    tmp_path: Path,
) -> None:
    urdf, controllers = write_arm(tmp_path / "src", "arm", HEAVY_ARM, "position", ["position", "velocity"], **PATH)
    result = import_robot(urdf, controllers, tmp_path / "arm.yaml")
    assert (
        "tracking check: arm_controller would abort a full-speed goal on the twin (see Tracking)" in result.report.notes
    )
    aborts, remedy = tracking(result)
    found = re.fullmatch(
        r"arm_controller: a full-speed goal on the twin would abort: path tolerance on shoulder: lags "
        r"(?P<lag>[\d.]+) rad > 0.2 \(by [\d.]+\) [\d.]+ s into the move",
        aborts,
    )
    assert found, aborts
    assert 0.2 < float(found["lag"]) < 0.3
    assert remedy == f"arm_controller: {REMEDIES}"

    # The prediction holds: the same goal, with the controller's own tolerances, aborts on the shoulder's path.
    run = simulate(result.config, "arm_controller")
    engine = lockstep(result.config)
    engine.run_cycles(round(HOLD_S * engine.update_rate))  # as the check holds first
    start = engine.state.position.copy()
    out = start + np.array([j.offset for j in run.joints])
    goal = {"trajectory": {"joint_names": [j.joint for j in HEAVY_ARM], "points": [{"positions": out.tolist()}]}}
    goal["trajectory"]["points"].append({"positions": start.tolist()})
    outcome = run_goal(engine, "arm_controller", goal)
    assert outcome.status == "aborted" and outcome.error_code == ErrorCode.PATH_TOLERANCE_VIOLATED, outcome
    assert "path tolerance violated on shoulder" in outcome.error_string


def test_the_tracking_check_can_be_skipped(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    urdf, controllers = write_arm(tmp_path / "src", "arm", HEAVY_ARM, "position", ["position", "velocity"], **PATH)
    argv = ["import", "ros2-control", "--urdf", str(urdf), "--controllers", str(controllers), "-o"]
    assert main([*argv, str(tmp_path / "arm.yaml"), "--no-tracking-check"]) == 0
    out = capsys.readouterr().out
    assert "Tracking (1):" in out and "not simulated (--no-tracking-check)" in out and "would abort" not in out
    assert main([*argv, str(tmp_path / "checked.yaml")]) == 0
    assert "path tolerance on shoulder" in capsys.readouterr().out


def test_a_joint_still_moving_goal_time_after_the_end_is_named_with_its_speed() -> None:
    """The 7-DoF style: the path is fine, but one joint still creeps when goal_time runs out."""
    creeping = JointTracking("joint_1", 0.9, 0.05, 1.1, 0.2, 0.004, 0.08, 0.02, 0.05, 0.004)
    settled = JointTracking("joint_2", 0.9, 0.05, 1.1, 0.2, 0.004, 0.0, 0.02, 0.05, 0.004)
    run = Tracking("arm_controller", 2.4, 1.0, None, (creeping, settled))
    assert run.violations() == [
        "stopped_velocity_tolerance on joint_1 1 s after the end: still moving at 0.08 rad/s > 0.05 (by 0.03)"
    ]
    assert Tracking("arm_controller", 2.4, 1.0, 0.3, (creeping, settled)).violations() == []  # it settled in time
    off = JointTracking("joint_1", 0.9, 0.05, 1.1, 0.2, 0.026, 0.0, 0.01, 0.05, 0.026)
    assert Tracking("arm_controller", 2.4, 1.0, None, (off,)).violations() == [
        "goal tolerance on joint_1 1 s after the end: 0.026 rad from the goal > 0.01 (by 0.016)"
    ]
