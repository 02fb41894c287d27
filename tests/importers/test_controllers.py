"""controller_manager YAML → hild controllers: both layouts, each controller type, and the report of each key."""

from __future__ import annotations

from pathlib import Path

import pytest

from hild.importers.ros2_control.controllers import ControllersPlan, JointCatalog, read_controllers
from hild.importers.ros2_control.report import ImportFailure, Report

CATALOG = JointCatalog(
    commanded=("j1", "j2"),
    urdf=frozenset({"j1", "j2", "j3", "fixed"}),
    mimic={"j3": "j1"},
    interfaces={"j1": frozenset({"position"}), "j2": frozenset({"position"})},
)


def read(tmp_path: Path, text: str) -> tuple[ControllersPlan, Report, Path]:
    path = tmp_path / "controllers.yaml"
    path.write_text(text)
    report = Report()
    return read_controllers(path, CATALOG, report), report, path


def texts(report: Report, kind: str) -> list[str]:
    return [f"{f.where.line}: {f.text}" for f in report.of(kind)]  # type: ignore[arg-type]


def test_namespaced_ros2_layout_with_wildcard_and_velocity_only_jtc(tmp_path: Path) -> None:
    plan, report, _ = read(
        tmp_path,
        """\
/**:
  ros__parameters:
    use_sim_time: true
/robot1/controller_manager:
  ros__parameters:
    update_rate: 1000
    jtc:
      type: joint_trajectory_controller/JointTrajectoryController
    group:
      type: velocity_controllers/JointGroupVelocityController
robot1:
  jtc:
    ros__parameters:
      joints: [j1, j2]
      command_interfaces: [velocity]
      gains: {j1: {p: 5.0}, j2: {p: 5.0}}
      constraints: {goal_time: 0.0}
  group:
    ros__parameters:
      joints: [j2]
""",
    )
    assert plan.update_rate == 1000
    jtc, group = plan.controllers
    assert jtc.type == "joint_trajectory" and jtc.params["command_interfaces"] == ["position", "velocity"]
    assert jtc.params["constraints"] == {"goal_time": 1.0, "stopped_velocity_tolerance": 0.01}
    assert jtc.pid == {}  # velocity-loop gains are not torque gains: never hold gains
    assert (group.type, group.params) == ("forward_command", {"joints": ["j2"], "interface": "velocity"})
    approximated = texts(report, "approximated")
    assert "15: jtc: velocity-only (a PID on the velocity interface) → [position, velocity]: the drive tracks both" in (
        approximated
    )
    assert "16: jtc: gains unused: hild's drive closes the position loop" in approximated
    assert "17: jtc: goal_time 0 (ROS: wait forever) → 1 s after the trajectory's end" in approximated
    assert any(line.startswith("8: controller 'jtc' claims j1/velocity, j2/velocity") for line in approximated)
    assert "3: wildcard parameter 'use_sim_time' is not used" in texts(report, "unsupported")


def test_ros1_layout_with_pid_position_controller(tmp_path: Path) -> None:
    plan, report, _ = read(
        tmp_path,
        """\
rrbot:
  joint_state_controller:
    type: joint_state_controller/JointStateController
    publish_rate: 50
  joint1_position_controller:
    type: effort_controllers/JointPositionController
    joint: j1
    pid: {p: 100.0, i: 0.01, d: 10.0, i_clamp_min: -2.0, i_clamp_max: 3.0, antiwindup: true}
""",
    )
    assert plan.update_rate == 100  # ROS 1 YAML has none: controller_manager's default
    jsc, pid = plan.controllers
    assert (jsc.type, jsc.params, jsc.autostart) == ("joint_state_broadcaster", {"publish_rate": 50}, True)
    assert pid.type == "joint_trajectory" and pid.params["joints"] == ["j1"]
    assert pid.params["command_interfaces"] == ["effort"] and not pid.autostart
    gains = pid.pid["j1"]
    assert (gains.p, gains.i, gains.d, gains.i_clamp) == (100.0, 0.01, 10.0, 2.0)
    assert "8: joint1_position_controller: asymmetric integral clamp → ±2" in texts(report, "approximated")
    assert "8: joint1_position_controller: PID option 'antiwindup' is not used by hild" in texts(report, "unsupported")
    assert "4: joint_state_controller: publish_rate 50 Hz" in texts(report, "mapped")


