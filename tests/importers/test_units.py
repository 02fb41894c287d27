"""The small pieces: XML with lines, the YAML writer, joint inertias, package roots."""

from __future__ import annotations

from pathlib import Path

import mujoco
import pytest
import yaml

from hild.importers.ros2_control.inertia import JointInertia, joint_inertias
from hild.importers.ros2_control.mapping import MAX_SUBSTEPS, JointPlan, choose_substeps
from hild.importers.ros2_control.packages import PackageRoots, parse_package_root
from hild.importers.ros2_control.report import Report, SourceRef
from hild.importers.ros2_control.writer import Document, render
from hild.importers.ros2_control.xmltree import XmlElement, XmlSyntaxError, parse_xml, serialize
from tests.importers.helpers import MY_ARM, RRBOT, import_robot


def test_xml_round_trip_is_exact_and_keeps_lines_when_tags_span_lines() -> None:
    text = (RRBOT / "rrbot.urdf").read_text()
    assert serialize(parse_xml(text)) == text
    spread = (
        '<robot name="r"\n       version="1">\n  <link\n    name="a"/>\n'
        '  <!-- two\n  lines -->\n  <link name="b"/>\n</robot>'
    )
    document = parse_xml(spread)
    assert [e.line for e in document.root.iter("link")] == [3, 7]
    document.root.children.insert(0, XmlElement("mujoco", {}, document.root.line))
    written = serialize(document).splitlines()
    assert written[0] == '<robot name="r" version="1"><mujoco/>'
    assert written[2] == '  <link name="a"/>' and written[6] == '  <link name="b"/>'


def test_xml_syntax_error_has_its_line() -> None:
    with pytest.raises(XmlSyntaxError) as info:
        parse_xml('<robot name="r">\n  <link name="a">\n</robot>\n')
    assert info.value.line == 3 and str(info.value) == "not well-formed XML: mismatched tag"


def test_yaml_writer_round_trips_through_a_yaml_parser() -> None:
    data = {
        "plain": "joint_1",
        "needs_quotes": "yes",
        "colon": "a: b",
        "unicode": "Gelenk-ä",
        "tiny": 1e-05,
        "big": 1e20,
        "whole": 3.0,
        "neg": -0.5,
        "flag": True,
        "none": None,
        "list": [1, 2.5, "x y"],
        "nested": {"deeper": {"k": 1}, "empty": {}},
        "long": {f"key_{i}": float(i) for i in range(30)},
    }
    text = render(Document(data, comments={("nested", "deeper"): "a comment"}, header=["head"], footer=["foot"]))
    assert yaml.safe_load(text) == data
    assert text.startswith("# head\n") and text.endswith("# foot\n")
    assert "deeper: {k: 1}  # a comment" in text


def test_joint_inertias_range_over_the_poses_the_arm_can_take(tmp_path: Path) -> None:
    result = import_robot(
        MY_ARM / "urdf" / "my_arm.urdf.xacro",
        MY_ARM / "config" / "my_arm_controllers.yaml",
        tmp_path / "arm.yaml",
        allow_partial=True,  # its admittance controller has no hild counterpart
    )
    joints = ["shoulder_pan", "shoulder_lift", "elbow", "wrist_2", "wrist_3", "gripper_finger_left"]
    model = mujoco.MjModel.from_xml_path(str(result.urdf))
    ranges = {"shoulder_pan": (-3.0, 3.0), "shoulder_lift": (-1.5, 1.5), "elbow": (-2.6, 2.6), "wrist_2": (-3, 3)}
    ranges |= {"wrist_3": (-3.0, 3.0), "gripper_finger_left": (0.0, 0.03)}
    found = joint_inertias(result.urdf, joints, ranges)
    for joint in joints:
        assert found[joint].at_zero == pytest.approx(model.dof_M0[model.joint(joint).dofadr[0]])
        assert found[joint].lightest <= found[joint].at_zero <= found[joint].heaviest
    # The pan joint of an arm standing upright carries almost nothing; stretched out, much more.
    assert found["shoulder_pan"].heaviest > 50 * found["shoulder_pan"].lightest
    assert found["gripper_finger_left"].heaviest == pytest.approx(0.05)  # prismatic: the finger's mass
    assert found["shoulder_lift"].damping == pytest.approx(0.5)


