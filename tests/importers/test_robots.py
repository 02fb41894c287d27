"""The three fixture robots end to end: import → `hild check` passes → lockstep engine → a trajectory succeeds."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from hild.config import load_config
from hild.cycle.engine import Engine
from tests.importers.helpers import ARM2, MY_ARM, RRBOT, import_robot, lockstep, run_goal, waypoints

ARM_JOINTS = ["shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3"]


def track(engine: Engine, controller: str, joints: list[str], offsets: list[list[float]]) -> np.ndarray:
    """Run an untimed trajectory through start + offsets (ending at start); return the largest excursion seen."""
    cols = [engine.joints.index(j) for j in joints]
    start = engine.state.position[cols].copy()
    result = run_goal(engine, controller, waypoints(joints, start, offsets))
    assert result.status == "succeeded", result
    np.testing.assert_allclose(engine.state.position[cols], start + np.asarray(offsets[-1]), atol=0.05)
    return start


def test_rrbot_effort_pid_trajectory_succeeds_on_the_twin(tmp_path: Path) -> None:
    result = import_robot(RRBOT / "rrbot.urdf", RRBOT / "rrbot_controllers.yaml", tmp_path / "rrbot.yaml")
    loaded = load_config(result.config)  # what `hild check` does
    cfg = loaded.config
    assert list(cfg.joints) == ["joint1", "joint2"]
    assert cfg.update_rate == 500
    assert cfg.hardware["twin"].driver == "mujoco"
    jtc = cfg.controllers["joint_trajectory_controller"]
    assert jtc.type == "joint_trajectory" and jtc.params["command_interfaces"] == ["effort"]
    assert jtc.params["gains"]["joint1"] == {"p": 400, "i": 50, "d": 60, "i_clamp": 15}
    assert (cfg.joints["joint1"].hold.kp, cfg.joints["joint1"].hold.kd) == (400, 60)  # from the effort PID
    assert cfg.joints["joint2"].limits.effort == 20  # the <command_interface> max is tighter than <limit effort>
    assert cfg.controllers["joint_state_broadcaster"].autostart
    assert not cfg.controllers["effort_controller"].autostart
    assert cfg.controllers["effort_controller"].params == {"joints": ["joint1", "joint2"], "interface": "effort"}

    engine = lockstep(result.config)
    engine.run_cycles(250)  # held upright (an unstable equilibrium) by the imported hold gains
    np.testing.assert_allclose(engine.state.position, [0.0, 0.0], atol=1e-3)
    track(engine, "joint_trajectory_controller", ["joint1", "joint2"], [[0.4, -0.5], [-0.3, 0.4], [0.0, 0.0]])


def test_rrbot_legacy_joint_position_controller_moves_its_joint(tmp_path: Path) -> None:
    result = import_robot(RRBOT / "rrbot.urdf", RRBOT / "rrbot_controllers.yaml", tmp_path / "rrbot.yaml")
    engine = lockstep(result.config)
    outcome = run_goal(engine, "joint1_position_controller", {"positions": [0.3]})
    assert outcome.status == "succeeded", outcome
    assert engine.state.position[0] == pytest.approx(0.3, abs=0.05)


@pytest.mark.parametrize("variant", ["gz", "mock"])
def test_arm2_position_trajectory_succeeds_from_its_initial_values(tmp_path: Path, variant: str) -> None:
    result = import_robot(ARM2 / f"arm2_{variant}.urdf", ARM2 / "arm2_controllers.yaml", tmp_path / "arm2.yaml")
    cfg = load_config(result.config).config
    assert cfg.hardware["twin"].params["initial_positions"] == {"shoulder": 0.3, "elbow": -0.6}
    assert cfg.joints["shoulder"].limits.soft_margin == pytest.approx(0.1)  # the tighter side of soft limits
    assert cfg.joints["elbow"].limits.soft_margin == pytest.approx(0.05)
    constraints = cfg.controllers["joint_trajectory_controller"].params["constraints"]
    assert constraints["goal_time"] == 0.6 and constraints["joints"]["elbow"] == {"trajectory": 0.2, "goal": 0.02}
    assert cfg.controllers["forward_position_controller"].params["interface"] == "position"

    engine = lockstep(result.config)
    engine.run_cycles(100)
    np.testing.assert_allclose(engine.state.position, [0.3, -0.6], atol=2e-3)  # starts at initial_value, holds
    track(engine, "joint_trajectory_controller", ["shoulder", "elbow"], [[0.5, -0.5], [-0.3, 0.8], [0.0, 0.0]])


def test_arm2_variants_differ_only_in_what_the_report_says_about_the_plugin(tmp_path: Path) -> None:
    gz = import_robot(ARM2 / "arm2_gz.urdf", ARM2 / "arm2_controllers.yaml", tmp_path / "gz" / "arm2.yaml")
    mock = import_robot(ARM2 / "arm2_mock.urdf", ARM2 / "arm2_controllers.yaml", tmp_path / "mock" / "arm2.yaml")
    strip = lambda text: re.sub(r"#.*", "", text)  # noqa: E731 - comments name the source files
    assert yaml.safe_load(strip(gz.config.read_text())) == yaml.safe_load(strip(mock.config.read_text()))
    assert any("gz_ros2_control/GazeboSimSystem" in f.text for f in gz.report.of("mapped"))
    assert any("mock_components/GenericSystem" in f.text for f in mock.report.of("approximated"))
    assert any("calculate_dynamics" in f.text for f in mock.report.of("unsupported"))


def test_my_arm_xacro_trajectory_succeeds_and_the_mimic_finger_follows(tmp_path: Path) -> None:
    result = import_robot(
        MY_ARM / "urdf" / "my_arm.urdf.xacro",
        MY_ARM / "config" / "my_arm_controllers.yaml",
        tmp_path / "my_arm.yaml",
        package_roots={"my_arm_description": MY_ARM},
        allow_partial=True,  # its admittance controller has no hild counterpart
    )
    cfg = load_config(result.config).config
    assert list(cfg.joints) == [*ARM_JOINTS, "gripper_finger_left"]  # the mimic finger is not commanded
    assert "admittance_controller" not in cfg.controllers
    assert cfg.joints["wrist_3"].limits.position.upper == pytest.approx(6.2832)  # continuous: ±1 turn
    urdf = result.urdf.read_text()
    assert "package://" not in urdf and str(MY_ARM / "meshes" / "base.obj") in urdf

    engine = lockstep(result.config)
    engine.run_cycles(250)
    start = engine.state.position.copy()
    np.testing.assert_allclose(start[:3], [0.0, 0.2, -0.4], atol=2e-3)  # initial_value of each joint
    track(
        engine,
        "arm_controller",
        ARM_JOINTS,
        [[0.5, -0.4, 0.6, 0.4, -0.3, 1.0], [-0.3, 0.3, -0.3, -0.2, 0.3, -0.5], [0.0] * 6],
    )

    assert engine.switch(["gripper_controller"], []).ok
    twin = engine.hardware[0].component
    right = twin.model.joint("gripper_finger_right").qposadr[0]
    for _ in range(250):
        engine.manager.records["gripper_controller"].instance.accept({"values": [0.025]})
        engine.run_cycles(1)
    left = engine.state.position[engine.joints.index("gripper_finger_left")]
    assert left == pytest.approx(0.025, abs=2e-3)
    assert twin.data.qpos[right] == pytest.approx(left, abs=2e-3)  # the MuJoCo equality from <mimic>


def test_my_arm_with_mock_hardware_xacro_arg(tmp_path: Path) -> None:
    result = import_robot(
        MY_ARM / "urdf" / "my_arm.urdf.xacro",
        MY_ARM / "config" / "my_arm_controllers.yaml",
        tmp_path / "my_arm.yaml",
        package_roots={"my_arm_description": MY_ARM},
        xacro_args={"use_mock_hardware": "true", "prefix": ""},
        allow_partial=True,
    )
    assert "mock_components/GenericSystem" in result.urdf.read_text()
    assert any("mock_components/GenericSystem" in f.text for f in result.report.of("approximated"))
    assert not any("MyArmSystemHardware" in f.text for f in result.report.findings)


def test_the_commented_can_template_passes_check_once_uncommented(tmp_path: Path) -> None:
    result = import_robot(
        MY_ARM / "urdf" / "my_arm.urdf.xacro",
        MY_ARM / "config" / "my_arm_controllers.yaml",
        tmp_path / "my_arm.yaml",
        package_roots={"my_arm_description": MY_ARM},
        allow_partial=True,  # its admittance controller has no hild counterpart
    )
    text = result.config.read_text()
    head, template = text.split("# hardware:\n")
    hardware = "hardware:\n" + "\n".join(line.removeprefix("# ") for line in template.splitlines())
    twin_section = re.search(r"^hardware:\n(?:  .*\n|\n)*?(?=^joints:)", head, re.M)
    assert twin_section is not None
    can = tmp_path / "my_arm_can.yaml"
    can.write_text(head.replace(twin_section.group(0), hardware + "\n"))
    cfg = load_config(can).config
    arm = cfg.hardware["myarm"]
    assert arm.driver == "mit_can"
    assert (arm.joints["shoulder_lift"].reduction, arm.joints["shoulder_lift"].direction) == (50, -1)
    assert arm.joints["elbow"].offset == pytest.approx(0.1)
    assert list(arm.joints) == list(cfg.joints)
