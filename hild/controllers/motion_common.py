"""What controllers that plan motion (joint_trajectory, servo) share: their claims, the limits they need, and
noticing the supervisor took a joint over."""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar, Protocol, cast

import numpy as np

from hild.config.model import JointLimits
from hild.config.params import Params
from hild.interfaces import interface_name
from hild.modes import JointMode

_TAKEN_OVER = int(JointMode.FAULT)  # FAULT and ESTOP: the supervisor decides the command


class PlansMotion:
    """For controllers that plan motion: they claim each of their joints' command interfaces, and a joint without
    acceleration and jerk limits cannot be planned for (unknown joints are reported elsewhere)."""

    KIND: ClassVar[str]  # the controller type, as problems name it
    MEASURED: ClassVar[tuple[str, ...]]  # the state fields its update reads of each of its joints
    params: Params

    @classmethod
    def claims_for(cls, params: Params) -> list[str]:
        planned = cast(_PlannedParams, params)
        return [interface_name(j, f) for j in planned.joints for f in planned.command_interfaces]

    def state_interfaces(self) -> list[str]:
        """``MEASURED`` of each of its joints: what it starts from and tracks against."""
        return [interface_name(j, f) for j in cast(_PlannedParams, self.params).joints for f in self.MEASURED]

    @classmethod
    def robot_problems(cls, params: Params, limits: Mapping[str, JointLimits]) -> list[str]:
        return [
            f"{cls.KIND} needs limits.acceleration and limits.jerk for joint {j} to plan its motion"
            for j in cast(_PlannedParams, params).joints
            if j in limits and (limits[j].acceleration is None or limits[j].jerk is None)
        ]


class _PlannedParams(Protocol):
    joints: list[str]
    command_interfaces: list[str]


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
