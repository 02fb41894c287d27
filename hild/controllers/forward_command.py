"""forward_command: forwards streamed values to one interface kind of a list of joints.

Unlike ros2_controllers' ForwardCommandController it is safe to stop talking to: after ``command_timeout`` of
silence (cycle clock, so a paused simulation does not time out) its joints return to hold. Until the first
command after activation it writes nothing, so the joints stay held where they are (bumpless start).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any, Literal

import numpy as np

from hild.arrays import JointState, ServoCommand
from hild.config.params import Field, Params, dynamic
from hild.controller import Controller, ControllerContext
from hild.crossing.mailboxes import LatestNumbers
from hild.interfaces import interface_name


class ForwardCommandParams(Params):
    joints: list[str] = Field(min_length=1, description="Joints commanded, in the order of the values.")
    interface: Literal["position", "velocity", "effort"] = "position"
    command_timeout: float = dynamic(
        default=0.5, gt=0.0, description="Seconds of silence after which the joints return to hold."
    )


class ForwardCommandController(Controller):
    Params = ForwardCommandParams

    def __init__(self, context: ControllerContext, params: ForwardCommandParams) -> None:
        super().__init__(context, params)
        if len(set(params.joints)) != len(params.joints):
            raise ValueError(f"{context.name}: joints listed twice in {params.joints}")
        self._index = context.index_of(params.joints)
        self._values = np.zeros(len(params.joints))
        self._slot: LatestNumbers = context.mailboxes.latest_numbers("commands", len(params.joints))
        self._last_rx = -math.inf
        self._streaming = False
        lim = context.limits
        if params.interface == "position":
            self._lo, self._hi = lim.lower[self._index], lim.upper[self._index]
        elif params.interface == "velocity":
            self._lo, self._hi = -lim.velocity[self._index], lim.velocity[self._index]
        else:
            self._lo, self._hi = -lim.effort[self._index], lim.effort[self._index]

    @classmethod
    def claims_for(cls, params: Params) -> list[str]:
        assert isinstance(params, ForwardCommandParams)
        return [interface_name(j, params.interface) for j in params.joints]

    # ---- API side -----------------------------------------------------------------------------------------
    def inputs(self) -> Mapping[str, Callable[[Any], None]]:
        return {"commands": self.accept}

    def accept(self, payload: Any) -> None:
        """Validate ``{"values": [...]}`` (controller joint order) and hand it to the cycle."""
        if not self.active:
            raise ValueError(f"controller {self.name} is not active")
        if not isinstance(payload, dict) or set(payload) != {"values"}:
            raise ValueError('expected an object {"values": [...]}')
        values = payload["values"]
        n = len(self._index)
        if not isinstance(values, list) or len(values) != n:
            found = f"{len(values)} values" if isinstance(values, list) else type(values).__name__
            raise ValueError(f"expected {n} values for {self.params.joints}; found {found}")
        if not all(isinstance(v, int | float) and not isinstance(v, bool) for v in values):
            raise ValueError("values must be numbers")
        arr = np.array(values, dtype=float)
        if not np.isfinite(arr).all():
            raise ValueError("values must be finite (no NaN or inf)")
        outside = np.flatnonzero((arr < self._lo) | (arr > self._hi))
        if outside.size:
            i = int(outside[0])
            raise ValueError(
                f"{self.params.interface} {arr[i]:g} for {self.params.joints[i]} is outside "
                f"[{self._lo[i]:g}, {self._hi[i]:g}]"
            )
        self._slot.put(arr)

    # ---- cycle side ---------------------------------------------------------------------------------------
    def on_activate(self, state: JointState, last_command: ServoCommand) -> None:
        self._slot.clear()
        self._last_rx = -math.inf
        self._streaming = False

    def update(self, t: float, dt: float, state: JointState, command: ServoCommand) -> None:
        fresh = self._slot.take()
        if fresh is not None:
            self._values[:] = fresh
            self._last_rx = t
            self._streaming = True
        if t - self._last_rx > self.params.command_timeout:
            if self._streaming:
                self._streaming = False
                self.context.emit_event(
                    "warning", f"no command for {self.params.command_timeout:g} s: joints return to hold"
                )
            return
        getattr(command, self.params.interface)[self._index] = self._values
        command.written[self._index] = True
