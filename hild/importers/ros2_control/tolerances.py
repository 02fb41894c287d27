"""Whether a joint's stiffness can hold the goal tolerance its trajectory controller demands against its own friction.

A joint with Coulomb friction ``f`` comes to rest wherever its spring pulls less than ``f``: up to ``f / kp`` from
the target (``kp`` the drive's position gain, or ``p`` of an effort PID without integral). A goal tolerance tighter
than that is a goal that aborts on the real arm, whatever the twin shows (MuJoCo's friction is soft: a twin joint
creeps on toward the target, a real one sticks). So, per joint of every trajectory controller with a goal tolerance:
the rest error may use at most ``FRICTION_SHARE`` of it. Gains the importer chose are raised to that, within the gain
rules ``hild check`` holds them to (:class:`~hild.importers.ros2_control.gains.GainLimits`); gains from the user's
PID are the user's, and the report says what they would need. Either way, a tolerance that cannot be met is said,
with why.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from hild.importers.ros2_control.controllers import ControllerPlan, ControllersPlan
from hild.importers.ros2_control.gains import GainLimits, raised_gains
from hild.importers.ros2_control.mapping import JointPlan
from hild.importers.ros2_control.report import Report

FRICTION_SHARE = 0.5  # of the goal tolerance the friction rest error may take: the rest is for the motion's end


@dataclass(frozen=True)
class Demand:
    """The tightest goal tolerance any trajectory controller demands of a joint."""

    goal: float
    controller: ControllerPlan


def goal_demands(plan: ControllersPlan) -> dict[str, Demand]:
    """Per joint, the tightest goal tolerance (> 0) of the trajectory controllers over it."""
    demands: dict[str, Demand] = {}
    for controller in plan.controllers:
        if controller.type != "joint_trajectory":
            continue
        for joint, tolerance in controller.params.get("constraints", {}).get("joints", {}).items():
            goal = float(tolerance.get("goal", 0.0))
            if goal > 0 and (joint not in demands or goal < demands[joint].goal):
                demands[joint] = Demand(goal, controller)
    return demands


def fit_friction(joints: list[JointPlan], plan: ControllersPlan, update_rate: float, report: Report) -> None:
    """Raise the importer's own hold gains where friction / kp would eat more than ``FRICTION_SHARE`` of a goal
    tolerance, within the gain rules; report every tolerance the stiffness cannot meet (runs before the twin's step
    is chosen, so the step fits the raised gains)."""
    demands = goal_demands(plan)
    for joint in joints:
        demand = demands.get(joint.name)
        friction = joint.inertia.friction
        if demand is None or friction <= 0:
            continue
        needed = friction / (FRICTION_SHARE * demand.goal)
        effort_pid = demand.controller.pid.get(joint.name)
        if effort_pid is not None:
            _check_user_pid(joint, demand, effort_pid.p, effort_pid.i, needed, report)
        elif joint.gains_pid is not None:
            _check_user_pid(joint, demand, joint.kp, 0.0, needed, report)
        elif joint.kp < needed:
            _raise_default(joint, demand, needed, update_rate, report)


def _tolerance(joint: JointPlan, demand: Demand) -> str:
    return f"goal tolerance {demand.goal:g} of {demand.controller.name} on {joint.name}"


def _check_user_pid(joint: JointPlan, demand: Demand, p: float, i: float, needed: float, report: Report) -> None:
    """The user's own gains: never changed; said when they cannot hold the tolerance against friction."""
    friction = joint.inertia.friction
    if p >= needed or i > 0:  # an integral works a friction rest off (the tracking check times it)
        return
    rest = friction / p if p > 0 else math.inf
    report.tracking(
        demand.controller.where,
        f"{_tolerance(joint, demand)} cannot be met by your gains on a real arm: friction {friction:g} N·m against "
        f"p {p:g} rests up to {rest:.3g} rad from the target; p ≥ {needed:.4g} (or an integral, or a goal tolerance "
        f"≥ {rest / FRICTION_SHARE:.3g}) would hold it",
    )


def _raise_default(joint: JointPlan, demand: Demand, needed: float, update_rate: float, report: Report) -> None:
    """The importer's own gains: raised to what the tolerance needs, or to the most the gain rules allow."""
    friction, heavy = joint.inertia.friction, joint.inertia.heaviest
    limits = GainLimits(joint.velocity, joint.effort, joint.soft_margin, 1.0 / update_rate)
    kp, kd, capped = raised_gains(needed, heavy, limits)
    if kp > joint.kp:
        old = joint.kp
        joint.kp, joint.kd = kp, kd
        joint.gains_from = f"raised for friction {friction:g} N·m vs the {_tolerance(joint, demand)}, critically damped"
        report.approximated(
            joint.where,
            f"{joint.name}: hold kp {old:g} → {kp:g}, kd {joint.kd:g}: friction {friction:g} N·m rested up to "
            f"{friction / old:.3g} rad off, more than {FRICTION_SHARE:g} × the {_tolerance(joint, demand)}",
        )
    if capped:
        rest = friction / joint.kp
        report.tracking(
            demand.controller.where,
            f"{_tolerance(joint, demand)} cannot be met on a real arm: friction {friction:g} N·m against kp "
            f"{joint.kp:g} (the most hild check's gain rules allow with effort limit {joint.effort:g} N·m) rests up "
            f"to {rest:.3g} rad from the target; loosen it to ≥ "
            f"{rest / FRICTION_SHARE:.3g}, or raise the effort limit",
        )