def test_package_roots_given_inferred_and_uris(tmp_path: Path) -> None:
    roots = PackageRoots({"given": tmp_path}, MY_ARM / "urdf")
    assert roots.find("given") == tmp_path.resolve()
    assert roots.find("my_arm_description") == MY_ARM and roots.inferred == {"my_arm_description": MY_ARM}
    assert roots.find("absent") is None
    assert roots.resolve_uri("package://given/a/b.stl", Path("/x")) == (tmp_path.resolve() / "a/b.stl", None)
    assert roots.resolve_uri("file:///m/a%20b.stl", Path("/x")) == (Path("/m/a b.stl"), None)
    assert roots.resolve_uri("meshes/c.obj", Path("/x")) == (Path("/x/meshes/c.obj"), None)
    assert roots.resolve_uri("package://absent/c.obj", Path("/x"))[1] == (
        "unknown ROS package 'absent': pass --package-root absent=DIR"
    )
    # Doubled slashes, as xacro writes them from file://$(find pkg)/… or package://pkg//…: clean paths, in the package
    assert roots.resolve_uri("file:////m//meshes/a.stl", Path("/x")) == (Path("/m/meshes/a.stl"), None)
    assert str(roots.resolve_uri("file:////m/a.stl", Path("/x"))[0]) == "/m/a.stl"  # not //m/a.stl
    assert roots.resolve_uri("package://given//a//b.stl", Path("/x")) == (tmp_path.resolve() / "a/b.stl", None)
    assert parse_package_root("pkg=/some/dir") == ("pkg", Path("/some/dir"))
    with pytest.raises(ValueError, match="expected NAME=DIR"):
        parse_package_root("pkg")


def plan(kp: float, kd: float, lightest: float) -> JointPlan:
    inertia = JointInertia(at_zero=lightest, lightest=lightest, heaviest=10 * lightest, damping=0.0, friction=0.0)
    where = SourceRef("robot.urdf", 7)
    return JointPlan("j", where, -1.0, 1.0, 0.0, 1.0, 10.0, 2.0, 20.0, kp, kd, "test", None, None, None, "", inertia)


def test_substeps_make_the_drive_law_stable_in_the_lightest_pose() -> None:
    report = Report()
    soft = plan(kp=100.0, kd=2.0, lightest=0.1)  # needs h ≤ min(0.5·0.1/2, 0.5·√(0.1/100)) = 15.8 ms: 1 ms rules
    assert choose_substeps([soft], 500.0, report) == 2 and report.findings == []
    stiff = plan(kp=100.0, kd=10.0, lightest=0.01)  # h ≤ min(0.5 ms, 5 ms)
    assert choose_substeps([soft, stiff], 500.0, report) == 4 and report.findings == []
    assert (stiff.kp, stiff.kd) == (100.0, 10.0)


def test_gains_beyond_max_substeps_are_lowered_and_reported() -> None:
    report = Report()
    heavy_handed = plan(kp=1000.0, kd=100.0, lightest=1e-4)  # would need h = 0.5 µs
    assert choose_substeps([heavy_handed], 100.0, report) == MAX_SUBSTEPS
    h = 0.01 / MAX_SUBSTEPS
    assert heavy_handed.kd == pytest.approx(0.5 * 1e-4 / h, rel=1e-3)
    assert heavy_handed.kd * h / 1e-4 <= 0.5 + 1e-9
    assert heavy_handed.kp * h * h / 1e-4 <= 0.25 + 1e-9
    (finding,) = report.findings
    assert finding.kind == "approximated" and str(finding.where) == "robot.urdf:7"
    assert "j: gains kp 1000, kd 100 need a physics step below" in finding.text


def test_yaml_writer_quotes_a_string_that_ends_in_a_newline() -> None:
    """`$` in the plain-scalar pattern matched before a final newline: "base\n" went out plain and came back "base"."""
    data = {"name": "base\n", "list": ["link\n", "plain"]}
    assert yaml.safe_load(render(Document(data))) == data
