"""ros2_canopen descriptions → the ``cia402`` section: what maps, how it scales, and what is reported by name.

The fixture robot (robots/canopen_arm) is laid out as ros2_canopen's own canopen_tests robot_control example:
a xacro ``<ros2_control>`` with ``canopen_ros2_control/RobotSystem``, a flat bus.yml, a controllers YAML with
Cia402RobotController. hild's generic EDS stands in for the drives' DCF.
"""

from __future__ import annotations

import math
import shutil
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from drivers.can.cia402.wiring import wire_drives
from drivers.can.params import Cia402Params
from hild import plugins
from hild.config import load_config
from hild.config.documents import load_document
from hild.config.model import Transmission
from hild.config.params import Params
from hild.cycle.transmission import Transmissions
from hild.hardware import Finding, HardwareComponent
from hild.importers.ros2_control.importer import ImportResult
from hild.importers.ros2_control.report import ImportFailure
from tests.conftest import REPO
from tests.importers.helpers import ROBOTS, import_robot

CANOPEN_ARM = ROBOTS / "canopen_arm"
EDS = REPO / "configs" / "cia402_generic.eds"
HEADING = "# ---- On the CiA 402 drives"


def robot(tmp_path: Path) -> Path:
    """A writable copy of canopen_arm with the generic EDS beside its bus.yml (where its dcf names it)."""
    target = tmp_path / "canopen_arm"
    shutil.copytree(CANOPEN_ARM, target)
    shutil.copy(EDS, target / "config" / "robot_control" / "cia402_generic.eds")
    return target


def bus_yml(arm: Path) -> Path:
    return arm / "config" / "robot_control" / "bus.yml"


def edit(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text, old
    path.write_text(text.replace(old, new, 1))


def run_import(arm: Path, tmp_path: Path, controllers: Path | None = None, **options: Any) -> ImportResult:
    return import_robot(
        arm / "urdf" / "canopen_arm.urdf.xacro",
        controllers or arm / "config" / "ros2_controllers.yaml",
        tmp_path / "out" / "arm.yaml",
        package_roots={"canopen_arm": arm},
        tracking_check=False,
        **options,
    )


def section(config: Path) -> dict[str, Any]:
    """The commented cia402 section of the written config, uncommented and parsed (as a user would)."""
    lines = config.read_text().splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(HEADING))
    body = [line[2:] for line in lines[start:] if line.startswith("# ") and not line.startswith("# ----")]
    data = load_document(config, "\n".join(body))
    (component,) = data["hardware"].values()
    return component


def findings(result: ImportResult, kind: str) -> str:
    return "\n".join(f"{f.where}: {f.text}" for f in result.report.of(kind))  # type: ignore[arg-type]


def test_robot_system_becomes_a_cia402_section_that_validates_and_scales_as_ros2_canopen(tmp_path: Path) -> None:
    arm = robot(tmp_path)
    result = run_import(arm, tmp_path)
    component = section(result.config)
    assert component["driver"] == "cia402"
    params = Cia402Params.model_validate(component["params"])
    assert params.bus.channel == "can0" and params.bus.bitrate == 500_000  # can_interface_name, baudrate 500 kbit/s
    assert params.mode == "csp" and params.heartbeat_ms == 50
    assert (result.config.parent / params.eds).resolve() == bus_yml(arm).parent / "cia402_generic.eds"
    wiring, problems = wire_drives(params, ["joint1", "joint2"], result.config.parent)
    assert problems == []
    one, two = wiring
    assert (one.node_id, two.node_id) == (2, 3)
    # scale_pos_to_dev is device units per rad: exactly hild's counts_per_rad
    assert one.counts_per_rad == pytest.approx(20860.76, rel=1e-12)
    assert one.velocity_per_rad_s == pytest.approx(20860.76, rel=1e-12)
    assert one.rated_torque == pytest.approx(10.0)  # 1000 × scale_eff_from_dev 0.01
    assert two.counts_per_rad == pytest.approx(1000.0, rel=1e-12)
    assert two.velocity_per_rad_s == pytest.approx(500.0, rel=1e-12)  # |scale_vel_to_dev|
    assert two.rated_torque == pytest.approx(10.0)  # no scale_eff_from_dev: the EDS's 0x6076 (10 N·m)
    drive = params.drives["joint1"]
    assert drive.following_error_window == pytest.approx(2086 / 20860.76)
    assert drive.homing is not None and drive.homing.method == 35 and drive.homing.timeout == 20
    assert params.drives["joint2"].homing is not None and params.drives["joint2"].homing.method == 37  # EDS default
    joints = {name: Transmission.model_validate(spec) for name, spec in component["joints"].items()}
    assert joints["joint1"] == Transmission()
    assert (joints["joint2"].direction, joints["joint2"].offset) == (-1, 0.25)


