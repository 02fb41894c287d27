"""Issue [import-real]: descriptions written the way current packages write them, end to end.

Each test imports a variant of the ``arm3`` fixture (tests/importers/robots/arm3) and then does what a user does:
``hild check`` (the config must pass without warnings about the importer's own choices), run it in lockstep, hold,
and a trajectory goal that must succeed with *every* joint within its goal tolerance — a joint jammed by a contact
or faulted by a limit fails the test even when the goal reports success.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hild.config import load_config
from hild.config.stop_review import check_with_model
from hild.engine import Engine
from hild.importers.ros2_control.importer import ImportResult
from hild.importers.ros2_control.report import ImportFailure
from tests.importers.helpers import MY_ARM, ROBOTS, import_robot, lockstep, run_goal, waypoints

ARM3 = ROBOTS / "arm3"
XACRO = ARM3 / "urdf" / "arm3.urdf.xacro"
SPLIT = [ARM3 / "config" / "arm3_controllers.yaml", ARM3 / "config" / "update_rate.yaml"]
CLASSIC = ARM3 / "config" / "arm3_classic.yaml"
JOINTS = ["pan", "shoulder", "elbow"]
MOVE = [[0.5, 0.4, -0.5], [-0.4, -0.3, 0.4]]


def checked(result: ImportResult) -> list[str]:
    """What `hild check` prints beyond the summary: its warnings."""
    loaded = load_config(result.config)
    check_with_model(loaded)
    return [n for n in loaded.notes if n.startswith("warning")]


def hold_then_move(result: ImportResult, joints: list[str], offsets: list[list[float]] = MOVE) -> Engine:
    """Lockstep: one second of hold (nothing moves, nothing faults), then a trajectory through start + offsets that
    must succeed with every joint within its goal tolerance of the last point."""
    engine = lockstep(result.config)
    start = engine.state.position.copy()
    engine.run_cycles(int(engine.update_rate))
    status = engine.status()
    assert status["mode"] == "hold", status
    np.testing.assert_allclose(engine.state.position, start, atol=5e-3)
    cols = [engine.joints.index(j) for j in joints]
    origin = engine.state.position[cols].copy()
    controller = next(n for n, c in engine.loaded.config.controllers.items() if c.type == "joint_trajectory")
    outcome = run_goal(engine, controller, waypoints(joints, origin, offsets))
    assert outcome.status == "succeeded", outcome
    tolerances = goal_tolerances(engine, controller, joints)
    error = np.abs(engine.state.position[cols] - (origin + np.asarray(offsets[-1])))
    assert (error <= tolerances).all(), f"joints off their goal: {dict(zip(joints, error.round(4), strict=True))}"
    assert engine.status()["mode"] != "fault", engine.status()
    return engine


def goal_tolerances(engine: Engine, controller: str, joints: list[str]) -> np.ndarray:
    constraints: dict[str, Any] = engine.loaded.config.controllers[controller].params.get("constraints", {})
    per_joint = constraints.get("joints", {})
    return np.array([per_joint.get(j, {}).get("goal", 0.02) or 0.02 for j in joints])


# ---- cause 1, 2, 6: the Jazzy layout, launch arguments, split files ----------------------------------------------
def test_jazzy_layout_split_over_two_files_with_a_prefix_argument(tmp_path: Path) -> None:
    result = import_robot(XACRO, SPLIT, tmp_path / "arm3.yaml", args={"prefix": "left_"})
    cfg = load_config(result.config).config
    assert list(cfg.joints) == ["left_pan", "left_shoulder", "left_elbow"]
    assert cfg.update_rate == 250  # from update_rate.yaml, the second file
    assert {n: c.type for n, c in cfg.controllers.items()} == {
        "joint_state_broadcaster": "joint_state_broadcaster",
        "arm_controller": "joint_trajectory",
        "forward_position_controller": "forward_command",
    }
    assert cfg.controllers["arm_controller"].params["joints"] == ["left_pan", "left_shoulder", "left_elbow"]
    assert cfg.controllers["arm_controller"].params["constraints"]["joints"]["left_elbow"]["goal"] == 0.02
    assert result.report.partial == []
    hold_then_move(result, ["left_pan", "left_shoulder", "left_elbow"])


def test_an_empty_prefix_is_a_value(tmp_path: Path) -> None:
    result = import_robot(XACRO, SPLIT, tmp_path / "arm3.yaml", args={"prefix": ""})
    assert list(load_config(result.config).config.joints) == JOINTS


def test_a_launch_argument_left_without_a_value_stops_the_import(tmp_path: Path) -> None:
    with pytest.raises(ImportFailure) as info:
        import_robot(XACRO, SPLIT, tmp_path / "arm3.yaml")
    line = next(i for i, text in enumerate(SPLIT[0].read_text().splitlines(), 1) if "$(var prefix)" in text)
    assert str(info.value) == (
        f"{SPLIT[0]}:{line}: $(var prefix) has no value: pass --arg prefix=VALUE (the launch file's argument)"
    )
    assert not (tmp_path / "arm3.yaml").exists()


def test_the_controller_file_alone_uses_the_default_rate_and_says_so(tmp_path: Path) -> None:
    result = import_robot(XACRO, SPLIT[:1], tmp_path / "arm3.yaml", args={"prefix": ""})
    assert load_config(result.config).config.update_rate == 100
    assert any("no update_rate in any file" in f.text for f in result.report.of("approximated"))


def test_a_controller_hild_cannot_map_makes_the_import_fail_unless_partial_is_accepted(tmp_path: Path) -> None:
    kwargs: dict[str, Any] = {"package_roots": {"my_arm_description": MY_ARM}}
    urdf, controllers = MY_ARM / "urdf" / "my_arm.urdf.xacro", MY_ARM / "config" / "my_arm_controllers.yaml"
    with pytest.raises(ImportFailure) as info:
        import_robot(urdf, controllers, tmp_path / "arm.yaml", **kwargs)
    message = str(info.value)
    line = next(i for i, t in enumerate(controllers.read_text().splitlines(), 1) if "AdmittanceController" in t)
    assert f"{controllers}:{line}: controller 'admittance_controller': type " in message
    assert message.endswith("pass --allow-partial to import the rest without them")
    assert not list(tmp_path.iterdir())
    result = import_robot(urdf, controllers, tmp_path / "arm.yaml", allow_partial=True, **kwargs)
    assert "admittance_controller" not in load_config(result.config).config.controllers
    assert any(note.startswith("partial import (--allow-partial): 1 left out") for note in result.report.notes)


def test_a_fixed_joint_in_ros2_control_is_a_joint_left_out(tmp_path: Path) -> None:
    text = XACRO.read_text().replace('<xacro:arm_joint name="elbow"', '<xacro:arm_joint name="tool_joint"', 1)
    text = text.replace("$(var prefix)elbow", "$(var prefix)pan")
    urdf = tmp_path / "arm3" / "urdf" / "arm3.urdf.xacro"
    urdf.parent.mkdir(parents=True)
    urdf.write_text(text)
    (tmp_path / "arm3" / "meshes").symlink_to(ARM3 / "meshes")
    controllers = tmp_path / "arm3_classic.yaml"
    controllers.write_text(CLASSIC.read_text().replace("[pan, shoulder, elbow]", "[pan, shoulder]"))
    controllers.write_text(re.sub(r"\n      elbow:.*", "", controllers.read_text()))
    with pytest.raises(ImportFailure, match=r"joint 'tool_joint' is fixed: not a commandable joint"):
        import_robot(urdf, [controllers], tmp_path / "out" / "arm3.yaml")
    result = import_robot(urdf, [controllers], tmp_path / "out" / "arm3.yaml", allow_partial=True)
    assert list(load_config(result.config).config.joints) == ["pan", "shoulder"]
