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
import yaml

from hild.config import ConfigError, load_config
from hild.config.stop_review import check_with_model
from hild.cycle.engine import Engine
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
    """`hild check` (any warning is about the description's own values, and in the report), then lockstep: one
    second of hold (nothing moves, nothing faults), then a trajectory through start + offsets that must succeed
    with every joint within its goal tolerance of the last point."""
    relayed = [f.text for f in result.report.findings if f.text.startswith("hild check warns: ")]
    for warning in checked(result):
        about = warning.split(": ", 2)[-1]  # "key: message" after the file:line
        assert any(about in text for text in relayed), warning
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
    assert checked(result) == []
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


# ---- cause 3: the twin collides the robot with itself ----------------------------------------------------------
def meshes(tmp_path: Path, **options: Any) -> ImportResult:
    return import_robot(XACRO, CLASSIC, tmp_path / "arm3.yaml", xacro_args={"collision": "mesh"}, **options)


def excluded(result: ImportResult) -> list[tuple[str, str]]:
    params = load_config(result.config).config.hardware["twin"].params
    return [tuple(pair) for pair in params.get("exclude_contacts", [])]  # type: ignore[misc]


def test_self_overlapping_collision_meshes_neither_jam_nor_kick_the_twin(tmp_path: Path) -> None:
    """The turntable sits 2 mm into the base block (adjacent links; the base is welded to the world, so MuJoCo's
    parent filter does not apply) and the upper arm's clevis hull covers both: on the old twin the pan joint stuck
    on the base's friction and the goal aborted on path tolerance."""
    result = meshes(tmp_path)
    adjacent = [("base_link", "turntable"), ("turntable", "upper_arm"), ("upper_arm", "forearm"), ("upper_arm", "tool")]
    assert excluded(result) == [*adjacent, ("base_link", "upper_arm")]  # the tool is welded to the forearm
    approximated = [f.text for f in result.report.of("approximated")]
    assert "joint 'pan': the twin ignores contacts between the links it joins: base_link–turntable" in approximated
    assert "joint 'elbow': the twin ignores contacts between the links it joins: upper_arm–forearm, upper_arm–tool" in (
        approximated
    )
    (overlap,) = [t for t in approximated if "links 'base_link' and 'upper_arm'" in t]
    assert re.search(r"overlap by [\d.]+ mm at the start pose: the twin ignores their contacts", overlap)
    hold_then_move(result, JOINTS)


def test_self_contacts_can_be_kept_but_adjacent_links_never_collide(tmp_path: Path) -> None:
    result = meshes(tmp_path, keep_self_contacts=True)
    assert ("base_link", "upper_arm") not in excluded(result)
    assert ("base_link", "turntable") in excluded(result)
    assert any(
        "links 'base_link' and 'upper_arm' overlap" in f.text and "contacts kept" in f.text
        for f in result.report.of("approximated")
    )


def test_contact_with_the_world_is_kept(tmp_path: Path) -> None:
    """A post fixed to the world beside the arm is not part of the robot: the forearm swinging into it stops."""
    post = (
        '  <joint name="post_joint" type="fixed"><parent link="world"/><child link="post"/>'
        '<origin xyz="0.3 -0.28 0.2"/></joint>\n'
        '  <link name="post"><collision><geometry><box size="0.05 0.05 0.4"/></geometry></collision></link>\n'
        "  <ros2_control"
    )
    urdf = tmp_path / "arm3" / "urdf" / "arm3.urdf.xacro"
    urdf.parent.mkdir(parents=True)
    urdf.write_text(XACRO.read_text().replace("  <ros2_control", post, 1))
    (tmp_path / "arm3" / "meshes").symlink_to(ARM3 / "meshes")
    result = import_robot(urdf, CLASSIC, tmp_path / "out" / "arm3.yaml", xacro_args={"collision": "mesh"})
    assert not any("post" in pair for pair in excluded(result))
    engine = lockstep(result.config)
    pan = engine.joints.index("pan")
    outcome = run_goal(engine, "arm_controller", waypoints(JOINTS, engine.state.position.copy(), [[-1.2, 0, 0]]))
    assert outcome.status != "succeeded"  # the post is in the way
    assert engine.state.position[pan] > -1.0


