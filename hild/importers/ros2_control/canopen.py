"""ros2_canopen's CiA 402 hardware (``canopen_ros2_control/RobotSystem``, ``/Cia402System``) → a ``cia402`` section.

A ros2_canopen ``<ros2_control>`` block names its bus in ``<param name="bus_config">`` (a bus.yml, read by
canopen_bus) and its CAN interface in ``can_interface_name``; each joint names its device (RobotSystem:
``device_name``, a bus.yml section; Cia402System: ``node_id``). What each device's keys become:

* ``node_id`` → ``node_id``; ``dcf`` (relative to the bus.yml) → ``eds``, referenced relative to the written config;
* ``position_mode`` / ``velocity_mode`` / ``effort_mode`` (CiA 402 mode codes, switched at run time by the
  controller that claims the interface) → one cyclic synchronous ``mode`` per drive (8 csp, 9 csv, 10 cst), the one
  of the interface hild's controllers command; profile and interpolated modes have no hild counterpart;
* the scale factors. ros2_canopen commands ``device = SI · scale_pos_to_dev + offset_pos_to_dev`` and reads
  ``SI = device · scale_pos_from_dev + offset_pos_from_dev`` (defaults 1000 and 0.001: milliradians). hild reads
  ``q = direction · device / counts_per_rad + offset`` (``counts_per_rad = counts_per_rev / 2π``, its transmission
  identity otherwise), so ``counts_per_rev = 2π·|scale_pos_to_dev|``, ``direction = sign(scale_pos_to_dev)``,
  ``offset = offset_pos_from_dev``; velocity units per rad/s are ``|scale_vel_to_dev|``, so ``velocity_factor =
  |scale_vel_to_dev| / |scale_pos_to_dev|``; ``rated_torque = 1000·scale_eff_from_dev`` N·m (0x6077 is per mille).
  Exact: the tests round-trip them through ``wire_drives``;
* ``heartbeat_producer`` → ``heartbeat_ms``; ``sdo`` writes of objects hild configures itself (0x6098 homing method,
  0x6065/0x6066 following error, 0x6072 max torque, 0x605A quick stop, 0x1017 heartbeat, 0x6060 mode) → their
  fields; ``homing_timeout_seconds`` → ``homing.timeout``; ``tpdo``/``rpdo`` → hild's own PDO layout instead.

The master's ``sync_period`` is compared with the update rate (hild sends SYNC once per cycle) and its
``baudrate`` (kbit/s) becomes the bus bitrate. Everything else is reported by name, never dropped silently.
The importer then checks the section as ``hild check`` does, through the cia402 driver's own params and review
(importer.py): hild's code outside the drivers never imports them (docs/architecture.md, "Rooms").
"""

from __future__ import annotations

import configparser
import math
import os
import re
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hild.config.documents import KeyPath
from hild.importers.ros2_control.canopen_bus import Bus, BusNode, as_float, as_int, read_bus
from hild.importers.ros2_control.controllers import ControllersPlan
from hild.importers.ros2_control.packages import PackageRoots
from hild.importers.ros2_control.report import Report, SourceRef
from hild.importers.ros2_control.urdf import HardwareJoint, Robot, Ros2Control

ROBOT_SYSTEM = "canopen_ros2_control/RobotSystem"
CIA402_SYSTEM = "canopen_ros2_control/Cia402System"
CANOPEN_SYSTEM = "canopen_ros2_control/CanopenSystem"  # CiA 301 only: raw PDO/NMT interfaces, no drive profile
DRIVE_PLUGINS = (ROBOT_SYSTEM, CIA402_SYSTEM)
CIA402_DRIVERS = ("ros2_canopen::Cia402Driver", "ros2_canopen::LifecycleCia402Driver")
MASTER_DRIVERS = ("ros2_canopen::MasterDriver", "ros2_canopen::LifecycleMasterDriver")
HARDWARE_PARAMS = ("bus_config", "master_config", "can_interface_name", "master_bin")

MODE_NAMES = {
    0: "no mode",
    1: "profile position",
    2: "velocity",
    3: "profile velocity",
    4: "profile torque",
    6: "homing",
    7: "interpolated position",
    8: "cyclic synchronous position",
    9: "cyclic synchronous velocity",
    10: "cyclic synchronous torque",
}
CYCLIC = {8: "csp", 9: "csv", 10: "cst"}
MODE_KEYS = {"position": "position_mode", "velocity": "velocity_mode", "effort": "effort_mode"}
MODE_OF_INTERFACE = {"position": "csp", "velocity": "csv", "effort": "cst"}
DEFAULT_SCALE_TO, DEFAULT_SCALE_FROM = 1000.0, 0.001  # ros2_canopen's own: SI ↔ thousandths
DEFAULT_HOMING_TIMEOUT = 10  # s, ros2_canopen's homing_timeout_seconds default
DEFAULT_BAUDRATE = 1000  # kbit/s, lely dcfgen's master baudrate default
TAU = 2.0 * math.pi
RELATIVE_TOLERANCE = 1e-6
HOMING_BIT = 1 << 5  # 0x6502 supported drive modes: homing

