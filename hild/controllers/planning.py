"""What controllers that plan motion (joint_trajectory, servo) share: their claims and the limits they need."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence

from hild.config.model import JointLimits
from hild.interfaces import interface_name


def interface_claims(joints: Sequence[str], fields: Iterable[str]) -> list[str]:
    """``<joint>/<field>`` for every joint and each of ``fields``."""
    fields = list(fields)
    return [interface_name(j, f) for j in joints for f in fields]


def missing_planning_limits(kind: str, joints: Sequence[str], limits: Mapping[str, JointLimits]) -> list[str]:
    """One problem per joint without the acceleration and jerk limits a planner needs (unknown joints are
    reported elsewhere)."""
    return [
        f"{kind} needs limits.acceleration and limits.jerk for joint {j} to plan its motion"
        for j in joints
        if j in limits and (limits[j].acceleration is None or limits[j].jerk is None)
    ]
