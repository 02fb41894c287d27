"""Controller YAML as real packages write it: the Jazzy layout, several files merged in order, launch substitutions.

Issue [import-real] causes 1, 2 and 6, at the reader: every controller keeps its name and type whichever layout
names it, a later file overrides an earlier one key by key (as ROS applies parameter files), and ``$(var NAME)``
takes its value from ``--arg`` or stops the import naming the substitution and its line.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from hild.importers.ros2_control.controllers import ControllersPlan, JointCatalog, read_controllers
from hild.importers.ros2_control.report import ImportFailure, Report

CATALOG = JointCatalog(
    commanded=("j1", "j2", "left_j1", "left_j2"),
    urdf=frozenset({"j1", "j2", "left_j1", "left_j2"}),
    mimic={},
    interfaces={},
)
JTC = "joint_trajectory_controller/JointTrajectoryController"
FORWARD = "forward_command_controller/ForwardCommandController"
JSB = "joint_state_broadcaster/JointStateBroadcaster"

# The ros2_control demos since Jazzy: each controller's type in its own ros__parameters block.
JAZZY = f"""\
joint_state_broadcaster:
  ros__parameters:
    type: {JSB}

forward_position_controller:
  ros__parameters:
    type: {FORWARD}
    joints:
      - j1
      - j2
    interface_name: position

joint_trajectory_controller:
  ros__parameters:
    type: {JTC}
    joints: [j1, j2]
    command_interfaces: [position]
    state_interfaces: [position, velocity]
