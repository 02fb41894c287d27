"""What controllers that plan motion (joint_trajectory, servo) share: their claims and the limits they need."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence

import numpy as np

from hild.config.model import JointLimits
from hild.interfaces import interface_name
from hild.modes import JointMode

_TAKEN_OVER = int(JointMode.FAULT)  # FAULT and ESTOP: the supervisor decides the command


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


def first_taken_over(modes: np.ndarray | None, index: np.ndarray, scratch: np.ndarray) -> int:
    """Position in ``index`` of the first joint the supervisor has taken over (fault or e-stop), else -1.

    While that lasts the joint's command is ignored; a planning controller follows the measured state instead
    of its plan, so an operator reset continues from where the arm is. ``scratch``: int64 like ``index``.
    Runs every cycle: one gather and plain ints (numpy reductions on a handful of elements cost microseconds)."""
    if modes is None:
        return -1
    modes.take(index, out=scratch)
    for k, mode in enumerate(scratch.tolist()):
        if mode >= _TAKEN_OVER:
            return k
    return -1
