"""A worked example controller (docs/contributing.md): sweeps its joints through a sine around where they were
when it was activated, with an ``amplitude`` input a client may stream.

It shows the two halves every controller has: the API half validates a client's input and hands it over through
a door from ``context.mailboxes`` (it may run in another process than the cycle), and the cycle half's ``update``
takes it and writes the command. What it does not write, the supervisor holds.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from hild.arrays import JointState, ServoCommand
from hild.config.params import Field, Params
from hild.controller import Controller, ControllerContext
from hild.interfaces import interface_name

MAX_AMPLITUDE = 0.5  # rad


class SineSweepParams(Params):
    joints: list[str] = Field(min_length=1, description="Joints swept, all with the same phase.")
    amplitude: float = Field(default=0.1, ge=0.0, le=MAX_AMPLITUDE, description="Radians, until a client sets it.")
    frequency: float = Field(default=0.5, gt=0.0, le=5.0, description="Hz.")


class SineSweep(Controller):
    Params = SineSweepParams

    def __init__(self, context: ControllerContext, params: SineSweepParams) -> None:
        super().__init__(context, params)
        self._joints = list(params.joints)
        self._index = context.index_of(params.joints)
        self._amplitude_door = context.mailboxes.latest_numbers("amplitude", 1)
        self._amplitude = params.amplitude
        self._center = np.zeros(len(self._index))
        self._target = np.zeros(len(self._index))
        self._frequency = params.frequency
        self._start: float | None = None

    @classmethod
    def claims_for(cls, params: Params) -> list[str]:
        assert isinstance(params, SineSweepParams)
        return [interface_name(joint, "position") for joint in params.joints]

    def state_interfaces(self) -> list[str]:
        """It reads where its joints are when activated (list_controllers reports it)."""
        return [interface_name(joint, "position") for joint in self._joints]

    # ---- API half: a client's {"amplitude": a} on ctrl/<name>/amplitude -----------------------------------------
    def inputs(self) -> Mapping[str, Callable[[Any], None]]:
        return {"amplitude": self.accept_amplitude}

    def accept_amplitude(self, payload: Any) -> None:
        """Validate, then hand over; a ValueError's text is what the client's drop event says."""
        if not self.active:
            raise ValueError(f"controller {self.name} is not active")
        if not isinstance(payload, dict) or set(payload) != {"amplitude"}:
            raise ValueError('expected an object {"amplitude": <radians>}')
        value = payload["amplitude"]
        if isinstance(value, bool) or not isinstance(value, int | float) or not 0.0 <= value <= MAX_AMPLITUDE:
            raise ValueError(f"amplitude must be a number in [0, {MAX_AMPLITUDE}]")
        self._amplitude_door.put([float(value)])

    # ---- cycle half -------------------------------------------------------------------------------------------
    def on_activate(self, state: JointState, last_command: ServoCommand) -> None:
        """Start where the joints are: sin(0) = 0, so the first command is the measured position (no jump)."""
        np.copyto(self._center, state.position[self._index])
        self._amplitude_door.clear()  # an amplitude sent while inactive does not count
        self._start = None

    def update(self, t: float, dt: float, state: JointState, command: ServoCommand) -> None:
        fresh = self._amplitude_door.take()
        if fresh is not None:
            self._amplitude = float(fresh[0])
        if self._start is None:
            self._start = t
        offset = self._amplitude * math.sin(2.0 * math.pi * self._frequency * (t - self._start))
        np.add(self._center, offset, out=self._target)
        command.position[self._index] = self._target
        command.written[self._index] = True