def test_scaling_round_trips_ros2_canopens_formulas(tmp_path: Path) -> None:
    """Device units → joint (ros2_canopen: d·scale_pos_from_dev + offset_pos_from_dev) and joint → device
    (q·scale_pos_to_dev + offset_pos_to_dev) agree with hild's wiring and transmission for both joints."""
    result = run_import(robot(tmp_path), tmp_path)
    component = section(result.config)
    params = Cia402Params.model_validate(component["params"])
    wiring, _ = wire_drives(params, ["joint1", "joint2"], result.config.parent)
    ros = {"joint1": (20860.76, 4.793689e-05, 0.0, 0.0), "joint2": (-1000.0, -0.001, 250.0, 0.25)}
    for w in wiring:
        to_dev, from_dev, off_to, off_from = ros[w.joint]
        spec = Transmission.model_validate(component["joints"][w.joint])
        tx = Transmissions(np.array([spec.reduction]), np.array([spec.direction]), np.array([spec.offset]))
        for device in (-52_000.0, -3.0, 0.0, 417.0, 131_072.0):
            joint = np.empty(1)
            tx.joint_positions(np.array([device / w.counts_per_rad]), joint)
            assert joint[0] == pytest.approx(device * from_dev + off_from, rel=1e-6, abs=1e-9)
        for q in (-2.5, -0.1, 0.0, 0.7, 2.9):
            actuator = np.empty(1)
            tx.actuator_positions(np.array([q]), actuator)
            assert actuator[0] * w.counts_per_rad == pytest.approx(q * to_dev + off_to, rel=1e-12, abs=1e-9)
            velocity = np.empty(1)
            tx.actuator_velocities(np.array([q]), velocity)
            vel_to = {"joint1": 20860.76, "joint2": -500.0}[w.joint]
            assert velocity[0] * w.velocity_per_rad_s == pytest.approx(q * vel_to, rel=1e-12)


def test_report_names_what_maps_and_what_hild_does_instead(tmp_path: Path) -> None:
    result = run_import(robot(tmp_path), tmp_path)
    mapped, approximated = findings(result, "mapped"), findings(result, "approximated")
    unsupported = findings(result, "unsupported")
    assert "bus.yml:21: joint1: position_mode 8 → mode csp" in mapped
    assert "velocity_mode 9 (csv) not used: hild runs one mode per drive" in approximated
    assert "master sync_period 10000 µs → SYNC every 10000 µs = 1 / update_rate" in mapped
    assert "joint1: tpdo layout replaced by hild's own" in approximated
    assert "joint1: rpdo layout replaced by hild's own" in approximated
    assert "Cia402RobotController): not needed" in approximated
    assert (
        "ros2_canopen homes every drive on init; hild homes only on an explicit `hild ctl home joint1`" in approximated
    )
    # each sdo write at its own line: 0x6081 (profile velocity) is the 5th entry, on line 35
    assert "bus.yml:35: joint1: sdo 0x6081:0 = 1000 (profile velocity" in unsupported
    assert "revision_number: hild does not check the drive's identity" in unsupported
    assert "hardware param" not in unsupported  # bus_config, master_config, can_interface_name, master_bin: read
    assert result.report.partial == []  # the twin config itself is complete


