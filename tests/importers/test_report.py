"""The import report: three sections, each finding at the line of the element or key it is about."""

from __future__ import annotations

import re
from pathlib import Path

from hild.importers.ros2_control.importer import ImportResult
from tests.importers.helpers import ARM2, MY_ARM, RRBOT, import_robot
from tests.importers.test_bad_input import edited, line_of


def find(result: ImportResult, kind: str, text: str) -> list[str]:
    return [str(f.where) for f in result.report.of(kind) if text in f.text]  # type: ignore[arg-type]


def rrbot(tmp_path: Path, controllers: Path = RRBOT / "rrbot_controllers.yaml") -> ImportResult:
    return import_robot(RRBOT / "rrbot.urdf", controllers, tmp_path / "out" / "rrbot.yaml")


def test_sections_are_printed_with_counts_and_every_line_has_file_and_line(tmp_path: Path) -> None:
    result = rrbot(tmp_path)
    text = result.report.format()
    for title, kind in (("Mapped", "mapped"), ("Approximated", "approximated"), ("Not supported", "unsupported")):
        assert f"{title} ({len(result.report.of(kind))}):" in text  # type: ignore[arg-type]
    assert text.index("Mapped") < text.index("Approximated") < text.index("Not supported")
    for finding in result.report.findings:
        assert re.fullmatch(r".+\.(urdf|yaml):\d+", str(finding.where)), finding
        assert f"  {finding.where}: {finding.text}" in text


def test_urdf_findings_point_at_their_elements(tmp_path: Path) -> None:
    urdf = RRBOT / "rrbot.urdf"
    result = rrbot(tmp_path)
    assert find(result, "mapped", "transmission 'tran2'") == [f"{urdf}:{line_of(urdf, '>-10<')}"]
    assert "direction -1" in next(f.text for f in result.report.of("mapped") if "tran2" in f.text)
    gazebo = line_of(urdf, '<gazebo reference="link1">')
    assert find(result, "unsupported", "<gazebo reference='link1'>") == [f"{urdf}:{gazebo}"]
    limit2 = line_of(urdf, '<limit effort="30" velocity="3.0"/>')
    assert find(result, "approximated", "joint2: continuous joint") == [f"{urdf}:{limit2}"]
    plugin = line_of(urdf, "<plugin>gazebo_ros2_control/GazeboSystem</plugin>")
    assert find(result, "mapped", "gazebo_ros2_control/GazeboSystem (Gazebo Classic)") == [f"{urdf}:{plugin}"]


def test_yaml_findings_point_at_their_keys(tmp_path: Path) -> None:
    controllers = edited(
        tmp_path,
        RRBOT / "rrbot_controllers.yaml",
        "    command_interfaces:\n",
        "    cmd_timeout: 0.5\n    command_interfaces:\n",
    )
    result = rrbot(tmp_path, controllers)
    assert find(result, "mapped", "update_rate 500 Hz") == [f"{controllers}:{line_of(controllers, 'update_rate')}"]
    assert find(result, "unsupported", "parameter 'cmd_timeout'") == [
        f"{controllers}:{line_of(controllers, 'cmd_timeout')}"
    ]
    gains = line_of(controllers, "joint1: {p: 400.0")
    assert find(result, "mapped", "joint1: hold gains kp 400, kd 60") == [f"{controllers}:{gains}"]
    legacy = line_of(controllers, "type: effort_controllers/JointPositionController")
    assert find(result, "approximated", "joint1_position_controller: effort_controllers/JointPositionController") == [
        f"{controllers}:{legacy}"
    ]


def test_the_twin_urdf_keeps_every_line_of_a_plain_urdf(tmp_path: Path) -> None:
    result = rrbot(tmp_path)
    source = (RRBOT / "rrbot.urdf").read_text().splitlines()
    copy = result.urdf.read_text().splitlines()
    assert len(copy) == len(source)
    for original, written in zip(source, copy, strict=True):
        if original.startswith("<robot "):
            assert '<mujoco><compiler strippath="false"' in written  # added on the <robot> line: nothing moves
        elif original.strip().startswith("<") and "<!--" not in original:
            assert written.strip() == original.strip(), (original, written)


def test_xacro_findings_point_into_the_written_expansion(tmp_path: Path) -> None:
    result = import_robot(
        MY_ARM / "urdf" / "my_arm.urdf.xacro",
        MY_ARM / "config" / "my_arm_controllers.yaml",
        tmp_path / "arm.yaml",
        allow_partial=True,
    )
    lines = result.urdf.read_text().splitlines()
    assert any(str(result.urdf) in note for note in result.report.notes)

    def at(where: str) -> str:
        file, line = where.rsplit(":", 1)
        assert file == str(result.urdf)
        return lines[int(line) - 1]

    (transmission,) = find(result, "mapped", "transmission 'shoulder_lift_transmission'")
    assert "<mechanical_reduction>-50" in at(transmission)
    (mimic,) = find(result, "mapped", "mimic joint 'gripper_finger_right'")
    assert '<mimic joint="gripper_finger_left"' in at(mimic)
    (plugin,) = find(result, "unsupported", "hardware plugin my_arm_hardware/MyArmSystemHardware")
    assert "<plugin>my_arm_hardware/MyArmSystemHardware</plugin>" in at(plugin)
    (initial,) = find(result, "mapped", "elbow: initial_value -0.4")
    assert '<param name="initial_value">-0.4</param>' in at(initial)
    # No --package-root: the package was found as the directory the xacro sits in, and that is said.
    assert find(result, "approximated", "ROS package 'my_arm_description' taken to be")


def test_config_comments_name_the_source_lines(tmp_path: Path) -> None:
    result = import_robot(ARM2 / "arm2_gz.urdf", ARM2 / "arm2_controllers.yaml", tmp_path / "arm2.yaml")
    text = result.config.read_text()
    urdf = ARM2 / "arm2_gz.urdf"
    shoulder = line_of(urdf, '<joint name="shoulder">')
    assert f"shoulder: {{}}  # arm2_gz.urdf:{shoulder}" in text
    controllers = ARM2 / "arm2_controllers.yaml"
    assert f"(arm2_controllers.yaml:{line_of(controllers, 'update_rate')})" in text
    assert "# hardware:\n#   gazebosimsystem:" in text  # the CAN template, commented out


def test_visual_meshes_the_twin_discards_may_be_collada_or_missing(tmp_path: Path) -> None:
    robot = tmp_path / "my_arm_description"
    robot.mkdir()
    for part in ("urdf", "meshes", "config"):
        (robot / part).mkdir()
        for file in (MY_ARM / part).iterdir():
            (robot / part / file.name).write_bytes(file.read_bytes())
    (robot / "meshes" / "base.dae").write_text("<COLLADA/>")
    xacro = robot / "urdf" / "my_arm.urdf.xacro"
    text = xacro.read_text()
    text = text.replace("meshes/base.obj", "meshes/base.dae", 1)  # the visual (first) only
    text = text.replace("meshes/tool.stl", "meshes/gone.stl", 1)
    xacro.write_text(text)
    result = import_robot(
        xacro, robot / "config" / "my_arm_controllers.yaml", tmp_path / "arm.yaml", allow_partial=True
    )
    (missing,) = find(result, "unsupported", "visual mesh of link 'tool_link' not found")
    assert "gone.stl" in result.urdf.read_text().splitlines()[int(missing.rsplit(":", 1)[1]) - 1]
    assert str(robot / "meshes" / "base.dae") in result.urdf.read_text()