# Device keys hild does not need, with why (anything not listed here or read below is "not used").
NOT_NEEDED = {
    "period": "hild runs the CiA 402 state machine on its own cycle",
    "polling": "hild exchanges PDOs on every SYNC",
    "switching_state": "hild sets the mode before it enables the drive",
    "dcf_path": "where lely's master finds its generated .bin files; hild reads the EDS/DCF itself",
    "namespace": "a ROS namespace",
    "enable_lazy_load": "a ROS loading option",
}
IDENTITY_KEYS = ("vendor_id", "product_code", "revision_number", "serial_number")
MASTER_NOT_NEEDED = {
    "node_id": "hild's master has no node id of its own (it sends NMT, SYNC and SDO requests)",
    "driver": "hild is the master",
    "package": "hild is the master",
    "namespace": "a ROS namespace",
    "heartbeat_consumer": "hild watches every drive's heartbeat",
}


@dataclass
class Cia402Section:
    """A ``cia402`` hardware component made from one ``<ros2_control>`` block, ready to render commented."""

    block: str
    plugin: str
    name: str
    component: dict[str, Any]
    comments: dict[KeyPath, str] = field(default_factory=dict)
    heading: list[str] = field(default_factory=list)
    missing: list[str] = field(default_factory=list)  # joints left out of it, with why (rendered as comments)


@dataclass
class _Drive:
    joint: str
    values: dict[str, Any]
    transmission: dict[str, float]
    eds: Path
    where: SourceRef
    heartbeat: tuple[int, SourceRef] | None = None


def is_canopen(plugin: str | None) -> bool:
    return plugin in (*DRIVE_PLUGINS, CANOPEN_SYSTEM)


def commanded_interfaces(controllers: ControllersPlan) -> dict[str, str]:
    """Per joint, the interface the first controller commanding it uses (position, velocity or effort): the
    interface whose bus.yml mode the drive runs. Broadcasters command nothing."""
    found: dict[str, str] = {}
    for plan in controllers.controllers:
        params = plan.params
        if plan.type == "joint_trajectory":
            interfaces = list(params.get("command_interfaces", ["position"]))
            interface = "effort" if interfaces == ["effort"] else "position"
        elif plan.type == "forward_command":
            interface = str(params.get("interface", "position"))
        elif "broadcaster" in plan.type:
            continue
        else:
            interface = "position"
        joints = params.get("joints") or ([params["joint"]] if "joint" in params else [])
        for joint in joints:
            found.setdefault(str(joint), interface)
    return found


def plan_canopen(
    robot: Robot,
    commanded: Mapping[str, Sequence[str]],
    interfaces: Mapping[str, str],
    packages: PackageRoots,
    config_dir: Path,
    update_rate: float,
    report: Report,
) -> dict[str, Cia402Section]:
    """Per ros2_canopen drive block (by name), its ``cia402`` section; ``commanded``: the joints hild commands
    per block, ``interfaces``: the command interface hild's controllers use per joint (position by default)."""
    sections: dict[str, Cia402Section] = {}
    channels: dict[str, SourceRef] = {}
    for block in robot.ros2_control:
        if block.plugin not in DRIVE_PLUGINS:
            continue
        section = _Block(block, packages, config_dir, update_rate, report).plan(
            commanded.get(block.name, ()), interfaces
        )
        channel = str(section.component["params"]["bus"]["channel"])
        if channel in channels:
            report.unsupported(
                block.where,
                f"<ros2_control> {block.name!r} is a second master on CAN interface {channel} (the first: "
                f"{channels[channel]}): hild runs one cia402 component per bus; merge the drives into one bus.yml",
            )
        channels.setdefault(channel, block.where)
        sections[block.name] = section
    drive_joints = {j for s in sections.values() for j in s.component["joints"]}
    for t in robot.transmissions:
        if any(end.name in drive_joints for end in t.joints):
            report.approximated(
                t.where,
                f"transmission {t.name!r}: ros2_canopen's hardware does not apply <transmission>s (its scale_* "
                "factors carry the gearing), so the cia402 section leaves it out",
            )
    return sections