# ---- cause 4: an inertia MuJoCo refuses ------------------------------------------------------------------------
def with_xacro(tmp_path: Path, old: str, new: str) -> Path:
    """The arm3 xacro with one edit, in a package directory of its own (meshes linked)."""
    text = XACRO.read_text()
    assert old in text
    urdf = tmp_path / "arm3" / "urdf" / "arm3.urdf.xacro"
    urdf.parent.mkdir(parents=True)
    urdf.write_text(text.replace(old, new, 1))
    (tmp_path / "arm3" / "meshes").symlink_to(ARM3 / "meshes")
    return urdf


TOOL_INERTIA = '<xacro:inertial mass="0.2" x="0" ixx="7.2e-05" iyy="7.2e-05" izz="7.2e-05"/>'


def test_an_inertia_mujoco_would_refuse_is_balanced_with_a_finding(tmp_path: Path) -> None:
    """The tool's izz is more than ixx + iyy (a typo, or a CAD export in the wrong frame): MuJoCo refuses such a
    body unless told to balance it, which sets all three moments to their mean."""
    urdf = with_xacro(tmp_path, TOOL_INERTIA, TOOL_INERTIA.replace('izz="7.2e-05"', 'izz="4e-4"'))
    result = import_robot(urdf, CLASSIC, tmp_path / "out" / "arm3.yaml")
    (finding,) = [f for f in result.report.of("approximated") if "A + B ≥ C" in f.text]
    assert finding.text == (
        "link 'tool': principal moments of inertia 7.2e-05, 7.2e-05, 0.0004 break A + B ≥ C, which MuJoCo refuses: "
        "the twin balances them (each becomes their mean, 0.0001813)"
    )
    lines = result.urdf.read_text().splitlines()
    assert 'izz="0.0004"' in lines[finding.where.line - 1]  # the <inertia> element in the expansion
    assert 'balanceinertia="true"' in next(line for line in lines if "<compiler" in line)
    hold_then_move(result, JOINTS)


def test_an_inertia_the_urdf_forbids_balancing_is_refused_at_its_line(tmp_path: Path) -> None:
    """Without balancing, the error names the source's own file and line and the link, never a staging file."""
    text = (ROBOTS / "rrbot" / "rrbot.urdf").read_text()
    start = text.index("<inertia ", text.index('<link name="link1">'))
    end = text.index("/>", start) + 2
    text = text[:start] + '<inertia ixx="0.001" ixy="0" ixz="0" iyy="0.001" iyz="0" izz="0.01"/>' + text[end:]
    text = text.replace(
        '<robot name="rrbot">', '<robot name="rrbot"><mujoco><compiler balanceinertia="false"/></mujoco>'
    )
    urdf = tmp_path / "rrbot.urdf"
    urdf.write_text(text)
    out = tmp_path / "out"
    with pytest.raises(ImportFailure) as info:
        import_robot(urdf, ROBOTS / "rrbot" / "rrbot_controllers.yaml", out / "rrbot.yaml")
    line = next(i for i, t in enumerate(text.splitlines(), 1) if 'izz="0.01"' in t)
    assert str(info.value) == (
        f"{urdf}:{line}: link 'link1': principal moments of inertia 0.001, 0.001, 0.01 break A + B ≥ C, which MuJoCo "
        'refuses (this URDF sets <compiler balanceinertia="false">): fix the <inertia>'
    )
    assert not out.exists()


# ---- cause 5: a joint that starts on its hard limit ------------------------------------------------------------
def test_a_start_on_or_just_beyond_a_limit_holds_and_the_report_says_so(tmp_path: Path) -> None:
    """The elbow is parked on its lower limit with gravity pressing it into the stop; the pan's calibrated rest is
    0.5 mrad beyond its upper limit (the twin cannot start there: it starts on the limit)."""
    urdf = with_xacro(
        tmp_path, '<xacro:arm_joint name="elbow" initial="0.5"/>', '<xacro:arm_joint name="elbow" initial="-2.0"/>'
    )
    urdf.write_text(
        urdf.read_text().replace(
            '<xacro:arm_joint name="pan" initial="0.0"/>', '<xacro:arm_joint name="pan" initial="2.8005"/>'
        )
    )
    result = import_robot(urdf, CLASSIC, tmp_path / "out" / "arm3.yaml")
    assert load_config(result.config).config.hardware["twin"].params["initial_positions"] == {
        "pan": 2.8,
        "shoulder": 0.0,
        "elbow": -2.0,
    }
    approximated = [f.text for f in result.report.of("approximated")]
    assert (
        "pan: initial_value 2.8005 is 0.0005 beyond the upper limit 2.8: the twin starts on the limit; a joint "
        "resting on its end stop holds (readings within safety.plausibility.margin 0.05 of a limit are accepted)"
    ) in approximated
    assert (
        "elbow: initial_value -2 is on the lower limit: a joint resting on its end stop holds (readings within "
        "safety.plausibility.margin 0.05 of a limit are accepted)"
    ) in approximated
    hold_then_move(result, JOINTS, [[-0.3, 0.2, 0.5], [-0.5, 0.1, 0.3]])


