"""Command interfaces and exclusive claims; sensors' state interfaces.

A command interface is named ``<joint>/<field>`` with field one of the servo command's ``position, velocity,
effort, kp, kd``. A claim is exclusive, and stricter than ros2_control: all claimed fields of one joint belong to
the same controller, because the five fields form one servo command and mixing owners has no safe meaning.

A controller that claims effort may also ask for **gravity on top** of it (``Controller.gravity_joints``): the
supervisor then adds the robot model's gravity torque to that controller's effort for those joints, as a real arm's
driver does under an effort-interface controller (docs/safety.md, "Gravity on top of an effort command").
A sensor (a wrist force/torque sensor, an IMU) is declared under the hardware component that reads it
(``hardware.<component>.sensors``) and exposes state interfaces only, named as ros2_control's semantic components
name them: ``<sensor>/force.x … torque.z`` (``force_torque``), ``<sensor>/orientation.x … w``,
``angular_velocity.x …``, ``linear_acceleration.x …`` (``imu``). Every sensor value of the robot lives in one flat
float64 array, the sensors in config order (:class:`SensorLayout`), each a contiguous block
(``hild.arrays.SensorValues``; controllers read the accepted ones through ``hild.arrays.SensorView``).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = [
    "FIELDS",
    "FORCE_TORQUE",
    "IMU",
    "SENSOR_INTERFACES",
    "ClaimError",
    "ClaimMasks",
    "SensorLayout",
    "SensorSpec",
    "build_masks",
    "check_claims",
    "interface_name",
    "parse_interface",
    "sensor_interface",
]

FIELDS = ("position", "velocity", "effort", "kp", "kd")


class ClaimError(ValueError):
    pass


def interface_name(joint: str, field: str) -> str:
    return f"{joint}/{field}"


def parse_interface(name: str) -> tuple[str, str]:
    joint, sep, field = name.rpartition("/")
    if not sep or not joint or field not in FIELDS:
        raise ClaimError(f"bad interface name {name!r}: expected '<joint>/<{'|'.join(FIELDS)}>'")
    return joint, field


def check_claims(claimant: str, claims: Iterable[str], available: set[str]) -> None:
    for name in claims:
        parse_interface(name)
        if name not in available:
            raise ClaimError(f"{claimant}: interface {name!r} does not exist")


@dataclass(slots=True)
class ClaimMasks:
    """Per-joint view of who claims what, rebuilt at each switch and read by the supervisor every cycle."""

    owner: np.ndarray  # controller slot index per joint, -1 = unclaimed
    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray
    kp: np.ndarray
    kd: np.ndarray
    gravity: np.ndarray  # the supervisor adds the gravity torque to the owner's effort command (effort claims only)

    @classmethod
    def empty(cls, n: int) -> ClaimMasks:
        return cls(np.full(n, -1, dtype=np.int64), *(np.zeros(n, dtype=bool) for _ in (*FIELDS, "gravity")))


def build_masks(
    joint_index: Mapping[str, int],
    claims_by_slot: Mapping[int, Iterable[str]],
    owner_names: Mapping[int, str],
    gravity_by_slot: Mapping[int, Iterable[str]] | None = None,
) -> ClaimMasks:
    """Turn the active controllers' claims into masks; raises ClaimError on any conflict. ``gravity_by_slot``: the
    joints each controller wants gravity added to its effort on (a joint whose effort it does not claim is
    refused: there is no effort of its own to add to)."""
    masks = ClaimMasks.empty(len(joint_index))
    taken: dict[str, int] = {}
    for slot, claims in claims_by_slot.items():
        for name in claims:
            joint, field = parse_interface(name)
            if name in taken:
                raise ClaimError(f"{name} is claimed by both {owner_names[taken[name]]} and {owner_names[slot]}")
            i = joint_index[joint]
            if masks.owner[i] not in (-1, slot):
                other = owner_names[int(masks.owner[i])]
                raise ClaimError(f"joint {joint} is commanded by {other}; {owner_names[slot]} cannot claim {name}")
            taken[name] = slot
            masks.owner[i] = slot
            getattr(masks, field)[i] = True
    for slot, joints in (gravity_by_slot or {}).items():
        for joint in joints:
            i = joint_index[joint]
            if masks.owner[i] != slot or not masks.effort[i]:
                raise ClaimError(
                    f"{owner_names[slot]} asks for gravity on top of its effort on {joint}, which it "
                    "does not command by effort"
                )
            masks.gravity[i] = True
    return masks


# ---- sensors: state interfaces only ------------------------------------------------------------------------
FORCE_TORQUE = "force_torque"
IMU = "imu"
_AXES = ("x", "y", "z")
SENSOR_INTERFACES: dict[str, tuple[str, ...]] = {
    FORCE_TORQUE: (*(f"force.{a}" for a in _AXES), *(f"torque.{a}" for a in _AXES)),
    IMU: (
        *(f"orientation.{a}" for a in (*_AXES, "w")),
        *(f"angular_velocity.{a}" for a in _AXES),
        *(f"linear_acceleration.{a}" for a in _AXES),
    ),
}
# Which limit bounds each group of a sensor's values (the magnitude of every component); orientation has none.
LIMITED = frozenset({"force", "torque", "angular_velocity", "linear_acceleration"})


def sensor_interface(sensor: str, value: str) -> str:
    """``<sensor>/<value>``, e.g. ``wrist_ft/force.z``."""
    return f"{sensor}/{value}"


@dataclass(frozen=True, slots=True)
class SensorSpec:
    """One sensor as the config declares it; ``offset`` is where its values start in the robot's flat array."""

    name: str
    type: str  # force_torque | imu
    frame_id: str
    hardware: str  # the component that reads it
    offset: int
    bounds: tuple[float, ...]  # per value: the largest plausible magnitude (inf: unbounded)

    @property
    def values(self) -> tuple[str, ...]:
        """Its values' short names, in array order (``force.x``, …)."""
        return SENSOR_INTERFACES[self.type]

    @property
    def width(self) -> int:
        return len(self.values)

    @property
    def part(self) -> slice:
        return slice(self.offset, self.offset + self.width)

    def interfaces(self) -> list[str]:
        """Its state interfaces' full names (``<sensor>/force.x``, …)."""
        return [sensor_interface(self.name, v) for v in self.values]