def test_unknown_types_and_orphan_parameters_are_reported_not_fatal(tmp_path: Path) -> None:
    plan, report, _ = read(
        tmp_path,
        """\
controller_manager:
  ros__parameters:
    update_rate: 100
    thread_priority: 60
    diff_drive:
      type: diff_drive_controller/DiffDriveController
    fwd:
      type: forward_command_controller/ForwardCommandController
fwd:
  ros__parameters:
    joints: [j1]
    interface_name: temperature
leftover:
  ros__parameters:
    joints: [j1]
""",
    )
    assert plan.controllers == []
    unsupported = texts(report, "unsupported")
    assert "4: controller_manager parameter 'thread_priority' is not used by hild" in unsupported
    assert "6: controller 'diff_drive': type diff_drive_controller/DiffDriveController has no hild counterpart" in (
        unsupported
    )
    assert "12: controller 'fwd': interface 'temperature' (hild forwards position, velocity or effort)" in unsupported
    assert "13: parameters for 'leftover', which is not a controller: no type here or in controller_manager" in (
        unsupported
    )


@pytest.mark.parametrize(
    ("joint", "reason"),
    [
        ("j3", "is a mimic joint of 'j1' and cannot be commanded"),
        ("fixed", "is in the URDF but in no <ros2_control> block, so it has no command interfaces"),
        ("nope", "does not exist in the URDF (commandable joints: j1, j2)"),
    ],
)
def test_joints_controllers_cannot_command(tmp_path: Path, joint: str, reason: str) -> None:
    text = f"controller_manager:\n  ros__parameters:\n    f:\n      type: {FORWARD}\nf:\n  ros__parameters:\n"
    text += f"    interface_name: position\n    joints:\n      - j1\n      - {joint}\n"
    with pytest.raises(ImportFailure) as info:
        read(tmp_path, text)
    assert (
        str(info.value) == f"{tmp_path / 'controllers.yaml'}:10: controller 'f' names joint {joint!r}, which {reason}"
    )


def test_a_jtc_interface_set_ros_rejects_is_an_error(tmp_path: Path) -> None:
    text = f"controller_manager:\n  ros__parameters:\n    t:\n      type: {JTC}\nt:\n  ros__parameters:\n"
    text += "    joints: [j1]\n    command_interfaces: [effort, velocity]\n"
    with pytest.raises(ImportFailure, match=r"controllers.yaml:8: controller 't': command_interfaces \['effort', "):
        read(tmp_path, text)


def test_no_controllers_at_all_is_an_error(tmp_path: Path) -> None:
    with pytest.raises(ImportFailure, match=r"controllers\.yaml:1: no controllers found"):
        read(tmp_path, "something:\n  else: 1\n")


FORWARD = "forward_command_controller/ForwardCommandController"
JTC = "joint_trajectory_controller/JointTrajectoryController"


@pytest.mark.parametrize(
    ("ros_type", "action"),
    [
        ("parallel_gripper_action_controller/GripperActionController", "parallel_gripper_command"),
        ("position_controllers/GripperActionController", "gripper_command"),
    ],
)
def test_gripper_action_controllers_become_parallel_gripper(tmp_path: Path, ros_type: str, action: str) -> None:
    plan, report, _ = read(
        tmp_path,
        f"""\
controller_manager:
  ros__parameters:
    update_rate: 500
    gripper_controller:
      type: {ros_type}
gripper_controller:
  ros__parameters:
    joint: j2
    goal_tolerance: 0.002
    allow_stalling: true
    stall_velocity_threshold: 0.002
    stall_timeout: 0.5
    max_effort: 0.0
    max_velocity: 0.05
    max_effort_interface: j2/max_effort
    action_monitor_rate: 50.0
""",
    )
    (gripper,) = plan.controllers
    assert gripper.type == "parallel_gripper" and not gripper.autostart
    assert gripper.params == {
        "joint": "j2",
        "ros_action": action,
        "goal_tolerance": 0.002,
        "stall_velocity_threshold": 0.002,
        "stall_timeout": 0.5,
        "max_velocity": 0.05,
        "action_monitor_rate": 50.0,
        "allow_stalling": True,
    }
    assert any("gripper_controller → parallel_gripper on j2" in t for t in texts(report, "mapped"))
    approximated = texts(report, "approximated")
    assert any("13: gripper_controller: max_effort 0 → parallel_gripper's default" in t for t in approximated)
    assert any("max_effort_interface not needed: hild bounds the grasp force itself" in t for t in approximated)
    assert not report.of("dropped")


def test_a_gripper_on_a_mimic_joint_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ImportFailure, match="names joint 'j3', which is a mimic joint of 'j1'"):
        read(
            tmp_path,
            """\
gripper:
  ros__parameters:
    type: parallel_gripper_action_controller/GripperActionController
    joint: j3
""",
        )