def test_a_start_far_beyond_a_limit_is_still_an_error(tmp_path: Path) -> None:
    urdf = with_xacro(
        tmp_path, '<xacro:arm_joint name="pan" initial="0.0"/>', '<xacro:arm_joint name="pan" initial="2.9"/>'
    )
    with pytest.raises(
        ImportFailure,
        match=r"joint .pan.: initial_value 2.9 is outside \[-2.8, 2.8\] by more than the plausibility margin 0.05",
    ):
        import_robot(urdf, CLASSIC, tmp_path / "out" / "arm3.yaml")


def test_a_zero_pose_outside_the_limits_starts_the_twin_on_the_nearest_limit(tmp_path: Path) -> None:
    """rrbot's joint1 without an initial_value and with a range that excludes 0: the twin used to start at 0, a
    reading beyond the limit by more than the margin, and the joint faulted at once."""
    text = (
        (ROBOTS / "rrbot" / "rrbot.urdf")
        .read_text()
        .replace('lower="-3.1416" upper="3.1416"', 'lower="0.3" upper="3.1416"')
    )
    urdf = tmp_path / "rrbot.urdf"
    urdf.write_text(text)
    result = import_robot(urdf, ROBOTS / "rrbot" / "rrbot_controllers.yaml", tmp_path / "out" / "rrbot.yaml")
    assert load_config(result.config).config.hardware["twin"].params["initial_positions"] == {"joint1": 0.3}
    assert any(
        f.text == "joint1: no initial_value, and the zero pose is outside [0.3, 3.142]: the twin starts on the "
        "nearest limit, 0.3"
        for f in result.report.of("approximated")
    )
    hold_then_move(result, ["joint1", "joint2"], [[0.4, -0.3], [0.2, 0.2]])


# ---- cause 7: smaller surprises ----------------------------------------------------------------------------------
@pytest.mark.parametrize("variant", ["primitive", "mesh"])
def test_imported_defaults_pass_hild_check_without_warnings(tmp_path: Path, variant: str) -> None:
    result = import_robot(XACRO, CLASSIC, tmp_path / "arm3.yaml", xacro_args={"collision": variant})
    assert checked(result) == []
    assert not any("initial_value of" in f.text for f in result.report.findings)  # 0 for velocity/effort: silent


def test_my_arm_defaults_pass_hild_check_without_warnings(tmp_path: Path) -> None:
    urdf, controllers = MY_ARM / "urdf" / "my_arm.urdf.xacro", MY_ARM / "config" / "my_arm_controllers.yaml"
    result = import_robot(urdf, controllers, tmp_path / "arm.yaml", allow_partial=True)
    assert checked(result) == []


def test_check_warnings_about_the_users_own_gains_name_them(tmp_path: Path) -> None:
    """rrbot's hold gains are its effort PID (p 400, d 60): hild check finds them stiff for the effort limit. The
    warning is about the user's numbers, so the import report carries it at the PID's own line."""
    controllers = ROBOTS / "rrbot" / "rrbot_controllers.yaml"
    result = import_robot(ROBOTS / "rrbot" / "rrbot.urdf", controllers, tmp_path / "rrbot.yaml")
    warnings = checked(result)
    assert warnings and all(".hold: kp " in w for w in warnings), warnings
    pid_line = next(i for i, t in enumerate(controllers.read_text().splitlines(), 1) if "joint1: {p: 400.0" in t)
    relayed = [f for f in result.report.of("approximated") if f.text.startswith("hild check warns: joints.joint1")]
    assert [str(f.where) for f in relayed] == [f"{controllers}:{pid_line}"]
    assert "from your PID gains of joint_trajectory_controller" in relayed[0].text
    text = result.config.read_text()
    assert (
        f"hold: {{kp: 400, kd: 60}}  # kp, kd: PID of joint_trajectory_controller (rrbot_controllers.yaml:{pid_line})"
        in (text)
    )


