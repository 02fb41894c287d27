"""The twin's start pose: a joint's ``initial_value``, or a pose the twin can start in when there is none.

A real arm parked on its end stop reads a hair beyond the limit; the plausibility check accepts readings within
``safety.plausibility.margin`` beyond a hard limit, so such a joint holds where it is. A start on a limit, or beyond
it by no more than that margin (a calibration a hair off), is therefore kept — clamped for the twin, which cannot
start outside a joint's range — and the report says why it holds. Further beyond is an error: a drive reading it
would fault. A zero pose outside the limits (no initial_value) would start the twin beyond a limit, and fault at
once: it starts on the nearest limit instead.
"""

from __future__ import annotations

from hild.config.model import PlausibilitySection
from hild.importers.ros2_control.report import Report, SourceRef
from hild.importers.ros2_control.urdf import HardwareJoint

PLAUSIBILITY_MARGIN = PlausibilitySection().margin  # the written config sets no safety.plausibility


def initial_position(
    joint: str, where: SourceRef, hw: HardwareJoint | None, lower: float, upper: float, report: Report
) -> float | None:
    """``initial_value`` of the position interface (state first, as gz/mock read it) → the twin's start pose
    (None: the model's zero pose). ``where``: the joint's declaration, for a start the importer chooses."""
    found = None
    for spec in (*hw.state_interfaces, *hw.command_interfaces) if hw is not None else ():
        raw = spec.params.get("initial_value")
        if raw is None:
            continue
        at = spec.where_of("initial_value")
        if spec.name != "position":
            if _number_or_none(raw) != 0.0:  # at rest is what the twin does anyway
                report.unsupported(at, f"{joint}: initial_value of {spec.name} (the twin starts at rest)")
            continue
        if found is not None:
            continue
        value = _number_or_none(raw)
        if value is None:
            raise at.fail(f"joint {joint!r}: initial_value {raw!r} is not a number")
        found = _start_on_limit(joint, value, lower, upper, at, report)
        report.mapped(at, f"{joint}: initial_value {value:g} → twin initial_positions")
    if found is None and not lower <= 0.0 <= upper:
        found = lower if lower > 0.0 else upper
        report.approximated(
            where,
            f"{joint}: no initial_value, and the zero pose is outside [{lower:.4g}, {upper:.4g}]: the twin "
            f"starts on the nearest limit, {found:g}",
        )
    return found


def _start_on_limit(joint: str, value: float, lower: float, upper: float, where: SourceRef, report: Report) -> float:
    """The twin's start for ``initial_value``: itself inside the limits, the limit when on or just beyond it."""
    margin = PLAUSIBILITY_MARGIN
    holds = (
        f"a joint resting on its end stop holds (readings within safety.plausibility.margin {margin:g} of a limit "
        "are accepted)"
    )
    for side, limit, beyond in (("lower", lower, lower - value), ("upper", upper, value - upper)):
        if beyond > margin:
            raise where.fail(
                f"joint {joint!r}: initial_value {value:g} is outside [{lower:g}, {upper:g}] by more than the "
                f"plausibility margin {margin:g}: a drive reading it would fault"
            )
        if beyond > 0.0:
            report.approximated(
                where,
                f"{joint}: initial_value {value:g} is {beyond:.4g} beyond the {side} limit {limit:g}: the twin "
                f"starts on the limit; {holds}",
            )
            return limit
        if beyond == 0.0:
            report.approximated(where, f"{joint}: initial_value {value:g} is on the {side} limit: {holds}")
    return value


def _number_or_none(raw: str) -> float | None:
    try:
        return float(raw)
    except ValueError:
        return None