def test_cia402_system_with_cogen_defaults_and_nodes(tmp_path: Path) -> None:
    """Cia402System finds devices by <param name="node_id">; the bus.yml in cogen's layout (defaults + nodes, as
    canopen_tests/config/cia402_system/bus.yml) has its defaults copied over each node, as cogen.py does."""
    arm = robot(tmp_path)
    edit(
        arm / "urdf" / "canopen_arm.ros2_control.xacro",
        "canopen_ros2_control/RobotSystem",
        "canopen_ros2_control/Cia402System",
    )
    ros2_control = arm / "urdf" / "canopen_arm.ros2_control.xacro"
    edit(ros2_control, '<param name="device_name">joint_1</param>', '<param name="node_id">2</param>')
    edit(ros2_control, '<param name="device_name">joint_2</param>', '<param name="node_id">3</param>')
    bus_yml(arm).write_text(
        "# cogen layout, as ros2_canopen's canopen_tests/config/cia402_system/bus.yml\n"
        'options:\n  dcf_path: "@BUS_CONFIG_PATH@"\n'
        'master:\n  node_id: 1\n  driver: "ros2_canopen::MasterDriver"\n  package: "canopen_master_driver"\n'
        "  sync_period: 20000\n"
        'defaults:\n  dcf: "cia402_generic.eds"\n  driver: "ros2_canopen::Cia402Driver"\n'
        '  package: "canopen_402_driver"\n  period: 10\n  scale_pos_to_dev: 2000.0\n  scale_pos_from_dev: 0.0005\n'
        "nodes:\n  cia402_device_1:\n    node_id: 2\n  cia402_device_2:\n    node_id: 3\n"
        "    scale_pos_to_dev: 4000.0\n"
    )
    result = run_import(arm, tmp_path)
    params = Cia402Params.model_validate(section(result.config)["params"])
    wiring, problems = wire_drives(params, ["joint1", "joint2"], result.config.parent)
    assert problems == []
    assert [w.counts_per_rad for w in wiring] == [pytest.approx(2000.0), pytest.approx(2000.0)]  # defaults win
    assert [w.mode for w in wiring] == ["csp", "csp"]
    approximated = findings(result, "approximated")
    assert "scale_pos_to_dev 4000.0 is overridden by defaults' 2000.0" in approximated
    assert "which the bus.yml gives no cyclic mode → mode csp" in approximated
    assert "sync_period: the bus.yml's SYNC came every 20000 µs (50 Hz); hild sends it once per cycle" in approximated
    assert "no heartbeat_producer (ros2_canopen's default 0: none)" in approximated
    assert "Cia402System (ros2_canopen, CiA 402) → the commented cia402 section" in findings(result, "mapped")


@pytest.mark.parametrize(
    ("old", "new", "named"),
    [
        (
            "position_mode: 8\n  heartbeat_producer: 50\n  scale_pos_to_dev: -1000.0",
            "position_mode: 1\n  heartbeat_producer: 50\n  scale_pos_to_dev: -1000.0",
            "position_mode 1 (profile position): hild drives the cyclic synchronous modes only",
        ),
        (
            "position_mode: 8\n  heartbeat_producer: 50\n  scale_pos_to_dev: -1000.0",
            "position_mode: 7\n  heartbeat_producer: 50\n  scale_pos_to_dev: -1000.0",
            "position_mode 7 (interpolated position)",
        ),
        (
            "node_id: 3\n",
            "num_channels: 2\n  node_id: 3\n",
            "CiA 402-2 multi-channel device: hild drives one axis per node",
        ),
        (
            "  node_id: 3\n",
            "",
            "has no node_id: hild needs a fixed node id 1..127 (LSS and node ids taken from the DCF",
        ),
        (
            'joint_2:\n  node_id: 3\n  dcf: "cia402_generic.eds"\n  driver: "ros2_canopen::Cia402Driver"',
            'joint_2:\n  node_id: 3\n  dcf: "cia402_generic.eds"\n  driver: "ros2_canopen::ProxyDriver"',
            "uses a CiA 301 proxy driver: not a CiA 402 drive",
        ),
        (
            "master:\n",
            'master2:\n  node_id: 5\n  driver: "ros2_canopen::MasterDriver"\n  dcf: "cia402_generic.eds"\nmaster:\n',
            "is a second master on this bus",
        ),
        (
            "  sync_period: 10000\n",
            "  sync_period: 10000\n  heartbeat_producer: 100\n",
            "master heartbeat_producer: hild produces no heartbeat of its own",
        ),
    ],
    ids=["profile_position", "interpolated", "multi_channel", "lss", "proxy_driver", "two_masters", "master_heartbeat"],
)
def test_each_unsupported_feature_is_reported_by_name(tmp_path: Path, old: str, new: str, named: str) -> None:
    arm = robot(tmp_path)
    edit(bus_yml(arm), old, new)
    result = run_import(arm, tmp_path)
    assert named in findings(result, "unsupported")
    component = section(result.config)  # what is left still validates
    Cia402Params.model_validate(component["params"])


