"""Joint modes — what the supervisor does with a joint — and joint sources — who moved it — readable by controllers
without importing the supervisor."""

from __future__ import annotations

import enum

__all__ = [
    "MODE_NAMES",
    "SOURCE_NAMES",
    "JointMode",
    "Source",
]


class JointMode(enum.IntEnum):
    HOLD = 0  # no controller commands it: held at its latched position
    CONTROLLED = 1  # an active controller commands it
    FAULT = 2  # a latched fault: its safe action until reset
    ESTOP = 3  # e-stop: its safe action until reset


MODE_NAMES = {m.value: m.name.lower() for m in JointMode}


class Source(enum.IntEnum):
    """Provenance: who moved a joint in a cycle — a human through a leader arm, a policy, a trajectory, hold.

    A dataset is filtered by it ("train only on the human demonstrations"), so each cycle's record says it per
    joint (docs/recording.md, "Provenance"). A controller declares the source of what it commands: its class's
    ``SOURCE``, or, for one that takes more than one kind of input (the servo: streamed targets or a policy's
    chunks), the ``source`` attribute it sets on the cycle side when the kind changes. A joint no controller
    commands is ``HOLD``.
    """

    HOLD = 0  # no controller: the supervisor holds it (or its fault / e-stop action)
    TRAJECTORY = 1  # planned motion: joint_trajectory goals, move_to, replay, a gripper's goals
    STREAM = 2  # a client's streamed commands: servo targets, forward_command, impedance targets
    LEADER = 3  # a human, through a leader arm (follow)
    POLICY = 4  # a policy's action chunks
    HAND = 5  # a human's hand on the arm (teach mode)


SOURCE_NAMES = {s.value: s.name.lower() for s in Source}