class _Block:
    """One ros2_canopen block: its hardware params, its bus.yml, its joints' devices."""

    def __init__(
        self,
        block: Ros2Control,
        packages: PackageRoots,
        config_dir: Path,
        update_rate: float,
        report: Report,
    ) -> None:
        self.block, self.packages, self.config_dir, self.report = block, packages, config_dir, report
        self.update_rate = update_rate
        self.urdf_dir = packages.near  # the given URDF's (or xacro's) directory, not the expansion's
        self.comments: dict[KeyPath, str] = {}
        self.name = re.sub(r"[^A-Za-z0-9_]+", "_", block.name).strip("_").lower() or "drives"

    # ---- the block --------------------------------------------------------------------------------------------
    def plan(self, joints: Sequence[str], interfaces: Mapping[str, str]) -> Cia402Section:
        block, report = self.block, self.report
        bus_path = self._bus_path()
        bus = read_bus(bus_path, report)
        report.mapped(self._param("bus_config")[1], f"bus_config → {bus_path} (its master and devices below)")
        bus_spec = self._bus_spec(bus)
        sync_note = self._master(bus)
        for name in ("master_config", "master_bin"):
            if name in block.params:
                report.approximated(
                    block.params[name][1],
                    f"{name}: lely's master DCF/.bin, generated by dcfgen from the bus.yml; hild is the master "
                    "itself and configures each drive by SDO when it starts (docs/drivers.md)",
                )
        for name, (_, where) in block.params.items():
            if name not in HARDWARE_PARAMS:
                report.unsupported(where, f"hardware param {name!r} of {block.plugin}: ros2_canopen does not read it")
        by_joint = {hw.name: hw for hw in block.joints}
        drives: list[_Drive] = []
        missing: list[str] = []
        for joint in joints:
            drive = self._drive(by_joint[joint], bus, interfaces.get(joint, "position"), missing)
            if drive is not None:
                drives.append(drive)
        section = self._section(bus, bus_spec, drives, missing)
        section.heading.append(f"---- {sync_note}.")
        if not drives:
            report.unsupported(block.where, f"<ros2_control> {block.name!r}: no drive hild can use")
        return section

    def _param(self, name: str) -> tuple[str, SourceRef]:
        if name not in self.block.params:
            raise self.block.plugin_where.fail(
                f"{self.block.plugin} needs <param name={name!r}> in <hardware> (ros2_canopen refuses it too)"
            )
        value, where = self.block.params[name]
        return value.strip().strip('"').strip("'").strip(), where

    def _bus_path(self) -> Path:
        """bus_config as ROS gives it: a path (xacro has already resolved ``$(find pkg)``), ``$(find pkg)`` or
        ``$(find-pkg-share pkg)`` left in a plain URDF, ``package://`` or ``file://``; relative to the URDF."""
        text, where = self._param("bus_config")
        found = re.match(r"^\$\((?:find|find-pkg-share)\s+([^)\s]+)\)(.*)$", text)
        if found:
            root = self.packages.find(found.group(1))
            if root is None:
                raise where.fail(f"bus_config: unknown ROS package {found.group(1)!r}: pass --package-root NAME=DIR")
            path = root / found.group(2).lstrip("/")
        else:
            resolved, why = self.packages.resolve_uri(text, self.urdf_dir)
            if resolved is None:
                raise where.fail(f"bus_config {text!r}: {why}")
            path = resolved
        if not path.is_file():
            raise where.fail(f"bus_config {text!r}: no such file {path}")
        return path.resolve()

    def _bus_spec(self, bus: Bus) -> dict[str, Any]:
        channel, where = self._param("can_interface_name")
        if not channel:
            raise where.fail("can_interface_name is empty: the CAN interface ros2_canopen opens (e.g. can0)")
        self.report.mapped(where, f"can_interface_name {channel!r} → bus channel (socketcan)")
        master = bus.master
        assert master is not None
        kbit = as_int(master.values.get("baudrate"))
        if "baudrate" in master.values and kbit is None:
            raise master.ref("baudrate").fail("master baudrate must be a number of kbit/s")
        if kbit is None:
            kbit = DEFAULT_BAUDRATE
            self.report.approximated(master.where, "master has no baudrate: dcfgen's default 1000 kbit/s")
        else:
            self.report.mapped(master.ref("baudrate"), f"master baudrate {kbit} kbit/s → bus bitrate {kbit * 1000}")
        origin = f"{where.short} can_interface_name, {master.ref('baudrate').short} baudrate"
        self.comments[("params", "bus")] = f"{origin}; socketcan runs at the bitrate set with ip link"
        return {"interface": "socketcan", "channel": channel, "bitrate": kbit * 1000}

    def _master(self, bus: Bus) -> str:
        """Report the master's keys; the returned line says how SYNC relates to the cycle."""
        master, report = bus.master, self.report
        assert master is not None
        driver = str(master.values.get("driver", ""))
        if driver and driver not in MASTER_DRIVERS:
            report.unsupported(master.ref("driver"), f"master driver {driver!r}: hild is the master (MasterDriver)")
        sync_us = as_float(master.values.get("sync_period"))
        period_us = 1e6 / self.update_rate
        if sync_us is None or sync_us <= 0:
            note = f"hild sends SYNC once per cycle ({self.update_rate:g} Hz); the bus.yml master sent none"
            report.approximated(master.ref("sync_period"), f"master sync_period absent or 0: {note}")
        elif abs(sync_us - period_us) <= RELATIVE_TOLERANCE * period_us:
            note = f"SYNC every {sync_us:g} µs = 1 / update_rate: hild sends it once per cycle"
            report.mapped(master.ref("sync_period"), f"master sync_period {sync_us:g} µs → {note}")
        else:
            note = (
                f"the bus.yml's SYNC came every {sync_us:g} µs ({1e6 / sync_us:g} Hz); hild sends it once per cycle, "
                f"every {period_us:g} µs (update_rate {self.update_rate:g} Hz)"
            )
            report.approximated(master.ref("sync_period"), f"master sync_period: {note}")
        for key in master.values:
            if key in ("sync_period", "baudrate"):
                continue
            if key in MASTER_NOT_NEEDED:
                why = MASTER_NOT_NEEDED[key]
                report.approximated(master.ref(key), f"master {key}: not needed" + (f" ({why})" if why else ""))
            elif key == "heartbeat_producer":
                report.unsupported(
                    master.ref(key),
                    "master heartbeat_producer: hild produces no heartbeat of its own (drives that watch the "
                    "master's heartbeat through 0x1016 must not)",
                )
            else:
                report.unsupported(master.ref(key), f"master {key}: not used by hild")
        for device in bus.devices.values():
            if str(device.values.get("driver", "")) in MASTER_DRIVERS:
                report.unsupported(
                    device.ref("driver"),
                    f"bus.yml {device.name!r} is a second master on this bus: hild is the only master of its bus",
                )
        return note

    # ---- one joint --------------------------------------------------------------------------------------------
    def _device(self, hw: HardwareJoint, bus: Bus) -> BusNode:
        where = hw.param_where
        if self.block.plugin == ROBOT_SYSTEM:
            name = hw.params.get("device_name", "").strip()
            if not name:
                raise hw.where.fail(
                    f'{ROBOT_SYSTEM}: joint {hw.name!r} needs <param name="device_name"> naming its bus.yml device'
                )
            device = bus.devices.get(name)
            if device is None:
                known = ", ".join(bus.devices) or "none"
                raise where.get("device_name", hw.where).fail(
                    f"joint {hw.name!r}: device_name {name!r} is not a device of {bus.path} (devices: {known})"
                )
            self.report.mapped(where.get("device_name", hw.where), f"{hw.name}: device_name {name!r} → {device.where}")
            return device
        text = hw.params.get("node_id")
        node_id = as_int(text) if text is not None else None
        if node_id is None:
            raise hw.where.fail(f'{CIA402_SYSTEM}: joint {hw.name!r} needs <param name="node_id"> (its node id)')
        device = bus.by_node_id(node_id)
        if device is None:
            raise where.get("node_id", hw.where).fail(
                f"joint {hw.name!r}: no device of {bus.path} has node_id {node_id}"
            )
        self.report.mapped(where.get("node_id", hw.where), f"{hw.name}: node_id {node_id} → {device.where}")
        return device

    def _drive(self, hw: HardwareJoint, bus: Bus, interface: str, missing: list[str]) -> _Drive | None:
        device = self._device(hw, bus)
        report, values = self.report, device.values
        driver = str(values.get("driver", ""))
        if driver not in CIA402_DRIVERS:
            what = "a CiA 301 proxy driver" if "Proxy" in driver else f"driver {driver or '(none)'}"
            report.unsupported(
                device.ref("driver"),
                f"{hw.name}: {device.name!r} uses {what}: not a CiA 402 drive, left out of the cia402 section "
                f"({ROBOT_SYSTEM} refuses it too)",
            )
            missing.append(f"{hw.name}: {device.name} is {what} (not CiA 402)")
            return None
        channels = as_int(values.get("num_channels")) or 1
        channel = as_int(hw.params.get("channel", "0"))
        if channels > 1 or channel != 0:
            report.unsupported(
                device.ref("num_channels") if channels > 1 else hw.param_where.get("channel", hw.where),
                f"{hw.name}: {device.name!r} is a CiA 402-2 multi-channel device: hild drives one axis per node",
            )
            missing.append(f"{hw.name}: multi-channel device {device.name}")
            return None
        node_id = as_int(values.get("node_id"))
        if node_id is None or not 1 <= node_id <= 127:
            what = "no node_id" if node_id is None else f"node_id {node_id}"
            report.unsupported(
                device.ref("node_id"),
                f"{hw.name}: {device.name!r} has {what}: hild needs a fixed node id 1..127 (LSS and node ids taken "
                "from the DCF are not supported)",
            )
            missing.append(f"{hw.name}: {what}")
            return None
        eds = self._eds(device, bus)
        drive: dict[str, Any] = {"node_id": node_id}
        self.comments[("params", "drives", hw.name)] = f"{device.where.short} {device.name}"
        drive["mode"] = self._mode(hw.name, device, interface)
        transmission = self._scales(hw.name, device, drive)
        self._sdo(hw.name, device, drive)
        sdo_heartbeat = drive.pop("_heartbeat", None)  # a 0x1017 write in the sdo list
        self._homing(hw.name, device, drive, eds)
        self._leftovers(hw.name, device)
        heartbeat = self._heartbeat(hw.name, device) or sdo_heartbeat
        return _Drive(hw.name, drive, transmission, eds, device.where, heartbeat)

    def _eds(self, device: BusNode, bus: Bus) -> Path:
        dcf = device.values.get("dcf")
        if not isinstance(dcf, str) or not dcf:
            raise device.where.fail(f"bus.yml {device.name!r} has no dcf (the device's EDS/DCF; dcfgen needs it too)")
        path = (bus.path.parent / dcf).resolve()
        if not path.is_file():
            raise device.ref("dcf").fail(f"dcf {dcf!r}: no such file {path} (dcf is relative to the bus.yml)")
        self.report.mapped(device.ref("dcf"), f"{device.name}: dcf {dcf} → eds (the written config refers to it)")
        return path

    def _mode(self, joint: str, device: BusNode, interface: str) -> str:
        """The one cyclic mode hild runs: the one of the interface hild's controllers command, if cyclic."""
        report = self.report
        given = {i: as_int(device.values[k]) for i, k in MODE_KEYS.items() if k in device.values}
        for i, code in given.items():
            key = MODE_KEYS[i]
            if code not in CYCLIC:
                report.unsupported(
                    device.ref(key),
                    f"{joint}: {key} {code} ({MODE_NAMES.get(code or 0, 'unknown')}): hild drives the cyclic "
                    "synchronous modes only (8 csp, 9 csv, 10 cst)",
                )
        wanted = given.get(interface)
        if wanted in CYCLIC:
            mode = CYCLIC[wanted]
            report.mapped(device.ref(MODE_KEYS[interface]), f"{joint}: {MODE_KEYS[interface]} {wanted} → mode {mode}")
        else:
            cyclic = [(i, CYCLIC[c]) for i, c in given.items() if c in CYCLIC]
            if cyclic:
                used, mode = cyclic[0]
                why = f"its {MODE_KEYS[used]}"
            else:
                mode = MODE_OF_INTERFACE[interface]
                why = "the cyclic counterpart of the interface; the drive must list it in 0x6502"
            report.approximated(
                device.where,
                f"{joint}: hild's controllers command {interface}, which the bus.yml gives no cyclic mode → mode "
                f"{mode} ({why})",
            )
        for i, code in given.items():
            if code in CYCLIC and CYCLIC[code] != mode:
                report.approximated(
                    device.ref(MODE_KEYS[i]),
                    f"{joint}: {MODE_KEYS[i]} {code} ({CYCLIC[code]}) not used: hild runs one mode per drive "
                    f"(set mode: {CYCLIC[code]} to use it)",
                )
        return mode

    def _scales(self, joint: str, device: BusNode, drive: dict[str, Any]) -> dict[str, float]:
        """counts_per_rev, velocity_factor and rated_torque in ``drive``; the joint's transmission returned."""
        report, values = self.report, device.values

        def number(key: str, default: float) -> tuple[float, bool]:
            if key not in values:
                return default, False
            value = as_float(values[key])
            if value is None or value == 0 or not math.isfinite(value):
                raise device.ref(key).fail(f"{key} must be a finite, non-zero number, found {values[key]!r}")
            return value, True

        pos_to, pos_to_given = number("scale_pos_to_dev", DEFAULT_SCALE_TO)
        pos_from, pos_from_given = number("scale_pos_from_dev", DEFAULT_SCALE_FROM)
        vel_to, vel_to_given = number("scale_vel_to_dev", DEFAULT_SCALE_TO)
        vel_from, vel_from_given = number("scale_vel_from_dev", DEFAULT_SCALE_FROM)
        off_to = as_float(values.get("offset_pos_to_dev", 0.0)) or 0.0
        off_from = as_float(values.get("offset_pos_from_dev", 0.0)) or 0.0
        if not (pos_to_given or pos_from_given):
            report.approximated(
                device.where,
                f"{joint}: no scale_pos_to_dev: ros2_canopen's default {DEFAULT_SCALE_TO:g} device units per rad "
                "(per m) is written out; if the drive counts encoder increments, set counts_per_rev, or remove it "
                "to take 0x608F × 0x6091 from the EDS",
            )
        counts_per_rad = abs(pos_to)
        direction = 1 if pos_to > 0 else -1
        if not _inverse(pos_to, pos_from):
            report.approximated(
                device.ref("scale_pos_from_dev"),
                f"{joint}: scale_pos_from_dev {pos_from:g} is not 1 / scale_pos_to_dev {pos_to:g}: ros2_canopen "
                f"reads positions in another scale than it commands; hild reads and commands in one: "
                f"{counts_per_rad:g} units per rad (the commands' scale)",
            )
        drive["counts_per_rev"] = TAU * counts_per_rad
        report.mapped(
            device.ref("scale_pos_to_dev"),
            f"{joint}: scale_pos_to_dev {pos_to!r} → counts_per_rev 2π·{counts_per_rad!r} = {TAU * counts_per_rad!r}"
            + (", direction -1" if direction < 0 else ""),
        )
        if not _inverse(vel_to, vel_from):
            report.approximated(
                device.ref("scale_vel_from_dev"),
                f"{joint}: scale_vel_from_dev {vel_from:g} is not 1 / scale_vel_to_dev {vel_to:g}; hild uses "
                f"{abs(vel_to):g} velocity units per rad/s (the commands' scale)",
            )
        if (vel_to > 0) != (pos_to > 0):
            report.unsupported(
                device.ref("scale_vel_to_dev"),
                f"{joint}: scale_vel_to_dev and scale_pos_to_dev have opposite signs: hild has one direction per "
                "joint, the position's",
            )
        drive["velocity_factor"] = abs(vel_to) / counts_per_rad
        if not (vel_to_given or vel_from_given):
            report.approximated(
                device.where, f"{joint}: no scale_vel_to_dev: ros2_canopen's default {DEFAULT_SCALE_TO:g}"
            )
        else:
            report.mapped(
                device.ref("scale_vel_to_dev"),
                f"{joint}: scale_vel_to_dev {vel_to:g} → velocity_factor {drive['velocity_factor']:.10g} "
                "(velocity units per position unit per second)",
            )
        if "scale_eff_from_dev" in values:
            eff, _ = number("scale_eff_from_dev", DEFAULT_SCALE_FROM)
            drive["rated_torque"] = 1000.0 * abs(eff)
            report.mapped(
                device.ref("scale_eff_from_dev"),
                f"{joint}: scale_eff_from_dev {eff:g} → rated_torque {drive['rated_torque']:g} N·m (0x6077 is ‰ of "
                "it); ros2_canopen sends effort commands unscaled (‰), hild sends N·m",
            )
        else:
            report.approximated(
                device.where,
                f"{joint}: no scale_eff_from_dev (ros2_canopen's default reads effort as a fraction of rated "
                "torque): hild reads N·m through the EDS's 0x6076 motor rated torque",
            )
        transmission: dict[str, float] = {}
        if direction < 0:
            transmission["direction"] = -1
        if off_from or off_to:
            expected = -off_to / pos_to
            if not math.isclose(expected, off_from, rel_tol=RELATIVE_TOLERANCE, abs_tol=1e-12):
                report.approximated(
                    device.ref("offset_pos_from_dev"),
                    f"{joint}: offset_pos_from_dev {off_from:g} and offset_pos_to_dev {off_to:g} disagree (reads "
                    f"would need {expected:g}): hild takes the reading's, {off_from:g}",
                )
            if off_from:
                transmission["offset"] = off_from
            report.mapped(
                device.ref("offset_pos_from_dev"), f"{joint}: offset_pos_from_dev {off_from:g} → transmission offset"
            )
        return transmission

    def _heartbeat(self, joint: str, device: BusNode) -> tuple[int, SourceRef] | None:
        if "heartbeat_producer" not in device.values:
            return None
        ms = as_int(device.values["heartbeat_producer"])
        if ms is None or not 0 <= ms <= 65535:
            raise device.ref("heartbeat_producer").fail("heartbeat_producer must be 0..65535 ms")
        return ms, device.ref("heartbeat_producer")

    def _sdo(self, joint: str, device: BusNode, drive: dict[str, Any]) -> None:
        """``sdo:`` writes at boot: those of objects hild writes itself become their fields."""
        entries = device.values.get("sdo")
        if entries is None:
            return
        if not isinstance(entries, list):
            raise device.ref("sdo").fail("sdo must be a list of {index, sub_index, value}")
        counts_per_rad = drive["counts_per_rev"] / TAU
        for item, entry in enumerate(entries):
            where = device.ref("sdo", item)
            index = as_int(entry.get("index")) if isinstance(entry, dict) else None
            sub = as_int(entry.get("sub_index", 0)) if isinstance(entry, dict) else None
            value = as_float(entry.get("value")) if isinstance(entry, dict) else None
            if index is None or sub is None or value is None:
                raise where.fail(f"sdo entry {entry!r}: expected {{index, sub_index, value}} with numbers")
            name = f"sdo {index:#06x}:{sub} = {value:g}"
            mapped = _SDO_FIELDS.get(index)
            if index == 0x6060:
                code = int(value)
                text = "the mode hild sets itself"
                if code in CYCLIC and code != {v: k for k, v in CYCLIC.items()}.get(drive["mode"]):
                    text += f"; {CYCLIC[code]} here, but the mode of the interface above wins"
                self.report.approximated(where, f"{joint}: {name} (mode of operation): {text}")
            elif index == 0x60C2:
                self.report.approximated(
                    where, f"{joint}: {name} (interpolation time period): hild writes it from the update rate"
                )
            elif index == 0x1017 and sub == 0:
                self.report.mapped(where, f"{joint}: {name} → heartbeat_ms (the component's, below)")
                drive["_heartbeat"] = (int(value), where)
            elif index == 0x6065 and sub == 0:
                drive["following_error_window"] = value / counts_per_rad
                self.report.mapped(where, f"{joint}: {name} → following_error_window {value / counts_per_rad:g} rad")
            elif index == 0x6066 and sub == 0:
                drive["following_error_timeout_ms"] = int(value)
                self.report.mapped(where, f"{joint}: {name} → following_error_timeout_ms")
            elif index == 0x605A and sub == 0:
                self.report.approximated(
                    where, f"{joint}: {name} → quick_stop_option (one for the component; the last drive's wins)"
                )
                drive.setdefault("_quick_stop", int(value))
            elif index == 0x6072 and sub == 0:
                rated = drive.get("rated_torque")
                if rated is None:
                    self.report.unsupported(
                        where, f"{joint}: {name} (max torque, ‰): set max_torque in N·m (no scale_eff_from_dev here)"
                    )
                else:
                    drive["max_torque"] = value * rated / 1000.0
                    self.report.mapped(where, f"{joint}: {name} → max_torque {drive['max_torque']:g} N·m")
            elif index in (0x6098, 0x607C, 0x6099):
                drive.setdefault("_homing_sdo", {})[(index, sub)] = value
            elif mapped is not None:
                self.report.unsupported(where, f"{joint}: {name} ({mapped})")
            else:
                self.report.unsupported(
                    where,
                    f"{joint}: {name}: hild writes only the objects docs/drivers.md lists; keep it in the drive "
                    "(or its DCF)",
                )

    def _homing(self, joint: str, device: BusNode, drive: dict[str, Any], eds: Path) -> None:
        """ros2_canopen homes on init (activation) when the drive has mode 6; hild on ``hild ctl home`` only."""
        given: dict[tuple[int, int], float] = drive.pop("_homing_sdo", {})
        dictionary = read_eds(eds, device.ref("dcf"))
        supported = eds_value(dictionary, 0x6502)
        if supported is not None and not supported & HOMING_BIT:
            if given or "homing_timeout_seconds" in device.values:
                self.report.unsupported(
                    device.where, f"{joint}: homing configured, but {eds.name} lists no homing mode in 0x6502"
                )
            return
        homing: dict[str, Any] = {}
        counts_per_rad = drive["counts_per_rev"] / TAU
        velocity_per_rad_s = counts_per_rad * drive["velocity_factor"]
        if (0x6098, 0) in given:
            homing["method"] = int(given[(0x6098, 0)])
        elif (method := eds_value(dictionary, 0x6098)) is not None:
            homing["method"] = method if method < 128 else method - 256  # INTEGER8
        if (0x607C, 0) in given:
            homing["offset"] = given[(0x607C, 0)] / counts_per_rad
        for sub, key in ((1, "speed_switch"), (2, "speed_zero")):
            if (0x6099, sub) in given and given[(0x6099, sub)] > 0:
                homing[key] = given[(0x6099, sub)] / velocity_per_rad_s
        timeout = as_int(device.values.get("homing_timeout_seconds", DEFAULT_HOMING_TIMEOUT))
        homing["timeout"] = float(timeout if timeout and timeout > 0 else DEFAULT_HOMING_TIMEOUT)
        drive["homing"] = homing
        source = "the sdo list's 0x6098" if (0x6098, 0) in given else f"{eds.name}'s 0x6098 default"
        self.report.approximated(
            device.ref("homing_timeout_seconds"),
            f"{joint}: homing (method {homing.get('method', 'hild default')} from {source}, timeout "
            f"{homing['timeout']:g} s): ros2_canopen homes every drive on init; hild homes only on an explicit "
            f"`hild ctl home {joint}`",
        )

    def _leftovers(self, joint: str, device: BusNode) -> None:
        read = {
            "node_id",
            "dcf",
            "sdo",
            "heartbeat_producer",
            "homing_timeout_seconds",
            "num_channels",
            *MODE_KEYS.values(),
            *(f"scale_{k}" for k in ("pos_to_dev", "pos_from_dev", "vel_to_dev", "vel_from_dev", "eff_from_dev")),
            "offset_pos_to_dev",
            "offset_pos_from_dev",
        }
        for key in device.values:
            where = device.ref(key)
            if key in read:
                continue
            if key in ("tpdo", "rpdo"):
                self.report.approximated(
                    where,
                    f"{joint}: {key} layout replaced by hild's own: one RPDO and one TPDO per drive per cycle, "
                    "mapped by SDO when hild starts (statusword/controlword, position, the mode's target; "
                    "docs/drivers.md)",
                )
            elif key in ("driver", "package"):
                self.report.mapped(where, f"{joint}: {key} {device.values[key]} → driver cia402")
            elif key in NOT_NEEDED:
                why = NOT_NEEDED[key]
                self.report.approximated(where, f"{joint}: {key}: not needed" + (f" ({why})" if why else ""))
            elif key in IDENTITY_KEYS:
                self.report.unsupported(where, f"{joint}: {key}: hild does not check the drive's identity (0x1018)")
            elif key == "sdo_timeout_ms":
                self.report.approximated(where, f"{joint}: sdo_timeout_ms → reply_timeout_ms (the component's)")
            else:
                self.report.unsupported(where, f"{joint}: bus.yml {key!r}: not used by hild")

    # ---- the section ------------------------------------------------------------------------------------------
    def _section(self, bus: Bus, bus_spec: dict[str, Any], drives: list[_Drive], missing: list[str]) -> Cia402Section:
        report, c = self.report, self.comments
        params: dict[str, Any] = {"bus": bus_spec}
        eds_of = {d.joint: self._relative(d.eds) for d in drives}
        common_eds = Counter(eds_of.values()).most_common(1)[0][0] if drives else "TODO.eds"
        modes = Counter(d.values["mode"] for d in drives)
        common_mode = modes.most_common(1)[0][0] if drives else "csp"
        params["eds"] = common_eds
        c[("params", "eds")] = "the devices' dcf, relative to this config"
        params["mode"] = common_mode
        heartbeats = [d.heartbeat for d in drives if d.heartbeat is not None]
        if heartbeats:
            ms, where = max(heartbeats, key=lambda h: h[0])
            params["heartbeat_ms"] = ms
            c[("params", "heartbeat_ms")] = f"{where.short} heartbeat_producer"
            report.mapped(where, f"heartbeat_producer {ms} ms → heartbeat_ms {ms} (written to every drive's 0x1017)")
            if len({h[0] for h in heartbeats}) > 1:
                report.approximated(where, f"heartbeat_producer differs between drives: hild writes one, {ms} ms")
        elif drives:
            report.approximated(
                SourceRef(str(bus.path)),
                "no heartbeat_producer (ros2_canopen's default 0: none): hild writes 100 ms to each drive's 0x1017 "
                "and treats a silent drive as stale",
            )
        quick = [d.values.pop("_quick_stop") for d in drives if "_quick_stop" in d.values]
        if quick:
            params["quick_stop_option"] = quick[-1]
        timeouts = [as_int(bus.devices[n].values.get("sdo_timeout_ms")) for n in bus.devices]
        if any(timeouts):
            params["reply_timeout_ms"] = max(t for t in timeouts if t)
        drives_out: dict[str, Any] = {}
        for d in drives:
            values = dict(d.values)
            if values["mode"] == common_mode:
                del values["mode"]
            if eds_of[d.joint] != common_eds:
                values["eds"] = eds_of[d.joint]
            drives_out[d.joint] = values
        params["drives"] = drives_out
        component = {
            "driver": "cia402",
            "params": params,
            "joints": {d.joint: d.transmission for d in drives},
        }
        for d in drives:
            if d.transmission:
                c[("joints", d.joint)] = "from the scale_pos/offset_pos signs and offsets"
        heading = [
            f"---- On the CiA 402 drives of ros2_canopen's {self.block.plugin}: replace the hardware section above",
            f"---- with this (docs/drivers.md). From {bus.path}.",
        ]
        return Cia402Section(self.block.name, self.block.plugin or "", self.name, component, c, heading, missing)

    def _relative(self, path: Path) -> str:
        return os.path.relpath(path, self.config_dir.resolve())


