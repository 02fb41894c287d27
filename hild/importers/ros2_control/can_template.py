"""The commented CAN section at the end of an imported config: the real drives, as far as the description says.

A ros2_control hardware plugin for CAN servos names its bus, CAN FD and each joint's motor in ``<param>``s, under
names its authors chose (OpenArm's Damiao plugin: ``can_interface``, ``can_fd``). The names below are the ones such
plugins use. What is found goes into the template with its source line and is reported as mapped; what is not is a
TODO on its own line saying what to fill in. Models are not checked here (the drivers know them): uncommenting the
section and running ``hild check`` does that.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from hild.importers.ros2_control.canopen import is_canopen
from hild.importers.ros2_control.mapping import JointPlan
from hild.importers.ros2_control.report import Report, SourceRef
from hild.importers.ros2_control.urdf import Robot

BUS_PARAMS: dict[str, tuple[str, ...]] = {
    "channel": (
        "can_interface",
        "can_interface_name",
        "can_bus",
        "can_device",
        "can_channel",
        "can_port",
        "can_iface",
        "can_name",
        "can",
        "channel",
    ),
    "fd": ("can_fd", "use_can_fd", "enable_can_fd", "canfd", "fd"),
    "bitrate": ("can_bitrate", "bitrate", "can_baudrate", "baudrate"),
    "data_bitrate": ("can_data_bitrate", "data_bitrate", "can_fd_bitrate", "data_baudrate", "dbitrate"),
}
MOTOR_PARAMS: dict[str, tuple[str, ...]] = {
    "model": ("motor_type", "motor_model", "actuator_type", "actuator_model", "motor", "model", "actuator"),
    "id": ("can_id", "motor_id", "send_can_id", "send_id", "tx_id", "esc_id", "node_id", "id"),
    "reply_id": ("recv_can_id", "reply_id", "master_id", "mst_id", "recv_id", "rx_id", "feedback_id"),
}
FLAVOUR_BY_MODEL = (("DM", "damiao"), ("AK", "tmotor"))  # model name prefix → mit_can flavour
PLACEHOLDER_MODEL = "DM4340"
_TRUE, _FALSE = ("true", "1", "yes", "on"), ("false", "0", "no", "off")

Found = tuple[Any, SourceRef]  # a value and where the description gives it


@dataclass
class CanFacts:
    """What one ``<ros2_control>`` block says about its CAN drives."""

    plugin: str
    bus: dict[str, Found] = field(default_factory=dict)  # channel, fd, bitrate, data_bitrate
    motors: dict[str, dict[str, Found]] = field(default_factory=dict)  # joint → model, id, reply_id
    used: set[str] = field(default_factory=set)  # hardware param names read here


def read_can_facts(robot: Robot, report: Report) -> dict[str, CanFacts]:
    """Per ``<ros2_control>`` block (by name), the CAN facts its params give; each one read is reported."""
    out: dict[str, CanFacts] = {}
    for block in robot.ros2_control:
        if is_canopen(block.plugin):  # ros2_canopen's params name a bus.yml: canopen.py reads them
            continue
        facts = CanFacts(block.plugin or "")
        params = {name.lower(): (name, value, where) for name, (value, where) in block.params.items()}
        for key, names in BUS_PARAMS.items():
            for candidate in names:
                if candidate in params:
                    name, raw, where = params[candidate]
                    value = _value(key, raw)
                    if value is not None:
                        facts.bus[key] = (value, where)
                        facts.used.add(name)
                        report.mapped(where, f"hardware param {name}={raw!r} → CAN template bus {key}")
                    break
        for hw in block.joints:
            joint_params = {name.lower(): (name, value) for name, value in hw.params.items()}
            motor: dict[str, Found] = {}
            for key, names in MOTOR_PARAMS.items():
                for candidate in names:
                    if candidate in joint_params:
                        name, raw = joint_params[candidate]
                        value = _value(key, raw)
                        where = hw.param_where.get(name, hw.where)
                        if value is not None:
                            motor[key] = (value, where)
                            report.mapped(where, f"{hw.name}: param {name}={raw!r} → CAN template motor {key}")
                        break
            facts.motors[hw.name] = motor
        out[block.name] = facts
    return out


def _value(key: str, raw: str) -> Any:
    """The param's value as the template needs it, or None when it is not one (then it stays unused)."""
    text = raw.strip()
    if key == "fd":
        return True if text.lower() in _TRUE else False if text.lower() in _FALSE else None
    if key in ("bitrate", "data_bitrate", "id", "reply_id"):
        try:
            return int(float(text)) if re.fullmatch(r"[0-9.eE+]+", text) else int(text, 0)
        except ValueError:
            return None
    return text or None


