"""The sensor contract: state-only interfaces a hardware component provides besides its joints.

A sensor (a wrist force/torque sensor, an IMU) is declared under the hardware component that reads it
(``hardware.<component>.sensors``) and exposes its values as state interfaces named as ros2_control's semantic
components name them: ``<sensor>/force.x … torque.z`` (``force_torque``), ``<sensor>/orientation.x … w``,
``angular_velocity.x …``, ``linear_acceleration.x …`` (``imu``). Nothing commands a sensor.

Every sensor value of the robot lives in one preallocated flat float64 array (:class:`SensorValues`), the sensors
in config order, each a contiguous block; a component fills its own blocks in ``read_sensors`` (views: no copy),
the engine's gate (``hild.cycle.sensor_gate``) accepts or stands in for each sensor's reading, and controllers read
the accepted values through a read-only :class:`SensorView`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = [
    "FORCE_TORQUE",
    "IMU",
    "SENSOR_INTERFACES",
    "SensorLayout",
    "SensorSpec",
    "SensorValues",
    "SensorView",
    "sensor_interface",
]

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