MOCK_HARDWARE = "      <plugin>mock_components/GenericSystem</plugin>\n"
DAMIAO_HARDWARE = """      <plugin>arm3_hardware/Arm3DamiaoSystem</plugin>
      <param name="can_interface">can1</param>
      <param name="can_fd">true</param>
"""


def uncommented_can_template(result: ImportResult, tmp_path: Path) -> Path:
    """The written config with its commented CAN section in place of the twin (what a user does on hardware)."""
    text = result.config.read_text()
    head, template = text.split("# hardware:\n")
    hardware = "hardware:\n" + "\n".join(line.removeprefix("# ") for line in template.splitlines())
    twin = re.search(r"^hardware:\n(?:  .*\n|\n)*?(?=^joints:)", head, re.M)
    assert twin is not None
    can = result.config.with_name("on_can.yaml")
    can.write_text(head.replace(twin.group(0), hardware + "\n"))
    return can


def check_errors(config: Path) -> list[str]:
    """`hild check`'s errors (the keys and messages), or [] when it passes."""
    try:
        check_with_model(load_config(config))
    except ConfigError as exc:
        return [f"{e.path}: {e.message}" for e in exc.issues]
    return []


def test_the_can_template_carries_the_descriptions_interface_fd_and_motor_models(tmp_path: Path) -> None:
    urdf = with_xacro(tmp_path, MOCK_HARDWARE, DAMIAO_HARDWARE)
    models = {"pan": "DM8009", "shoulder": "DM8009", "elbow": "DM4340"}
    text = urdf.read_text()
    for joint, model in models.items():
        old = f'<xacro:arm_joint name="{joint}" initial='
        text = text.replace(old, f'<xacro:arm_joint name="{joint}" model="{model}" initial=')
    text = text.replace(
        '<xacro:macro name="arm_joint" params="name initial">\n      <joint name="${prefix}${name}">',
        '<xacro:macro name="arm_joint" params="name model initial">\n      <joint name="${prefix}${name}">\n'
        '        <param name="motor_type">${model}</param>',
    )
    urdf.write_text(text)
    result = import_robot(urdf, CLASSIC, tmp_path / "out" / "arm3.yaml")
    written = result.config.read_text()
    assert "#       bus: {interface: socketcan, channel: can1, fd: true}" in written
    assert "#       flavour: damiao" in written
    assert re.search(
        r"#         pan: \{id: 0x01, reply_id: 0x11, model: DM8009\}  # model: arm3\.urdf:\d+; TODO", written
    )
    mapped = [f.text for f in result.report.of("mapped")]
    assert "hardware param can_interface='can1' → CAN template bus channel" in mapped
    assert "hardware param can_fd='true' → CAN template bus fd" in mapped
    assert "elbow: param motor_type='DM4340' → CAN template motor model" in mapped
    # What `hild check` says once it is uncommented: bus and motors are valid; the twin's hold gains on the direct
    # drives of this arm (no gearbox) exceed a Damiao drive's kd range, and check says so for each joint.
    can = uncommented_can_template(result, tmp_path)
    errors = check_errors(can)
    assert errors and all(re.match(r"joints\.\w+\.hold\.kd: .* above the drive's range 0\.\.5", e) for e in errors), (
        errors
    )
    section = yaml.safe_load(can.read_text())["hardware"]["arm3system"]["params"]
    assert section["bus"] == {"interface": "socketcan", "channel": "can1", "fd": True}
    assert {j: m["model"] for j, m in section["motors"].items()} == models


def test_the_can_template_says_what_to_fill_in_when_the_description_does_not_say(tmp_path: Path) -> None:
    result = import_robot(XACRO, CLASSIC, tmp_path / "arm3.yaml")
    written = result.config.read_text()
    assert "channel: can0, bitrate: 1000000}  # TODO: your CAN interface (the description names none)" in written
    assert "flavour: damiao  # TODO: damiao | tmotor | myactuator (the description names no motor model)" in written
    assert re.search(r"pan: \{id: 0x01, reply_id: 0x11, model: DM4340\}  # TODO: id, reply_id, model", written)
    errors = check_errors(uncommented_can_template(result, tmp_path))
    assert all(".hold.kd: " in e for e in errors), errors  # only the gains to tune for the drive
