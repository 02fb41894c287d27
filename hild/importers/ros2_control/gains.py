"""Hold gains a ros2_control robot does not give: from its effort PID, or a default that ``hild check`` accepts.

Without an effort PID the default is a critically damped 5 Hz loop in the joint's heaviest pose, stiff enough
that its own damping and friction at full speed cost at most ``DAMPING_LAG`` of tracking error — then lowered, if
need be, to the highest bandwidth the config checks allow (``GainLimits``): an imported config must pass
``hild check`` without warnings about numbers the importer chose. A user's PID is kept as given; a warning about
it is the user's to weigh, and names where the numbers came from.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from hild.config.model import SafetySection
from hild.importers.ros2_control.controllers import Pid
from hild.importers.ros2_control.inertia import JointInertia
from hild.importers.ros2_control.report import Report, SourceRef

HOLD_BANDWIDTH_HZ = 5.0
HOLD_DAMPING_RATIO = 1.0
DAMPING_LAG = 0.05  # rad (m)
OVERSPEED_FACTOR = SafetySection().overspeed_factor  # the written config sets none; hild check reasons with it


def round4(value: float) -> float:
    """Four significant digits: derived numbers read better and nothing depends on the fifth."""
    return float(f"{value:.4g}")


@dataclass(frozen=True)
class GainLimits:
    """What ``hild check`` holds hold gains to: a collision at full speed, or a spring at overspeed, must not change
    the drive's torque by more than the effort limit within one cycle; nor may the hold saturate inside the soft
    margin (hild/config/safety.py)."""

    velocity: float
    effort: float
    soft_margin: float
    dt: float

    def bandwidth(self, inertia: float, damping_ratio: float) -> float:
        """The highest ω (rad/s) whose gains kp = M·ω², kd = 2ζ·M·ω pass every rule, with a 1 % margin."""
        v, e, dt = self.velocity, self.effort, self.dt
        surge = (math.sqrt(damping_ratio**2 + dt * e / (inertia * v)) - damping_ratio) / dt  # kp·v·dt + kd·v ≤ e
        spring = math.sqrt(e / (OVERSPEED_FACTOR * v * dt * inertia))  # kp · overspeed · v · dt ≤ e
        margin = math.sqrt(e / (self.soft_margin * inertia)) if self.soft_margin > 0 else math.inf  # kp·margin ≤ e
        return 0.99 * min(surge, spring, margin)


def critical_kd(kp: float, inertia: float) -> float:
    """The kd that damps ``kp`` on ``inertia`` critically (ζ = HOLD_DAMPING_RATIO), rounded as derived numbers are."""
    return round4(2.0 * HOLD_DAMPING_RATIO * math.sqrt(kp * inertia))


def raised_gains(needed: float, inertia: float, limits: GainLimits) -> tuple[float, float, bool]:
    """``(kp, kd, capped)``: kp ``needed``, or the most ``hild check``'s rules allow on ``inertia`` (``capped``),
    with its critically damped kd — how the importer raises gains it chose itself (never a user's PID)."""
    most = inertia * limits.bandwidth(inertia, HOLD_DAMPING_RATIO) ** 2 if inertia > 0 else math.inf
    kp = round4(min(needed, most))
    return kp, critical_kd(kp, inertia), most < needed


def hold_gains(
    joint: str, where: SourceRef, limits: GainLimits, inertia: JointInertia, pid: tuple[str, Pid] | None, report: Report
) -> tuple[float, float, str]:
    """``(kp, kd, where they come from)`` for holding ``joint`` (declared at ``where``)."""
    heavy = inertia.heaviest
    if pid is not None:
        controller, gains = pid
        kp, kd = gains.p, gains.d
        source = f"PID of {controller} ({gains.where.short})"
        if kd <= 0:
            kd = critical_kd(kp, heavy)
            report.approximated(gains.where, f"{joint}: hold kp {kp:g} from {source}, no d → kd {kd:g} (ζ = 1)")
            return kp, kd, f"kp: {source}; kd: critical damping"
        report.mapped(gains.where, f"{joint}: hold gains kp {kp:g}, kd {kd:g} from {source}")
        return kp, kd, f"kp, kd: {source}"
    omega = 2.0 * math.pi * HOLD_BANDWIDTH_HZ
    by_bandwidth = heavy * omega**2
    by_losses = (inertia.damping * limits.velocity + inertia.friction) / DAMPING_LAG
    kp = max(by_bandwidth, by_losses)
    rule = (
        f"{HOLD_BANDWIDTH_HZ:g} Hz on inertia {heavy:.4g}"
        if by_bandwidth >= by_losses
        else f"damping/friction lag ≤ {DAMPING_LAG:g} at full speed"
    )
    most = limits.bandwidth(heavy, HOLD_DAMPING_RATIO) if heavy > 0 else math.inf
    if math.sqrt(kp / heavy) > most:
        kp = heavy * most**2
        rule = (
            f"{most / (2 * math.pi):.3g} Hz on inertia {heavy:.4g}: the most the effort limit {limits.effort:g} allows "
            f"for a collision at {limits.velocity:g} rad/s"
        )
    kp = round4(kp)
    kd = critical_kd(kp, heavy)
    report.approximated(where, f"{joint}: no effort PID → hold kp {kp:g}, kd {kd:g} ({rule}, ζ = 1)")
    return kp, kd, f"default: {rule.split(':')[0]}, critically damped"


GRASP_TRAVEL = 0.02  # of a gripper joint's range: how far from the object its force bound reaches max_effort
GRIPPER_DEFAULT_EFFORT = 10.0  # parallel_gripper's (and ros2_controllers') default max_effort


def grasp_gains(
    joint: str,
    kp: float,
    lower: float,
    upper: float,
    limits: GainLimits,
    inertia: JointInertia,
    max_effort: float,
    where: SourceRef,
    controller: str,
    report: Report,
) -> tuple[float, float] | None:
    """Gains stiff enough for a gripper to press with ``max_effort`` within ``GRASP_TRAVEL`` of its range from the
    object (parallel_gripper bounds its force through the drive's spring: a soft spring never reaches it), within the
    bandwidth ``hild check`` allows; None when ``kp`` already is. Reported either way it changes."""
    travel = GRASP_TRAVEL * (upper - lower)
    wanted = max_effort / travel
    if kp >= wanted:
        return None
    new_kp, new_kd, capped = raised_gains(wanted, inertia.heaviest, limits)
    reach = max_effort / new_kp
    text = (
        f"{joint}: hold kp {kp:g} → {new_kp:g}, kd {new_kd:g} for {controller}: it presses with max_effort "
        f"{max_effort:g} within {reach:.3g} of the object"
    )
    if capped:
        text += f" (not {travel:.3g}: the most the effort limit {limits.effort:g} allows)"
    report.approximated(where, text)
    return new_kp, new_kd