def test_two_blocks_on_one_can_interface_are_two_masters(tmp_path: Path) -> None:
    arm = robot(tmp_path)
    ros2_control = arm / "urdf" / "canopen_arm.ros2_control.xacro"
    text = ros2_control.read_text()
    hardware = text[text.index("      <hardware>") : text.index("      </hardware>") + len("      </hardware>\n")]
    second = f'    </ros2_control>\n    <ros2_control name="${{name}}_wrist" type="system">\n{hardware}'
    edit(ros2_control, '      <joint name="${prefix}joint2">', second + '      <joint name="${prefix}joint2">')
    result = run_import(arm, tmp_path)
    assert "'canopen_arm_wrist' is a second master on CAN interface can0" in findings(result, "unsupported")
    assert result.config.read_text().count(HEADING) == 2  # each block still gets its component, to merge by hand
    lines = result.config.read_text().splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(HEADING))
    body = [line[2:] for line in lines[start:] if line.startswith("# ") and not line.startswith("# ----")]
    hardware = load_document(result.config, "\n".join(body))["hardware"]  # one hardware: for both, as YAML needs
    assert {n: list(c["params"]["drives"]) for n, c in hardware.items()} == {
        "canopen_arm": ["joint1"],
        "canopen_arm_wrist": ["joint2"],
    }


def test_a_joint_left_out_is_a_todo_in_the_section(tmp_path: Path) -> None:
    arm = robot(tmp_path)
    edit(
        bus_yml(arm),
        'driver: "ros2_canopen::Cia402Driver"\n  package: "canopen_402_driver"\n  period: 10\n  position_mode: 8\n'
        "  heartbeat",
        'driver: "ros2_canopen::ProxyDriver"\n  package: "canopen_proxy_driver"\n  period: 10\n  position_mode: 8\n'
        "  heartbeat",
    )
    result = run_import(arm, tmp_path)
    component = section(result.config)
    assert list(component["params"]["drives"]) == ["joint1"]
    assert "#   # TODO: joint2: joint_2 is a CiA 301 proxy driver (not CiA 402)" in result.config.read_text()


def test_effort_controller_runs_the_effort_mode(tmp_path: Path) -> None:
    arm = robot(tmp_path)
    edit(bus_yml(arm), "position_mode: 8\n  velocity_mode: 9\n", "position_mode: 8\n  effort_mode: 10\n")
    edit(
        arm / "config" / "ros2_controllers.yaml",
        "command_interfaces:\n      - position",
        "command_interfaces:\n      - effort",
    )
    result = run_import(arm, tmp_path)
    params = Cia402Params.model_validate(section(result.config)["params"])
    wiring, problems = wire_drives(params, ["joint1", "joint2"], result.config.parent)
    assert problems == []
    # joint2's bus.yml has no effort mode: it keeps its cyclic position mode, and says so
    assert [w.mode for w in wiring] == ["cst", "csp"]
    assert "joint1: effort_mode 10 → mode cst" in findings(result, "mapped")
    assert "joint2: hild's controllers command effort, which the bus.yml gives no cyclic mode → mode csp" in (
        findings(result, "approximated")
    )