_SDO_FIELDS = {
    0x6081: "profile velocity: profile modes only, hild runs cyclic ones",
    0x6083: "profile acceleration: profile modes only, hild runs cyclic ones",
    0x6084: "profile deceleration: profile modes only, hild runs cyclic ones",
    0x609A: "homing acceleration: its unit is the drive's; set homing.acceleration in rad/s²",
}


def read_eds(path: Path, where: SourceRef) -> configparser.ConfigParser:
    """An EDS/DCF as the INI file it is. Only two defaults are read here (0x6502 supported modes, 0x6098 homing
    method); the drivers parse the dictionary with canopen, which hild's importer may not import (docs/architecture.md,
    "Rooms")."""
    parser = configparser.ConfigParser(interpolation=None, strict=False)
    parser.optionxform = str  # type: ignore[assignment,method-assign]
    try:
        parser.read_string(path.read_text(errors="replace"), str(path))
    except (OSError, configparser.Error) as exc:
        raise where.fail(f"cannot read the EDS/DCF {path}: {exc}") from None
    return parser


def eds_value(eds: configparser.ConfigParser, index: int) -> int | None:
    """Object ``index``'s value in a DCF (ParameterValue) or its default (DefaultValue); None when absent."""
    for name in (f"{index:04X}", f"{index:04x}"):
        if eds.has_section(name):
            section = eds[name]
            for key in ("ParameterValue", "DefaultValue"):
                text = section.get(key, "").strip()
                if text and "$NODEID" not in text.upper():
                    return as_int(text)
    return None


def _inverse(to_dev: float, from_dev: float) -> bool:
    return math.isclose(to_dev * from_dev, 1.0, rel_tol=RELATIVE_TOLERANCE)
