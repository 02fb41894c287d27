"""force_torque_sensor_broadcaster: publishes a force/torque sensor's accepted wrench at ``publish_rate``.

Its params are ros2_controllers' (``sensor_name``, or ``interface_names.force.x`` … ``torque.z``; ``frame_id``)
plus ``publish_rate`` and a first-order low-pass filter (``low_pass_cutoff``, Hz; 0 = off), both dynamic. It
claims nothing, so it runs beside any controller and through an e-stop. The filter runs every cycle on the accepted
readings (a rejected or missing one leaves it where it was); a sample goes into the ``wrench`` ring at the publish
rate, with ``fresh`` false when a sensor it reads had no accepted reading that cycle (docs/safety.md, "Sensor
plausibility"). The API publishes it as JSON on ``hild/<robot>/<controller>/wrench`` (``{stamp, frame_id, force:
{x, y, z}, torque: {x, y, z}, fresh}``) and, on the ROS 2 face, as ``geometry_msgs/msg/WrenchStamped`` on
``<controller>/wrench``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from hild.arrays import JointState, ServoCommand
from hild.config.params import Field, Params, dynamic, model_validator
from hild.controller import Controller, ControllerContext, ShapedOutput
from hild.interfaces import FORCE_TORQUE, SENSOR_INTERFACES, sensor_interface

OUTPUT = "wrench"
AXES = ("x", "y", "z")
RING_FIELDS = ("force", "torque", "fresh")  # width 3; fresh is the same in its three places


class Axes(Params):
    x: str = Field(default="", description="State interface of the x component; empty: not measured (0).")
    y: str = Field(default="", description="State interface of the y component; empty: not measured (0).")
    z: str = Field(default="", description="State interface of the z component; empty: not measured (0).")


class WrenchInterfaces(Params):
    force: Axes = Field(default_factory=Axes)
    torque: Axes = Field(default_factory=Axes)

    def names(self) -> list[str]:
        """In wrench order (force.x … torque.z); "" where none is named."""
        return [getattr(getattr(self, part), axis) for part in ("force", "torque") for axis in AXES]


class ForceTorqueBroadcasterParams(Params):
    sensor_name: str = Field(
        default="", description="The force_torque sensor to publish (its six interfaces); or give interface_names."
    )
    interface_names: WrenchInterfaces = Field(
        default_factory=WrenchInterfaces,
        description="Each component's state interface, when not a sensor's six (sensor_name empty).",
    )
    frame_id: str = Field(default="", description="Frame of the published wrench; default: the sensor's frame_id.")
    publish_rate: float = dynamic(default=100.0, gt=0.0, description="Hz; at most the update rate.")
    low_pass_cutoff: float = dynamic(
        default=0.0, ge=0.0, description="Hz of a first-order low-pass filter on every component; 0 = off."
    )

    @model_validator(mode="after")
    def _one_source(self) -> ForceTorqueBroadcasterParams:
        named = [n for n in self.interface_names.names() if n]
        if self.sensor_name and named:
            raise ValueError("give sensor_name or interface_names, not both")
        if not self.sensor_name and not named:
            raise ValueError("give sensor_name (a force_torque sensor) or interface_names (force.x … torque.z)")
        return self

    def interfaces(self) -> list[str]:
        """The six interfaces in wrench order, "" for a component not measured."""
        if self.sensor_name:
            return [sensor_interface(self.sensor_name, v) for v in SENSOR_INTERFACES[FORCE_TORQUE]]
        return self.interface_names.names()


class ForceTorqueSensorBroadcaster(Controller):
    Params = ForceTorqueBroadcasterParams

    def __init__(self, context: ControllerContext, params: ForceTorqueBroadcasterParams) -> None:
        super().__init__(context, params)
        names = params.interfaces()
        measured = [i for i, n in enumerate(names) if n]
        sensors = context.sensors
        self._where = np.array(measured, dtype=np.intp)  # components measured, in wrench order
        self._index = sensors.index_of([names[i] for i in measured])  # their places in the sensor values
        self._sensors = sorted({sensors.sensor_index(names[i]) for i in measured})
        first = names[measured[0]].split("/", 1)[0]
        self.frame_id = params.frame_id or sensors.spec(first).frame_id
        self.ring = context.mailboxes.ring(OUTPUT, 3, RING_FIELDS)
        self._measured = np.zeros(len(measured))  # this cycle's accepted values of the measured components
        self._filtered = np.zeros(len(measured))  # the filter's state (without a filter: the last accepted values)
        self._step = np.zeros(len(measured))
        self._out = np.zeros(6)  # wrench order; components not measured stay 0
        self._started = False
        self._interval = 1.0
        self._alpha = 1.0
        self._next = 0.0
        self.on_params(params)

    @classmethod
    def joints_for(cls, params: Params) -> list[str]:
        return []

    @classmethod
    def sensor_interfaces_for(cls, params: Params) -> list[str]:
        assert isinstance(params, ForceTorqueBroadcasterParams)
        return [n for n in params.interfaces() if n]

    def state_interfaces(self) -> list[str]:
        return self.sensor_interfaces_for(self.params)

    def on_activate(self, state: JointState, last_command: ServoCommand) -> None:
        self._next = -np.inf  # publish on the first cycle
        self._started = False

    def on_params(self, old: Params) -> None:
        p = self.params
        assert isinstance(p, ForceTorqueBroadcasterParams)
        rate = self.context.update_rate
        self._interval = 1.0 / min(p.publish_rate, rate)
        # y += α·(x − y) per cycle: the exact discretisation of a first-order lag of cutoff fc at the cycle's rate
        self._alpha = 1.0 - math.exp(-2.0 * math.pi * p.low_pass_cutoff / rate) if p.low_pass_cutoff > 0 else 1.0

    def update(self, t: float, dt: float, state: JointState, command: ServoCommand) -> None:
        sensors = self.context.sensors
        fresh = True
        for k in self._sensors:
            if not sensors.fresh[k]:
                fresh = False
        if fresh:  # preallocated: no array is made per cycle
            np.take(sensors.values, self._index, out=self._measured)
            if self._started and self._alpha < 1.0:
                np.subtract(self._measured, self._filtered, out=self._step)
                self._step *= self._alpha
                self._filtered += self._step
            else:
                np.copyto(self._filtered, self._measured)
                self._out.fill(0.0)
                self._started = True
        if t + 1e-9 < self._next:  # keep the phase; resync after a gap (as joint_state_broadcaster does)
            return
        self._next += self._interval
        if self._next <= t:
            self._next = t + self._interval
        out = self._out
        if self._started:
            np.put(out, self._where, self._filtered)
        else:
            out.fill(np.nan)  # no accepted reading yet: null in JSON, fresh false
        ring = self.ring
        i = ring.slot()
        ring.data["force"][i] = out[:3]
        ring.data["torque"][i] = out[3:]
        ring.data["fresh"][i] = 1.0 if fresh else 0.0
        ring.commit(t)
        self.context.notify()

    def wrench_message(self, seq: int, stamp: float, fields: dict[str, list[float]]) -> dict[str, Any]:
        """A ring sample as the JSON ``wrench`` message."""
        force, torque = fields["force"], fields["torque"]
        return {
            "stamp": stamp,
            "seq": seq,
            "frame_id": self.frame_id,
            "force": dict(zip(AXES, force, strict=True)),
            "torque": dict(zip(AXES, torque, strict=True)),
            "fresh": bool(fields["fresh"][0]),
        }

    def outputs(self) -> Mapping[str, ShapedOutput]:
        return {OUTPUT: ShapedOutput(self.ring, self.wrench_message)}