def test_canopen_system_is_not_a_drive(tmp_path: Path) -> None:
    arm = robot(tmp_path)
    edit(
        arm / "urdf" / "canopen_arm.ros2_control.xacro",
        "canopen_ros2_control/RobotSystem",
        "canopen_ros2_control/CanopenSystem",
    )
    result = run_import(arm, tmp_path)
    assert "CanopenSystem: ros2_canopen's CiA 301 system" in findings(result, "unsupported")
    assert HEADING not in result.config.read_text()


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (("bus_yml", 'dcf: "cia402_generic.eds"', 'dcf: "missing.eds"'), "dcf 'missing.eds': no such file"),
        (("bus_yml", "joint_2:\n", "joint_9:\n"), "device_name 'joint_2' is not a device of"),
        (("xacro", "/config/robot_control/bus.yml", "/config/nowhere/bus.yml"), "bus_config"),
        (
            ("xacro", 'can_interface_name="$(arg can_interface_name)"', 'can_interface_name=""'),
            "can_interface_name is empty",
        ),
    ],
    ids=["missing_dcf", "unknown_device", "missing_bus_yml", "no_can_interface"],
)
def test_bad_input_is_a_clear_error_and_writes_nothing(
    tmp_path: Path, change: tuple[str, str, str], message: str
) -> None:
    arm = robot(tmp_path)
    where, old, new = change
    edit(bus_yml(arm) if where == "bus_yml" else arm / "urdf" / "canopen_arm.urdf.xacro", old, new)
    with pytest.raises(ImportFailure, match=message.replace("(", r"\(")):
        run_import(arm, tmp_path)
    assert not (tmp_path / "out").exists()


def test_missing_bus_yml_names_the_file(tmp_path: Path) -> None:
    arm = robot(tmp_path)
    bus_yml(arm).unlink()
    with pytest.raises(ImportFailure, match=rf"no such file {bus_yml(arm)}"):
        run_import(arm, tmp_path)


def test_the_uncommented_section_loads_as_a_config(tmp_path: Path) -> None:
    """Replacing the twin with the cia402 section gives a config `hild check`'s loader accepts."""
    result = run_import(robot(tmp_path), tmp_path)
    text = result.config.read_text()
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(HEADING))
    hardware = [line[2:] for line in lines[start:] if line.startswith("# ") and not line.startswith("# ----")]
    head = lines[: lines.index("hardware:")]
    rest = lines[lines.index("hardware:") + 1 :]
    tail = rest[next(i for i, line in enumerate(rest) if line and not line.startswith(" ")) :]
    config = tmp_path / "out" / "real.yaml"
    config.write_text("\n".join([*head, *hardware, *tail[: tail.index("") if "" in tail else len(tail)]]) + "\n")
    loaded = load_config(config)
    assert loaded.config.hardware["canopen_arm"].driver == "cia402"
    assert isinstance(loaded.driver_params["canopen_arm"], Cia402Params)
    assert math.isclose(loaded.config.update_rate, 100.0)


class _ReviewingCia402(HardwareComponent):
    """Stands in for the cia402 driver in the loader: its params model and a review through wire_drives (the EDS
    paths of the checked config are absolute), so the importer's relay of `hild check` can be tested here."""

    Params = Cia402Params

    @classmethod
    def review(cls, params: Params, joints: Sequence[str], update_rate: float) -> list[Finding]:
        assert isinstance(params, Cia402Params)
        _, problems = wire_drives(params, joints, Path("/"))
        return [Finding("error", p) for p in problems]

    def read(self, t: float, dt: float, state: Any) -> None:  # pragma: no cover - never run
        raise NotImplementedError

    def write(self, t: float, dt: float, command: Any) -> None:  # pragma: no cover - never run
        raise NotImplementedError


@pytest.fixture
def reviewing_driver(monkeypatch: pytest.MonkeyPatch) -> None:
    real = plugins.load

    def load(group: str, name: str) -> Any:
        return _ReviewingCia402 if (group, name) == (plugins.DRIVERS, "cia402") else real(group, name)

    monkeypatch.setattr(plugins, "load", load)


