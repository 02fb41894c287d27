"""Joint state, servo command and sensor values as preallocated struct-of-arrays.

Every backend, controller and the supervisor exchange these two shapes. They are allocated once at start-up
and then only written in place (``arr[:] = …`` or ``np.copyto``), so the cycle thread never allocates for them.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from hild.interfaces import SensorLayout, SensorSpec

__all__ = [
    "COMMAND_FIELDS",
    "STATE_FIELDS",
    "JointState",
    "MimicJoint",
    "MimicJoints",
    "SensorValues",
    "SensorView",
    "ServoCommand",
    "contiguous_slice",
    "gather_command",
    "scatter_state",
]

FloatArray = np.ndarray
MOTION_FIELDS = ("position", "velocity", "effort")  # a state's float fields the servo law uses
SERVO_FIELDS = ("position", "velocity", "effort", "kp", "kd")  # the servo command's five fields


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
    def zeros(cls, n: int, over: Callable[[str], FloatArray] | None = None) -> JointState:
        """A zero state; ``over(field)``: an existing zeroed array to use for position, velocity and effort (the
        engine's cycle-log row: hild.crossing.cyclelog.CycleRow), fresh arrays for the rest."""
        motion = {name: np.zeros(n) if over is None else over(name) for name in MOTION_FIELDS}
        return cls(
            **motion,
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
    def zeros(cls, n: int, over: Callable[[str], FloatArray] | None = None) -> ServoCommand:
        """A zero command; ``over(field)``: an existing zeroed array to use for each of the five servo fields (the
        engine's cycle-log row: hild.crossing.cyclelog.CycleRow), fresh arrays for the rest."""
        servo = {name: np.zeros(n) if over is None else over(name) for name in SERVO_FIELDS}
        return cls(**servo, written=np.zeros(n, dtype=bool), hold_effort=np.zeros(n))

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


@dataclass(frozen=True, slots=True)
class MimicJoint:
    """A joint nothing commands that follows a robot joint (the config's ``mimic_joints``; URDF ``<mimic>``):
    ``position = multiplier·q + offset``, ``velocity = multiplier·q̇``, as ros2_control reads them."""

    name: str
    joint: str  # the robot joint it follows
    multiplier: float = 1.0
    offset: float = 0.0


class MimicJoints:
    """The robot's mimic joints as arrays over the robot's joint order, computed in place (no allocation)."""

    __slots__ = ("joints", "leader", "multiplier", "names", "offset")

    def __init__(self, joints: Iterable[MimicJoint], robot_joints: Sequence[str]) -> None:
        self.joints = tuple(joints)
        index = {name: i for i, name in enumerate(robot_joints)}
        self.names = tuple(m.name for m in self.joints)
        self.leader = np.array([index[m.joint] for m in self.joints], dtype=np.intp)
        self.multiplier = np.array([m.multiplier for m in self.joints], dtype=float)
        self.offset = np.array([m.offset for m in self.joints], dtype=float)

    @classmethod
    def of(cls, cfg: Any) -> MimicJoints:
        """From a validated config (its ``mimic_joints`` section), over its joints."""
        section = getattr(cfg, "mimic_joints", None) or {}
        mimics = [MimicJoint(name, m.joint, m.multiplier, m.offset) for name, m in section.items()]
        return cls(mimics, list(cfg.joints))

    def __len__(self) -> int:
        return len(self.joints)

    def positions(self, position: np.ndarray, out: np.ndarray) -> None:
        """``out[k] = multiplier[k]·position[leader[k]] + offset[k]``; ``position`` over the robot's joints."""
        np.take(position, self.leader, out=out)
        out *= self.multiplier
        out += self.offset

    def velocities(self, velocity: np.ndarray, out: np.ndarray) -> None:
        """``out[k] = multiplier[k]·velocity[leader[k]]``."""
        np.take(velocity, self.leader, out=out)
        out *= self.multiplier


@dataclass(slots=True)
class SensorValues:
    """Every sensor value (flat float64, sensors in config order) and, per sensor, whether it is a new reading.

    Allocated once; a component writes its own part in place (``view``) in ``read_sensors``."""

    values: np.ndarray
    fresh: np.ndarray

    @classmethod
    def zeros(cls, width: int, sensors: int) -> SensorValues:
        return cls(values=np.zeros(width), fresh=np.zeros(sensors, dtype=bool))

    def view(self, values: slice, sensors: slice) -> SensorValues:
        """A component's sensors as views of this array: what it writes lands here, with no copy."""
        return SensorValues(self.values[values], self.fresh[sensors])


class SensorView:
    """What a controller sees of the sensors: the *accepted* values (a rejected or missing reading is replaced by
    the last accepted one) and per sensor ``fresh``, read-only views of the engine's arrays, live on the cycle.

    In the client domain (a controller's API half) the arrays are zeros: only the cycle half reads values."""

    def __init__(self, layout: SensorLayout, values: np.ndarray | None = None, fresh: np.ndarray | None = None) -> None:
        self.layout = layout
        values = np.zeros(layout.width) if values is None else values
        fresh = np.zeros(len(layout.sensors), dtype=bool) if fresh is None else fresh
        self.values = values.view()
        self.values.flags.writeable = False
        self.fresh = fresh.view()
        self.fresh.flags.writeable = False
        self.names: tuple[str, ...] = layout.names
        self.interfaces: tuple[str, ...] = tuple(layout.interfaces())
        self._index = {name: i for i, name in enumerate(self.interfaces)}
        self._sensor_of = [k for k, s in enumerate(layout.sensors) for _ in range(s.width)]

    def spec(self, sensor: str) -> SensorSpec:
        """The sensor named ``sensor``; KeyError naming the robot's sensors when there is none."""
        try:
            return self.layout.spec(sensor)
        except KeyError:
            raise KeyError(f"no sensor {sensor!r} (sensors: {', '.join(self.names) or 'none'})") from None

    def index_of(self, interfaces: Sequence[str]) -> np.ndarray:
        """Positions of ``interfaces`` in ``values``; ValueError naming those no sensor provides."""
        missing = [n for n in interfaces if n not in self._index]
        if missing:
            known = ", ".join(self.interfaces) or "none"
            raise ValueError(f"no sensor provides {missing} (sensor interfaces: {known})")
        return np.array([self._index[n] for n in interfaces], dtype=np.intp)

    def sensor_index(self, interface: str) -> int:
        """The position in ``fresh`` of the sensor that provides ``interface``."""
        return self._sensor_of[int(self.index_of([interface])[0])]
