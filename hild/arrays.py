"""Joint state and servo command as preallocated struct-of-arrays.

Every backend, controller and the supervisor exchange these two shapes. They are allocated once at start-up
and then only written in place (``arr[:] = …`` or ``np.copyto``), so the cycle thread never allocates for them.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

__all__ = [
    "COMMAND_FIELDS",
    "STATE_FIELDS",
    "JointState",
    "ServoCommand",
    "contiguous_slice",
    "gather_command",
    "scatter_state",
]

FloatArray = np.ndarray


@dataclass(slots=True)
class JointState:
    """Measured state per joint (or per actuator, before transmissions are applied).

    ``fault`` is the driver's raw fault code (0 = healthy); ``fresh`` says whether the driver received new
    feedback for that joint in this cycle, which is how the supervisor detects a servo that stops answering.
    """

    position: FloatArray
    velocity: FloatArray
    effort: FloatArray
    temperature: FloatArray
    fault: np.ndarray
    fresh: np.ndarray

    @classmethod
    def zeros(cls, n: int) -> JointState:
        return cls(
            position=np.zeros(n),
            velocity=np.zeros(n),
            effort=np.zeros(n),
            temperature=np.full(n, np.nan),
            fault=np.zeros(n, dtype=np.int64),
            fresh=np.ones(n, dtype=bool),
        )

    def copy_from(self, other: JointState) -> None:
        for name in STATE_FIELDS:
            np.copyto(getattr(self, name), getattr(other, name))

    def view(self, part: slice) -> JointState:
        """The joints ``part`` as views: what a component writes into them lands in this state, with no copy."""
        return JointState(*(getattr(self, name)[part] for name in STATE_FIELDS))

    def __len__(self) -> int:
        return len(self.position)


@dataclass(slots=True)
class ServoCommand:
    """The servo command: the drive computes ``τ = kp·(position − q) + kd·(velocity − q̇) + effort``.

    docs/architecture.md, "The servo command", has why every backend takes this one command.

    ``written`` is only meaningful on the controllers' side of the supervisor: a controller sets it for each
    joint it commanded in this cycle. A joint nobody wrote goes to hold, so silence is always safe.

    ``hold_effort`` too: the effort a joint keeps pressing with once its controller stops commanding it (a
    gripper's grasp, so a held or e-stopped gripper does not let go of what it holds; docs/safety.md, "Grasps").
    Every other controller leaves it 0; the supervisor keeps what the joint's controller last wrote.
    """

    position: FloatArray
    velocity: FloatArray
    effort: FloatArray
    kp: FloatArray
    kd: FloatArray
    written: np.ndarray
    hold_effort: FloatArray

    @classmethod
    def zeros(cls, n: int) -> ServoCommand:
        return cls(
            position=np.zeros(n),
            velocity=np.zeros(n),
            effort=np.zeros(n),
            kp=np.zeros(n),
            kd=np.zeros(n),
            written=np.zeros(n, dtype=bool),
            hold_effort=np.zeros(n),
        )

    def copy_from(self, other: ServoCommand) -> None:
        for name in COMMAND_FIELDS:
            np.copyto(getattr(self, name), getattr(other, name))

    def view(self, part: slice) -> ServoCommand:
        """The joints ``part`` as views of this command (read by a component in place, no copy)."""
        return ServoCommand(*(getattr(self, name)[part] for name in COMMAND_FIELDS))

    def __len__(self) -> int:
        return len(self.position)


STATE_FIELDS = tuple(f.name for f in fields(JointState))
COMMAND_FIELDS = tuple(f.name for f in fields(ServoCommand))


def scatter_state(src: JointState, index: np.ndarray, dst: JointState) -> None:
    """Write a component's (smaller) state into the joints ``index`` of the robot's state."""
    for name in STATE_FIELDS:
        getattr(dst, name)[index] = getattr(src, name)


def gather_command(src: ServoCommand, index: np.ndarray, dst: ServoCommand) -> None:
    """Copy the joints ``index`` of the robot's command into a component's (smaller) command, in place."""
    for name in COMMAND_FIELDS:
        getattr(src, name).take(index, out=getattr(dst, name))


def contiguous_slice(addresses: np.ndarray) -> slice | None:
    """``slice(a, a + n)`` when ``addresses`` are ``a, a+1, …, a+n-1`` (views are cheaper than take/put), else None."""
    n = len(addresses)
    if n and np.array_equal(addresses, np.arange(addresses[0], addresses[0] + n)):
        return slice(int(addresses[0]), int(addresses[0]) + n)
    return None
