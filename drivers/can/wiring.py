"""Which motor answers where: ``mit_can``'s motors resolved from the config, and every reason they cannot work.

Shared by the host driver and the emulator (``hild emulate`` wires its drives exactly as the host expects them), so
both ends of a bus agree on ids and ranges. The vendor facts come from the flavour object.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

from drivers.can.component import coverage_problems
from drivers.can.params import MitCanParams
from drivers.can.protocol.flavours import FLAVOURS, MitFlavour
from drivers.can.protocol.mit import MitRanges
from drivers.can.protocol.models import ranges_for


@dataclass(frozen=True, slots=True)
class MotorWiring:
    """One motor's ids and ranges, resolved from the config."""

    joint: str
    id: int
    command_id: int
    reply_id: int
    ranges: MitRanges


def wire_motors(params: MitCanParams, joints: Sequence[str]) -> tuple[list[MotorWiring], list[str]]:
    """Resolve every joint's motor; also return every reason the params cannot work (empty when they can)."""
    flavour = FLAVOURS[params.flavour]
    problems = coverage_problems("motor", "motors", params.motors, joints)
    ids = flavour.motor_ids
    wiring: list[MotorWiring] = []
    for joint in joints:
        motor = params.motors.get(joint)
        if motor is None:
            continue
        if motor.id not in ids:
            problems.append(f"{joint}: {flavour.name} motor id must be {ids[0]}..{ids[-1]:#x}, got {motor.id:#x}")
            continue
        if motor.reply_id is not None and not flavour.own_reply_ids:
            problems.append(
                f"{joint}: reply_id applies to {_only(lambda f: f.own_reply_ids)} only ({flavour.name} derives it "
                "from the id)"
            )
        try:
            ranges = ranges_for(flavour.name, motor.model, motor.ranges.as_dict() if motor.ranges else None)
        except ValueError as exc:
            problems.append(f"{joint}: {exc}")
            continue
        reply = motor.reply_id if motor.reply_id is not None else flavour.reply_id(motor.id, params.master_id)
        wiring.append(MotorWiring(joint, motor.id, flavour.command_id(motor.id), reply, ranges))
    problems += _collisions(flavour, wiring)
    if not flavour.registers and params.timeout_ms is not None:
        problems.append(f"timeout_ms: {flavour.name} has no CAN timeout register ({_only(lambda f: f.registers)} only)")
    if not flavour.polls_status and params.status_poll_ms is not None:
        problems.append(
            f"status_poll_ms: applies to {_only(lambda f: f.polls_status)} only ({flavour.name} replies carry the "
            "status)"
        )
    return wiring, problems


def _collisions(flavour: MitFlavour, wiring: list[MotorWiring]) -> list[str]:
    """Ids two motors share, or a reply id that is another motor's command id or reserved by the flavour."""
    problems: list[str] = []
    by_command: dict[int, str] = {}
    for m in wiring:
        if m.command_id in by_command:
            problems.append(f"{m.joint}: motor id {m.id:#x} is also used by {by_command[m.command_id]}")
        by_command.setdefault(m.command_id, m.joint)
    mask = flavour.motor_key_mask
    by_reply: dict[tuple[int, int], str] = {}
    for m in wiring:
        if m.reply_id in by_command:
            problems.append(
                f"{m.joint}: reply id {m.reply_id:#x} collides with the command id of {by_command[m.reply_id]}"
            )
        if m.reply_id in flavour.reserved_ids:
            problems.append(f"{m.joint}: reply id 0x{m.reply_id:X} is {flavour.reserved_ids[m.reply_id]}")
        key = (m.reply_id, m.id & mask)
        if key in by_reply:
            what = "the id" if mask == 0xFF else f"the low {mask.bit_length()} bits of the id"
            problems.append(
                f"{m.joint}: shares reply id {m.reply_id:#x} with {by_reply[key]} and replies cannot be told apart "
                f"({what} must differ; give each motor its own reply_id)"
            )
        by_reply.setdefault(key, m.joint)
    return problems


def _only(has: Callable[[MitFlavour], bool]) -> str:
    """The flavours with a feature, for a message about a config key that only they take."""
    return ", ".join(f.name for f in FLAVOURS.values() if has(f))