"""


def write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def read(files: list[Path], variables: dict[str, str] | None = None) -> tuple[ControllersPlan, Report]:
    report = Report()
    return read_controllers(files, CATALOG, report, variables or {}), report


def texts(report: Report, kind: str) -> list[str]:
    return [f"{f.where}: {f.text}" for f in report.of(kind)]  # type: ignore[arg-type]


def test_jazzy_layout_without_a_controller_manager_block(tmp_path: Path) -> None:
    path = write(tmp_path, "controllers.yaml", JAZZY)
    plan, report = read([path])
    names = [(c.name, c.type) for c in plan.controllers]
    assert names == [
        ("joint_state_broadcaster", "joint_state_broadcaster"),
        ("forward_position_controller", "forward_command"),
        ("joint_trajectory_controller", "joint_trajectory"),
    ]
    assert plan.controllers[1].params == {"joints": ["j1", "j2"], "interface": "position"}
    assert plan.controllers[2].where.line == 15  # the type key of the controller's own block
    assert plan.update_rate == 100  # no controller_manager anywhere: its default, said so
    assert any("no update_rate" in t for t in texts(report, "approximated"))
    assert report.partial == []
    assert not any("'type'" in t for t in texts(report, "unsupported"))  # type is read, not "not used"


def test_jazzy_layout_beside_a_controller_manager_block(tmp_path: Path) -> None:
    text = "controller_manager:\n  ros__parameters:\n    update_rate: 250\n\n" + JAZZY
    plan, report = read([write(tmp_path, "controllers.yaml", text)])
    assert plan.update_rate == 250
    assert [c.name for c in plan.controllers] == [
        "joint_state_broadcaster",
        "forward_position_controller",
        "joint_trajectory_controller",
    ]
    assert not any("which controller_manager does not define" in t for t in texts(report, "unsupported"))


def test_a_type_in_both_places_must_agree(tmp_path: Path) -> None:
    text = f"controller_manager:\n  ros__parameters:\n    fwd:\n      type: {JSB}\n"
    text += f"fwd:\n  ros__parameters:\n    type: {FORWARD}\n    joints: [j1]\n    interface_name: position\n"
    path = write(tmp_path, "controllers.yaml", text)
    with pytest.raises(ImportFailure) as info:
        read([path])
    assert str(info.value).startswith(f"{path}:7: controller 'fwd' has two types: {FORWARD} here and {JSB} at ")
    assert f"{path}:4" in str(info.value)


def test_files_merge_in_order_key_by_key(tmp_path: Path) -> None:
    first = write(
        tmp_path,
        "controllers.yaml",
        f"controller_manager:\n  ros__parameters:\n    update_rate: 100\n    jtc:\n      type: {JTC}\n"
        "jtc:\n  ros__parameters:\n    joints: [j1, j2]\n    constraints:\n      goal_time: 0.5\n"
        "      j1: {goal: 0.1}\n",
    )
    second = write(
        tmp_path,
        "update_rate.yaml",
        "/controller_manager:\n  ros__parameters:\n    update_rate: 500\n"
        "jtc:\n  ros__parameters:\n    constraints:\n      j1: {goal: 0.02}\n",
    )
    plan, report = read([first, second])
    assert plan.update_rate == 500 and plan.update_rate_where.file == str(second)
    (jtc,) = plan.controllers
    assert jtc.params["joints"] == ["j1", "j2"]  # from the first file: the second does not name them
    assert jtc.params["constraints"]["goal_time"] == 0.5
    assert jtc.params["constraints"]["joints"]["j1"] == {"goal": 0.02}  # the later file wins
    assert f"{second}:3: update_rate 500 Hz" in texts(report, "mapped")


def test_a_file_of_controller_params_only_reads_its_types_from_another(tmp_path: Path) -> None:
    types = write(
        tmp_path,
        "cm.yaml",
        f"controller_manager:\n  ros__parameters:\n    update_rate: 50\n    fwd:\n      type: {FORWARD}\n",
    )
    params = write(tmp_path, "params.yaml", "fwd:\n  ros__parameters:\n    joints: [j2]\n    interface_name: effort\n")
    plan, _ = read([types, params])
    (fwd,) = plan.controllers
    assert (fwd.name, fwd.params) == ("fwd", {"joints": ["j2"], "interface": "effort"})


def test_launch_variables_take_their_values_from_args(tmp_path: Path) -> None:
    text = JAZZY.replace("- j1", "- $(var prefix)j1").replace("[j1, j2]", "[$(var prefix)j1, $(var prefix)j2]")
    plan, _report = read([write(tmp_path, "controllers.yaml", text)], {"prefix": "left_"})
    assert plan.controllers[1].params["joints"] == ["left_j1", "j2"]
    assert plan.controllers[2].params["joints"] == ["left_j1", "left_j2"]
    plan, _ = read([write(tmp_path, "controllers.yaml", text)], {"prefix": ""})
    assert plan.controllers[2].params["joints"] == ["j1", "j2"]


def test_a_launch_variable_without_a_value_is_named_with_its_line(tmp_path: Path) -> None:
    text = JAZZY.replace("- j2", "- $(var joint_prefix)j2")
    path = write(tmp_path, "controllers.yaml", text)
    with pytest.raises(ImportFailure) as info:
        read([path], {"prefix": "x"})
    assert str(info.value) == (
        f"{path}:10: $(var joint_prefix) has no value: pass --arg joint_prefix=VALUE (the launch file's argument)"
    )


def test_other_launch_substitutions_are_reported_not_guessed(tmp_path: Path) -> None:
    text = JAZZY + "    robot_description_path: $(find-pkg-share my_arm)/urdf/arm.urdf\n"
    _plan, report = read([write(tmp_path, "controllers.yaml", text)])
    assert any("$(find-pkg-share my_arm)" in t and ":19:" in t for t in texts(report, "unsupported"))


def test_ros1_and_ros2_files_do_not_mix(tmp_path: Path) -> None:
    ros1 = write(tmp_path, "ros1.yaml", "arm:\n  jsc:\n    type: joint_state_controller/JointStateController\n")
    ros2 = write(tmp_path, "ros2.yaml", JAZZY)
    with pytest.raises(ImportFailure, match=r"ros1\.yaml: a ROS 1 controller file .*/ros2\.yaml"):
        read([ros2, ros1])


def test_controllers_hild_cannot_map_are_listed_as_partial(tmp_path: Path) -> None:
    text = JAZZY + "diff_drive:\n  ros__parameters:\n    type: diff_drive_controller/DiffDriveController\n"
    text += f"temp:\n  ros__parameters:\n    type: {FORWARD}\n    joints: [j1]\n    interface_name: temperature\n"
    path = write(tmp_path, "controllers.yaml", text)
    plan, report = read([path])
    assert [c.name for c in plan.controllers] == [
        "joint_state_broadcaster",
        "forward_position_controller",
        "joint_trajectory_controller",
    ]
    assert [f"{f.where}" for f in report.partial] == [f"{path}:21", f"{path}:26"]
    assert "diff_drive" in report.partial[0].text and "temperature" in report.partial[1].text


def goal_time_block(seconds: float) -> str:
    """A ``/**`` block setting jtc's goal time: applied to every node and every robot."""
    return f"/**:\n  jtc:\n    ros__parameters:\n      constraints:\n        goal_time: {seconds}\n"


# A file that repeats its top-level key: ROS's parameter parser applies every block in order, as it would separate
# files; yaml.safe_load keeps the last block only.
REPEATED = f"""\
/**:
  controller_manager:
    ros__parameters:
      update_rate: 250
      jtc:
        type: {JTC}
      jsb:
        type: {JSB}

/**:
  jtc:
    ros__parameters:
      joints: [j1, j2]
      command_interfaces: [position]
      constraints:
        goal_time: 0.5

{goal_time_block(0.8)}"""


def test_a_repeated_top_level_key_is_merged_block_by_block_as_ros_applies_it(tmp_path: Path) -> None:
    path = write(tmp_path, "controllers.yaml", REPEATED)
    plan, report = read([path])
    assert [(c.name, c.type) for c in plan.controllers] == [
        ("jtc", "joint_trajectory"),
        ("jsb", "joint_state_broadcaster"),
    ]
    assert plan.update_rate == 250  # from the first block
    (jtc,) = [c for c in plan.controllers if c.name == "jtc"]
    assert jtc.params["joints"] == ["j1", "j2"]  # from the second block …
    assert jtc.params["constraints"]["goal_time"] == 0.8  # … overridden by the third, parameter by parameter
    assert f"{path}:10: '/**' repeated (first at line 1): merged with it block by block, as ROS applies it" in texts(
        report, "mapped"
    )
    assert f"{path}:18: '/**' repeated (first at line 1): merged with it block by block, as ROS applies it" in texts(
        report, "mapped"
    )


def test_a_file_that_yields_no_controllers_stops_the_import(tmp_path: Path) -> None:
    path = write(tmp_path, "controllers.yaml", "/**:\n  ros__parameters:\n    use_sim_time: true\n")
    with pytest.raises(ImportFailure, match="no controllers found"):
        read([path])


TWO_ROBOTS = f"""\
/leader:
  controller_manager:
    ros__parameters:
      update_rate: 100
      jtc:
        type: {JTC}
  jtc:
    ros__parameters:
      joints: [j1, j2]
/follower:
  controller_manager:
    ros__parameters:
      update_rate: 500
      fwd:
        type: {FORWARD}
  fwd:
    ros__parameters:
      joints: [left_j1]
      interface_name: position
{goal_time_block(0.7)}"""


def test_two_robots_blocks_are_not_merged_the_first_is_read_and_the_report_says_so(tmp_path: Path) -> None:
    path = write(tmp_path, "controllers.yaml", TWO_ROBOTS)
    plan, report = read([path])
    assert [c.name for c in plan.controllers] == ["jtc"] and plan.update_rate == 100  # the leader's, not merged
    assert plan.controllers[0].params["constraints"]["goal_time"] == 0.7  # /** applies to every robot
    assert (
        f"{path}:2: the controller files give 2 robots' namespaces (/leader, /follower): the import reads /leader, "
        "the first (--namespace NAME chooses)"
    ) in texts(report, "approximated")
    left_out = [t for t in texts(report, "unsupported") if "another robot's namespace" in t]
    reads = "another robot's namespace, left out (the import reads /leader)"
    assert left_out == [
        f"{path}:11: 'controller_manager' under /follower: {reads}",
        f"{path}:16: 'fwd' under /follower: {reads}",
    ]


def test_the_namespace_chooses_the_robot(tmp_path: Path) -> None:
    path = write(tmp_path, "controllers.yaml", TWO_ROBOTS)
    report = Report()
    plan = read_controllers([path], CATALOG, report, {}, namespace="/follower")
    assert [c.name for c in plan.controllers] == ["fwd"] and plan.update_rate == 500
    with pytest.raises(ImportFailure, match="--namespace /right: no node of the controller files is under it"):
        read_controllers([path], CATALOG, Report(), {}, namespace="right")
