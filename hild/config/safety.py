"""Safety checks beyond the schema: a well-formed config that is unsafe to run is refused, a suspicious one flagged.

The rules (and why) are listed in docs/config.md, "Checks beyond the schema". Rules that protect people from real
drives refuse the config only for joints on real hardware: a driver says it has no real drive behind it with
``SIMULATED = True`` (mock, MuJoCo twin) and everything else counts as real. On simulated joints the same findings
are warnings, so a twin config that would be unsafe on the arm says so before anyone copies its numbers.

The gain rules reason about what happens between two cycles. The supervisor keeps the *predicted* drive torque
within ``±effort`` once per cycle, but the drive evaluates ``kp·(p − q) + kd·(v − q̇) + ff`` continuously with its
own, newer ``q`` and ``q̇``. Whatever the drive adds on its own within one cycle is beyond the supervisor's reach.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from hild.config.model import JointSection, RobotConfig, Transmission
from hild.config.params import Params

Loc = tuple[str | int, ...]

DETECTION_MAX = 0.5  # s: on real hardware a silent servo (or a stalled cycle) must be noticed within this


@dataclass(frozen=True)
class SafetyFinding:
    level: str  # "error" refuses the config; "warning" goes to LoadedConfig.notes
    loc: Loc
    message: str


@dataclass(frozen=True)
class _Joint:
    name: str
    section: JointSection
    transmission: Transmission
    driver: type
    params: Params | None
    real: bool


def review_safety(
    config: RobotConfig, driver_classes: Mapping[str, type], driver_params: Mapping[str, Params]
) -> list[SafetyFinding]:
    """Every safety finding of ``config``, given the driver classes and parameters the loader resolved."""
    joints = _joints(config, driver_classes, driver_params)
    findings: list[SafetyFinding] = []
    dt = 1.0 / config.update_rate
    for joint in joints:
        findings += _limits(joint)
        findings += _gains(joint, dt, config.safety.overspeed_factor)
    findings += _gain_ranges(joints, driver_classes, driver_params, config)
    findings += _safety_section(config, [j.name for j in joints if j.real])
    return findings


def _joints(
    config: RobotConfig, driver_classes: Mapping[str, type], driver_params: Mapping[str, Params]
) -> list[_Joint]:
    out = []
    for hw_name, hw in config.hardware.items():
        cls = driver_classes.get(hw_name)
        if cls is None:  # the driver did not load: already an error
            continue
        real = not getattr(cls, "SIMULATED", False)
        for name, transmission in hw.joints.items():
            if name in config.joints:
                out.append(_Joint(name, config.joints[name], transmission, cls, driver_params.get(hw_name), real))
    return out


def _level(joint: _Joint) -> str:
    return "error" if joint.real else "warning"


def _on_sim(joint: _Joint) -> str:
    return "" if joint.real else " (simulated here; refused on real hardware)"


def _limits(joint: _Joint) -> list[SafetyFinding]:
    """Limits a real drive is commanded within must be numbers: ``.inf`` passes the schema, and means no limit."""
    findings = []
    limits = joint.section.limits
    for field in ("velocity", "effort", "acceleration", "jerk"):
        value = getattr(limits, field)
        if value is not None and not math.isfinite(value):
            message = f"the {field} limit must be a finite number, not {value}{_on_sim(joint)}"
            findings.append(SafetyFinding(_level(joint), ("joints", joint.name, "limits", field), message))
    return findings


def _gain_sets(section: JointSection) -> list[tuple[str, float, float]]:
    """(key, kp, kd) of every gain set the supervisor may send: hold, position defaults, velocity defaults."""
    sets = [("hold", section.hold.kp, section.hold.kd)]
    if section.position_gains is not None:
        sets.append(("position_gains", section.position_gains.kp, section.position_gains.kd))
    if section.velocity_gains is not None:
        sets.append(("velocity_gains", 0.0, section.velocity_gains.kd))
    return sets


def _gains(joint: _Joint, dt: float, overspeed: float) -> list[SafetyFinding]:
    limits = joint.section.limits
    velocity, effort = limits.velocity, limits.effort
    if not (math.isfinite(velocity) and math.isfinite(effort)):
        return []  # reported by _limits
    findings = []
    fastest = overspeed * velocity  # the supervisor faults the joint above this speed, not below
    for key, kp, kd in _gain_sets(joint.section):
        # The spring alone: in one cycle at the fastest speed the supervisor allows, the position error changes by
        # fastest·dt and the drive's torque by kp times that. If that exceeds the effort limit, the per-cycle clamp
        # bounds nothing the drive does in between.
        drift = kp * fastest * dt
        if drift > effort:
            message = (
                f"kp {kp:g}: at {fastest:g} rad/s (velocity limit × overspeed_factor) the drive's spring changes the "
                f"torque by kp·v·dt = {drift:.3g} N·m within one cycle, more than the whole effort limit {effort:g} "
                f"N·m: the supervisor's per-cycle clamp cannot bound it; lower kp or raise update_rate{_on_sim(joint)}"
            )
            findings.append(SafetyFinding(_level(joint), ("joints", joint.name, key), message))
            continue
        # A collision at the velocity limit: the command keeps moving v·dt into the obstacle and the measured
        # velocity drops by v (with velocity feed-forward, the damping term then pushes), both before the next clamp.
        surge = kp * velocity * dt + kd * velocity
        if surge > effort:
            message = (
                f"kp {kp:g}, kd {kd:g}: a collision at the velocity limit ({velocity:g} rad/s) raises the drive's "
                f"torque by kp·v·dt + kd·v = {surge:.3g} N·m within one cycle, before the supervisor can clamp it: "
                f"more than the effort limit {effort:g} N·m"
            )
            findings.append(SafetyFinding("warning", ("joints", joint.name, key), message))
    hold, margin = joint.section.hold, limits.soft_margin
    if hold.kp * margin > effort:
        message = (
            f"hold kp {hold.kp:g} × soft_margin {margin:g} = {hold.kp * margin:.3g} N·m exceeds the effort limit "
            f"{effort:g} N·m: the hold saturates {effort / hold.kp:.3g} rad from where it holds, inside the soft "
            "margin, and resists further only with the effort limit, not with the stiffness configured"
        )
        findings.append(SafetyFinding("warning", ("joints", joint.name, "hold"), message))
    if joint.real and margin == 0.0:
        message = "soft_margin 0: commands may reach the hard position limit, where the joint faults; leave a margin"
        findings.append(SafetyFinding("warning", ("joints", joint.name, "limits", "soft_margin"), message))
    return findings


def _gain_ranges(
    joints: list[_Joint], driver_classes: Mapping[str, type], driver_params: Mapping[str, Params], config: RobotConfig
) -> list[SafetyFinding]:
    """Gains above what the drive accepts (after the transmission) are clamped silently by the drive, which then
    applies another torque than the one the supervisor predicted and limited."""
    findings = []
    ranges: dict[str, Any] = {}
    for hw_name, hw in config.hardware.items():
        cls, params = driver_classes.get(hw_name), driver_params.get(hw_name)
        if cls is not None and params is not None and hasattr(cls, "gain_ranges"):
            ranges.update(cls.gain_ranges(params, list(hw.joints)))
    for joint in joints:
        limit = ranges.get(joint.name)
        if limit is None:
            continue
        scale = joint.transmission.reduction**2  # joint gains → actuator gains: ÷ reduction²
        for key, kp, kd in _gain_sets(joint.section):
            for gain, value, most in (("kp", kp, limit.kp), ("kd", kd, limit.kd)):
                motor = value / scale
                if motor > most * (1.0 + 1e-9):
                    message = (
                        f"{gain} {value:g} is {motor:g} at the motor (÷ reduction² {scale:g}), above the drive's "
                        f"range 0..{most:g}: the drive would clamp it silently and apply less torque than the "
                        "supervisor predicts"
                    )
                    findings.append(SafetyFinding("error", ("joints", joint.name, key, gain), message))
    return findings


def _safety_section(config: RobotConfig, real_joints: list[str]) -> list[SafetyFinding]:
    if not real_joints:
        return []
    s, rate = config.safety, config.update_rate
    findings = []
    stale = s.stale_feedback_cycles / rate
    if stale > DETECTION_MAX:
        message = (
            f"{s.stale_feedback_cycles} cycles at {rate:g} Hz: a servo that stops answering is noticed only after "
            f"{stale:.3g} s; keep it within {DETECTION_MAX:g} s on real hardware"
        )
        findings.append(SafetyFinding("error", ("safety", "stale_feedback_cycles"), message))
    if s.stale_feedback_time > DETECTION_MAX:
        message = (
            f"a servo that stops answering is noticed only after {s.stale_feedback_time:g} s; keep it within "
            f"{DETECTION_MAX:g} s on real hardware"
        )
        findings.append(SafetyFinding("error", ("safety", "stale_feedback_time"), message))
    if s.max_cycle_gap == 0 or s.max_cycle_gap > DETECTION_MAX:
        message = (
            "0 disables the stall fault" if s.max_cycle_gap == 0 else f"a {s.max_cycle_gap:g} s stall is tolerated"
        ) + ": after a long stall the arm was on its drives' own watchdogs, and the cycle would carry on as if not"
        findings.append(SafetyFinding("warning", ("safety", "max_cycle_gap"), message))
    if s.max_consecutive_overruns == 0:
        message = "0 disables the overrun fault: a stalled cycle leaves the drives on their last command"
        findings.append(SafetyFinding("warning", ("safety", "max_consecutive_overruns"), message))
    elif s.max_consecutive_overruns / rate > DETECTION_MAX:
        message = (
            f"a stalled cycle faults the joints only after {s.max_consecutive_overruns / rate:.3g} s "
            f"(more than {DETECTION_MAX:g} s)"
        )
        findings.append(SafetyFinding("warning", ("safety", "max_consecutive_overruns"), message))
    for key in ("fault_action", "estop_action"):
        if getattr(s, key) == "disable":
            message = (
                f"disable leaves {', '.join(real_joints)} limp: an arm under gravity falls unless these joints have "
                "brakes or carry no load; hold or damp keep it up"
            )
            findings.append(SafetyFinding("warning", ("safety", key), message))
    if config.clock.source == "sim":
        message = (
            "the sim clock with real hardware: command timeouts, trajectories and watchdogs follow simulated time "
            "(for lockstep tests on virtual buses, never for a real arm)"
        )
        findings.append(SafetyFinding("warning", ("clock", "source"), message))
    return findings