def test_without_a_cia402_driver_the_section_is_said_to_be_unchecked(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An install without the cia402 driver (another driver set): the import says the section went unchecked."""
    real = plugins.load

    def load(group: str, name: str) -> Any:
        if (group, name) == (plugins.DRIVERS, "cia402"):
            raise plugins.PluginError("unknown driver 'cia402' (known: mock, mujoco_twin)")
        return real(group, name)

    monkeypatch.setattr(plugins, "load", load)
    result = run_import(robot(tmp_path), tmp_path)
    assert "cia402 section not checked: no cia402 driver is installed" in findings(result, "approximated")


@pytest.mark.usefixtures("reviewing_driver")
def test_the_section_is_checked_as_hild_check_does(tmp_path: Path) -> None:
    result = run_import(robot(tmp_path), tmp_path)
    assert "cia402 section: passes `hild check` in place of the twin" in findings(result, "mapped")


@pytest.mark.usefixtures("reviewing_driver")
def test_what_the_driver_refuses_is_reported(tmp_path: Path) -> None:
    """A drive whose EDS lacks the mode the bus.yml asks for: the driver's review says so, the import reports it."""
    arm = robot(tmp_path)
    eds = bus_yml(arm).parent / "cia402_generic.eds"
    edit(eds, "DefaultValue=0x3A0", "DefaultValue=0x120")  # 0x6502: homing and CSV only, no CSP
    result = run_import(arm, tmp_path)
    unsupported = findings(result, "unsupported")
    assert "cia402 section: hild check refuses it:" in unsupported
    assert (
        "refuses it: hardware.canopen_arm.params: joint1: the drive's EDS (cia402_generic.eds) does not list csp"
        in (unsupported)
    )
    assert result.config.exists()  # a template the import reports on, not a reason to write nothing


@pytest.mark.parametrize(
    "form",
    ["package://canopen_arm/config/robot_control/bus.yml", "../config/robot_control/bus.yml"],
    ids=["package_uri", "relative_to_the_urdf"],
)
def test_bus_config_forms_resolve_like_the_urdfs_other_paths(tmp_path: Path, form: str) -> None:
    arm = robot(tmp_path)
    edit(arm / "urdf" / "canopen_arm.urdf.xacro", "$(find canopen_arm)/config/robot_control/bus.yml", form)
    result = run_import(arm, tmp_path)
    assert f"bus_config → {bus_yml(arm).resolve()}" in findings(result, "mapped")


def test_ros2_canopens_own_robot_control_bus_yml(tmp_path: Path) -> None:
    """ros2_canopen's robot_control example as it is: profile position (1) everywhere, 0x6060 := 7 (interpolated)
    in its sdo list, no scales (ros2_canopen's default thousandths), switching_state, PDO blocks."""
    arm = robot(tmp_path)
    original = arm / "config" / "ros2_canopen_robot_control"
    shutil.copy(EDS, original / "cia402_slave.eds")
    edit(
        arm / "urdf" / "canopen_arm.urdf.xacro",
        "/config/robot_control/bus.yml",
        "/config/ros2_canopen_robot_control/bus.yml",
    )
    result = run_import(arm, tmp_path)
    unsupported, approximated = findings(result, "unsupported"), findings(result, "approximated")
    assert unsupported.count("position_mode 1 (profile position): hild drives the cyclic synchronous modes only") == 2
    assert "0x6083:0 = 2000 (profile acceleration" in unsupported
    assert "sdo 0x6060:0 = 7 (mode of operation): the mode hild sets itself" in approximated
    assert "switching_state: not needed" in approximated
    assert "no scale_pos_to_dev: ros2_canopen's default 1000 device units per rad" in approximated
    params = Cia402Params.model_validate(section(result.config)["params"])
    wiring, problems = wire_drives(params, ["joint1", "joint2"], result.config.parent)
    assert problems == []
    assert [(w.node_id, w.mode, w.counts_per_rad, w.velocity_per_rad_s) for w in wiring] == [
        (2, "csp", pytest.approx(1000.0), pytest.approx(1000.0)),
        (3, "csp", pytest.approx(1000.0), pytest.approx(1000.0)),
    ]
