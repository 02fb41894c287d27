"""A worked example driver (docs/contributing.md): one simulated motor per joint that follows its position command
with a first-order lag, the way a stiff position-controlled servo does.

A real driver differs in what ``on_configure`` opens (a bus, a port) and what ``read``/``write`` exchange with the
drives; the shape is the same. It works in actuator space only (the engine applies transmissions) and on its own
joints only.
"""

from __future__ import annotations

import numpy as np

from hild.arrays import JointState, ServoCommand
from hild.config.params import Field, Params
from hild.hardware import HardwareComponent, HardwareContext


class LagMotorParams(Params):
    time_constant: float = Field(default=0.05, gt=0.0, description="Seconds for the shaft to cover 63 % of a step.")


class LagMotor(HardwareComponent):
    Params = LagMotorParams
    SIMULATED = True  # no real drive behind it: the config's hardware safety rules only warn

    def __init__(self, context: HardwareContext, params: LagMotorParams) -> None:
        super().__init__(context, params)
        n = len(context.joints)
        self.position = np.zeros(n)  # allocated once: read and write run on the cycle and must not allocate
        self.velocity = np.zeros(n)
        self._step = np.zeros(n)
        self.enabled = False
        self.time_constant = params.time_constant

    # Lifecycle (not real time: may block briefly, may raise HardwareError with a reason).
    def on_configure(self) -> None:
        """Open the bus and check every drive answers; a real driver refuses to start on a mismatch here."""

    def on_activate(self) -> None:
        self.enabled = True  # the engine has read once: the first command is a hold where the shaft is

    def on_deactivate(self) -> None:
        self.enabled = False  # limp, as a disabled drive

    # The cycle (real time: no blocking, no logging, no needless allocation).
    def read(self, t: float, dt: float, state: JointState) -> None:
        np.copyto(state.position, self.position)
        np.copyto(state.velocity, self.velocity)
        state.fresh.fill(True)  # every motor answered this cycle (a silent one would stay False)

    def write(self, t: float, dt: float, command: ServoCommand) -> None:
        if not self.enabled or dt <= 0.0:
            self.velocity.fill(0.0)
            return
        alpha = 1.0 - np.exp(-dt / self.time_constant)
        np.subtract(command.position, self.position, out=self._step)
        self._step *= alpha
        np.divide(self._step, dt, out=self.velocity)
        self.position += self._step