@dataclass(frozen=True)
class SensorLayout:
    """The robot's sensors, in config order (each component's sensors one after the other)."""

    sensors: tuple[SensorSpec, ...] = ()

    @classmethod
    def of(cls, cfg: Any) -> SensorLayout:
        """The sensors of a validated config (``hild.config.model.RobotConfig``)."""
        specs, offset = [], 0
        for hw_name, hw in cfg.hardware.items():
            for name, section in hw.sensors.items():
                bounds = _bounds(section.type, section.limits.ranges(section.type))
                specs.append(SensorSpec(name, section.type, section.frame_id, hw_name, offset, bounds))
                offset += len(bounds)
        return cls(tuple(specs))

    @property
    def width(self) -> int:
        return sum(s.width for s in self.sensors)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(s.name for s in self.sensors)

    def of_hardware(self, hardware: str) -> tuple[SensorSpec, ...]:
        return tuple(s for s in self.sensors if s.hardware == hardware)

    def interfaces(self) -> list[str]:
        return [i for s in self.sensors for i in s.interfaces()]

    def bounds(self) -> np.ndarray:
        return np.array([b for s in self.sensors for b in s.bounds], dtype=np.float64)

    def spec(self, name: str) -> SensorSpec:
        for s in self.sensors:
            if s.name == name:
                return s
        raise KeyError(name)

    def describe(self) -> list[dict[str, Any]]:
        """Each sensor as list_hardware reports it: name, type, frame_id, hardware, state_interfaces."""
        return [
            {"name": s.name, "type": s.type, "frame_id": s.frame_id, "hardware": s.hardware,
             "state_interfaces": s.interfaces()}
            for s in self.sensors
        ]  # fmt: skip


def _bounds(kind: str, ranges: Mapping[str, float]) -> tuple[float, ...]:
    out = []
    for value in SENSOR_INTERFACES[kind]:
        group = value.split(".", 1)[0]
        out.append(float(ranges[group]) if group in LIMITED else float("inf"))
    return tuple(out)
