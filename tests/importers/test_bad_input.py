"""Bad input stops the import with the file, line and element or key; nothing is ever written."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from hild.importers.ros2_control.report import ImportFailure
from tests.importers.helpers import MY_ARM, RRBOT, copy_robot, import_robot

CONTROLLERS = RRBOT / "rrbot_controllers.yaml"


def line_of(path: Path, needle: str, occurrence: int = 1) -> int:
    """1-based line of the ``occurrence``-th line containing ``needle``."""
    hits = [i + 1 for i, line in enumerate(path.read_text().splitlines()) if needle in line]
    return hits[occurrence - 1]


def edited(tmp_path: Path, source: Path, old: str, new: str, name: str | None = None) -> Path:
    text = source.read_text()
    assert old in text
    target = tmp_path / (name or source.name)
    target.write_text(text.replace(old, new, 1))
    return target


def fails(tmp_path: Path, urdf: Path, controllers: Path = CONTROLLERS, **options: object) -> str:
    out = tmp_path / "out"
    with pytest.raises(ImportFailure) as info:
        import_robot(urdf, controllers, out / "robot.yaml", **options)
    assert not out.exists(), "a failed import left files behind"
    return str(info.value)


def test_malformed_urdf_names_the_line_of_the_xml_error(tmp_path: Path) -> None:
    urdf = edited(tmp_path, RRBOT / "rrbot.urdf", '<child link="link1"/>', '<child link="link1">')
    message = fails(tmp_path, urdf)
    assert message == f"{urdf}:{line_of(urdf, '</joint>', 2)}: not well-formed XML: mismatched tag"


def test_controller_naming_a_missing_joint_names_controller_joint_and_line(tmp_path: Path) -> None:
    controllers = edited(tmp_path, CONTROLLERS, "      - joint2\n", "      - joint3\n")
    message = fails(tmp_path, RRBOT / "rrbot.urdf", controllers)
    line = line_of(controllers, "- joint3")
    assert message.startswith(f"{controllers}:{line}: controller 'effort_controller' names joint 'joint3', which")
    assert "does not exist in the URDF (commandable joints: joint1, joint2)" in message


def test_controller_naming_the_mimic_joint_is_refused(tmp_path: Path) -> None:
    controllers = edited(
        tmp_path, MY_ARM / "config" / "my_arm_controllers.yaml", "- gripper_finger_left", "- gripper_finger_right"
    )
    message = fails(tmp_path, MY_ARM / "urdf" / "my_arm.urdf.xacro", controllers)
    assert f"{controllers}:{line_of(controllers, '- gripper_finger_right')}: controller 'gripper_controller'" in message
    assert "is a mimic joint of 'gripper_finger_left' and cannot be commanded" in message


def test_missing_inertia_on_a_moving_link_is_a_clear_error(tmp_path: Path) -> None:
    text = (RRBOT / "rrbot.urdf").read_text()
    start = text.index("<inertial>", text.index('<link name="link2">'))
    end = text.index("</inertial>", start) + len("</inertial>")
    urdf = tmp_path / "rrbot.urdf"
    urdf.write_text(text[:start] + text[end:])
    message = fails(tmp_path, urdf)
    line = line_of(urdf, '<link name="link2">')
    assert message.startswith(f"{urdf}:{line}: link 'link2' has no <inertial>")
    assert "moves with joint 'joint2'" in message


def test_ros2_control_joint_missing_from_the_urdf(tmp_path: Path) -> None:
    urdf = edited(
        tmp_path, RRBOT / "rrbot.urdf", '<joint name="joint2">\n      <command', '<joint name="j9">\n      <command'
    )
    message = fails(tmp_path, urdf)
    line = line_of(urdf, '<joint name="j9">')
    assert message == f"{urdf}:{line}: <ros2_control> joint 'j9' is not a joint of the URDF (joints: joint1, joint2)"


def test_revolute_joint_without_limits(tmp_path: Path) -> None:
    urdf = edited(
        tmp_path, RRBOT / "rrbot.urdf", '<limit lower="-3.1416" upper="3.1416" effort="30" velocity="3.0"/>', ""
    )
    message = fails(tmp_path, urdf)
    line = line_of(urdf, '<joint name="joint1"')
    assert message == f"{urdf}:{line}: revolute joint 'joint1' needs <limit lower=... upper=...>"


def test_bad_number_in_the_urdf(tmp_path: Path) -> None:
    urdf = edited(tmp_path, RRBOT / "rrbot.urdf", 'effort="30" velocity="3.0"/>', 'effort="thirty" velocity="3.0"/>')
    message = fails(tmp_path, urdf)
    assert message == f"{urdf}:{line_of(urdf, 'thirty')}: <limit> effort='thirty' is not a number"


def test_invalid_controllers_yaml_names_its_line(tmp_path: Path) -> None:
    controllers = tmp_path / "controllers.yaml"
    controllers.write_text("controller_manager:\n  ros__parameters:\n    update_rate: [1\n")
    assert fails(tmp_path, RRBOT / "rrbot.urdf", controllers).startswith(f"{controllers}:4: not valid YAML")


def test_unknown_ros_package_without_a_root(tmp_path: Path) -> None:
    robot = tmp_path / "checkout"
    copy_robot(MY_ARM, robot)  # a directory not named after the package: no guess possible
    (robot / "my_arm_description").rename(robot / "description")
    message = fails(
        tmp_path, robot / "description" / "urdf" / "my_arm.urdf.xacro", MY_ARM / "config" / "my_arm_controllers.yaml"
    )
    assert "unknown ROS package 'my_arm_description' in $(find my_arm_description)" in message
    assert "--package-root my_arm_description=DIR" in message


def test_malformed_included_xacro_names_the_included_file(tmp_path: Path) -> None:
    robot = copy_robot(MY_ARM, tmp_path)
    macros = robot / "urdf" / "my_arm_macros.xacro"
    macros.write_text(macros.read_text().replace('<child link="${child}"/>', '<child link="${child}">'))
    message = fails(tmp_path, robot / "urdf" / "my_arm.urdf.xacro", robot / "config" / "my_arm_controllers.yaml")
    assert message.startswith(f"{macros}:") and message.endswith("not well-formed XML: mismatched tag")


def test_undefined_xacro_argument(tmp_path: Path) -> None:
    xacro = edited(
        tmp_path, MY_ARM / "urdf" / "my_arm.urdf.xacro", '<xacro:arg name="use_mock_hardware" default="false"/>', ""
    )
    message = fails(
        tmp_path, xacro, MY_ARM / "config" / "my_arm_controllers.yaml", package_roots={"my_arm_description": MY_ARM}
    )
    assert "Undefined substitution argument use_mock_hardware (pass it with --arg NAME=VALUE)" in message


def test_a_mesh_mujoco_cannot_read_fails_after_staging_and_leaves_no_directory(tmp_path: Path) -> None:
    robot = copy_robot(MY_ARM, tmp_path)
    (robot / "meshes" / "tool.stl").write_bytes(b"not an stl")
    nested = tmp_path / "new" / "deeper"
    with pytest.raises(ImportFailure) as info:
        import_robot(
            robot / "urdf" / "my_arm.urdf.xacro", robot / "config" / "my_arm_controllers.yaml", nested / "arm.yaml"
        )
    assert not (tmp_path / "new").exists()
    message = str(info.value)  # at the <mesh> element (of the expansion), never naming a staging file
    assert re.match(
        rf"{nested / 'arm.urdf'}:\d+: the twin cannot use this URDF \(mesh 'tool'\): MuJoCo refuses", message
    )
    assert "invalid header in STL file" in message and str(robot / "meshes" / "tool.stl") in message
    assert ".hild-import-" not in message


def test_a_negative_moment_of_inertia_names_its_line(tmp_path: Path) -> None:
    urdf = edited(tmp_path, RRBOT / "rrbot.urdf", 'ixx="0.084167"', 'ixx="-0.084167"')
    message = fails(tmp_path, urdf)
    line = line_of(urdf, 'ixx="-0.084167"')
    assert message.startswith(f"{urdf}:{line}: link 'link1': principal moments of inertia -0.08417, ")
    assert message.endswith("a negative one is no rigid body's; fix the <inertia>")


def test_a_collision_mesh_in_a_format_mujoco_lacks(tmp_path: Path) -> None:
    robot = copy_robot(MY_ARM, tmp_path)
    (robot / "meshes" / "tool.dae").write_text("<COLLADA/>")
    xacro = robot / "urdf" / "my_arm.urdf.xacro"
    xacro.write_text(xacro.read_text().replace("meshes/tool.stl", "meshes/tool.dae"))
    message = fails(tmp_path, xacro, robot / "config" / "my_arm_controllers.yaml")
    assert re.search(r"link 'tool_link': MuJoCo reads \.stl, \.obj, \.msh meshes, not '\.dae'", message)


def test_refuses_to_overwrite_without_force_and_overwrites_with_it(tmp_path: Path) -> None:
    output = tmp_path / "rrbot.yaml"
    output.write_text("# mine\n")
    with pytest.raises(ImportFailure, match="exists: pass --force"):
        import_robot(RRBOT / "rrbot.urdf", CONTROLLERS, output)
    assert output.read_text() == "# mine\n" and not (tmp_path / "rrbot.urdf").exists()
    import_robot(RRBOT / "rrbot.urdf", CONTROLLERS, output, force=True)
    assert "driver: mujoco" in output.read_text() and (tmp_path / "rrbot.urdf").is_file()


def test_never_overwrites_its_own_input_even_with_force(tmp_path: Path) -> None:
    robot = copy_robot(RRBOT, tmp_path)
    with pytest.raises(ImportFailure, match="the output would overwrite this input"):
        import_robot(robot / "rrbot.urdf", robot / "rrbot_controllers.yaml", robot / "rrbot.yaml", force=True)
    assert (robot / "rrbot.urdf").read_text() == (RRBOT / "rrbot.urdf").read_text()