def template_lines(joints: Sequence[JointPlan], facts: Mapping[str, CanFacts]) -> list[str]:
    """A commented mit_can hardware section per <ros2_control> block (``joints``: the JointPlans, in order)."""
    groups: dict[str, list[JointPlan]] = {}
    for j in joints:
        groups.setdefault(j.block, []).append(j)
    out = [
        "---- On MIT-protocol CAN servos: replace the hardware section above with this (docs/drivers.md) and fill",
        "---- in what the TODOs name. The transmissions come from the URDF's <transmission>s.",
        "hardware:",
    ]
    motor_id = 1
    for index, (block, members) in enumerate(groups.items()):
        block_facts = facts.get(block, CanFacts(""))
        name = re.sub(r"[^A-Za-z0-9_]+", "_", block).strip("_").lower() or f"arm{index or ''}"
        origin = f"  # was <ros2_control name={block!r}> {block_facts.plugin}".rstrip() if block else ""
        motors = [block_facts.motors.get(j.name, {}) for j in members]
        flavour = _flavour([m["model"][0] for m in motors if "model" in m])
        out += [f"  {name}:{origin}", "    driver: mit_can", "    params:", _bus_line(block_facts.bus, index)]
        if flavour is None:
            named = "names no motor model" if not any("model" in m for m in motors) else "names models of no flavour"
            out.append(f"      flavour: damiao  # TODO: damiao | tmotor | myactuator (the description {named})")
        else:
            out.append(f"      flavour: {flavour}  # from the motor models")
        if flavour in (None, "damiao"):
            out.append("      timeout_ms: 100")
        out.append("      motors:")
        for j, motor in zip(members, motors, strict=True):
            out.append(_motor_line(j.name, motor, motor_id))
            motor_id += 1
        out.append("    joints:  # q_joint = direction · q_motor / reduction + offset")
        for j in members:
            spec = ", ".join(f"{k}: {v:g}" for k, v in (j.transmission or {}).items())
            note = f"  # {j.transmission_from.short}" if j.transmission_from else ""
            out.append(f"      {j.name}: {{{spec}}}{note}")
    return out


def _flavour(models: list[str]) -> str | None:
    flavours = {f for m in models for prefix, f in FLAVOUR_BY_MODEL if m.upper().startswith(prefix)}
    return flavours.pop() if len(flavours) == 1 and len(models) > 0 else None


def _bus_line(bus: Mapping[str, Found], index: int) -> str:
    parts = ["interface: socketcan", f"channel: {bus['channel'][0] if 'channel' in bus else f'can{index}'}"]
    fd = "fd" in bus and bus["fd"][0]
    if "bitrate" in bus or not fd:
        parts.append(f"bitrate: {bus['bitrate'][0] if 'bitrate' in bus else 1_000_000}")
    if fd:
        parts.append("fd: true")
        if "data_bitrate" in bus:
            parts.append(f"data_bitrate: {bus['data_bitrate'][0]}")
    sources = [f"{where.short} {key}" for key, (_, where) in bus.items()]
    note = ", ".join(sources) if "channel" in bus else "TODO: your CAN interface (the description names none)"
    if fd and "data_bitrate" not in bus:
        note += "; CAN FD: add data_bitrate if your adapter switches bit rate"
    return f"      bus: {{{', '.join(parts)}}}  # {note}"


def _motor_line(joint: str, motor: Mapping[str, Found], motor_id: int) -> str:
    ident = motor["id"][0] if "id" in motor else motor_id
    reply = motor["reply_id"][0] if "reply_id" in motor else ident + 0x10
    model = motor["model"][0] if "model" in motor else PLACEHOLDER_MODEL
    given = [f"{key}: {where.short}" for key, (_, where) in motor.items()]
    todo = [key for key in ("id", "reply_id", "model") if key not in motor]
    note = "; ".join([*given, *([f"TODO: {', '.join(todo)}"] if todo else [])])
    return f"        {joint}: {{id: {ident:#04x}, reply_id: {reply:#04x}, model: {model}}}  # {note}"
