"""Joint modes: what the supervisor does with a joint, readable by controllers without importing the supervisor."""

from __future__ import annotations

import enum

__all__ = [
    "MODE_NAMES",
    "JointMode",
]


class JointMode(enum.IntEnum):
    HOLD = 0  # no controller commands it: held at its latched position
    CONTROLLED = 1  # an active controller commands it
    FAULT = 2  # a latched fault: its safe action until reset
    ESTOP = 3  # e-stop: its safe action until reset


MODE_NAMES = {m.value: m.name.lower() for m in JointMode}
