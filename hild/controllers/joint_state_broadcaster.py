"""joint_state_broadcaster: publishes every joint's measured state at ``publish_rate``.

It claims nothing, so it runs alongside any controller and survives an e-stop. Samples go into a preallocated
ring; the API publishes them on ``hild/<robot>/joint_states`` from the asyncio side. ``fresh`` (1 or 0 per joint)
says whether the sample is a new accepted reading; 0 means the drive's reading was missing or rejected as
implausible and the values are the last accepted ones (hild.cycle.plausibility), never the bad reading.
``tau_ext`` is the contact observer's external torque estimate per joint (docs/safety.md, "Contact"): NaN (JSON
null) when ``safety.contact`` is off or the observer cannot run, and for mimic joints.

Mimic joints (the config's ``mimic_joints``) follow the robot's joints in each sample, as ros2_control reports them
(hardware_interface's mimic joints, Jazzy): position = multiplier·q + offset, velocity = multiplier·q̇ of the joint
each follows, and ``fresh`` that joint's. ros2_control computes no effort for a mimic joint and
joint_state_broadcaster publishes NaN for an interface a joint does not have, so effort is NaN (JSON: null).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from hild.arrays import JointState, ServoCommand
from hild.config.params import Params, dynamic
from hild.controller import Controller, ControllerContext
from hild.crossing.ring import SampleRing
from hild.interfaces import interface_name

PUBLISHED_FIELDS = ("position", "velocity", "effort", "fresh", "tau_ext")
STATE_FIELDS = ("position", "velocity", "effort")  # the published fields that are state interfaces


class BroadcasterParams(Params):
    publish_rate: float = dynamic(default=100.0, gt=0.0, description="Hz; at most the update rate.")


class JointStateBroadcaster(Controller):
    Params = BroadcasterParams

    def __init__(self, context: ControllerContext, params: BroadcasterParams) -> None:
        super().__init__(context, params)
        self._n = n = len(context.joints)
        self._mimics = context.mimic_joints
        self.ring = context.mailboxes.ring("joint_states", n + len(self._mimics), PUBLISHED_FIELDS)
        self.ring.names = [*context.joints, *self._mimics.names]  # type: ignore[attr-defined]  # what the API names
        self._interval = 1.0 / min(params.publish_rate, context.update_rate)
        self._next = 0.0
        self._tau_ext = context.external_torque  # the cycle's live array, or None: then NaN

    @classmethod
    def joints_for(cls, params: Params) -> list[str]:
        return []

    def state_interfaces(self) -> list[str]:
        """Position, velocity and effort of every joint of the robot: what it publishes."""
        return [interface_name(j, f) for j in self.context.joints for f in STATE_FIELDS]

    def on_activate(self, state: JointState, last_command: ServoCommand) -> None:
        self._next = -np.inf  # publish on the first cycle

    def on_params(self, old: Params) -> None:
        assert isinstance(self.params, BroadcasterParams)
        self._interval = 1.0 / min(self.params.publish_rate, self.context.update_rate)  # from the next sample on

    def update(self, t: float, dt: float, state: JointState, command: ServoCommand) -> None:
        # Keep the phase (exact rate on a jittery wall clock); resync after a gap instead of bursting.
        # The small tolerance absorbs floating-point error in an accumulated sim clock.
        if t + 1e-9 < self._next:
            return
        self._next += self._interval
        if self._next <= t:
            self._next = t + self._interval
        ring = self.ring
        i = ring.slot()
        if self._mimics:
            self._with_mimics(i, state)
        else:
            ring.data["position"][i] = state.position
            ring.data["velocity"][i] = state.velocity
            ring.data["effort"][i] = state.effort
            ring.data["fresh"][i] = state.fresh
            if self._tau_ext is not None:
                ring.data["tau_ext"][i] = self._tau_ext
            else:
                ring.data["tau_ext"][i].fill(np.nan)
        ring.commit(t)
        self.context.notify()

    def _with_mimics(self, i: int, state: JointState) -> None:
        """Slot ``i``: the robot's joints, then each mimic joint from the joint it follows."""
        n, mimics, data = self._n, self._mimics, self.ring.data
        position, velocity, effort, fresh = (
            data["position"][i],
            data["velocity"][i],
            data["effort"][i],
            data["fresh"][i],
        )
        position[:n] = state.position
        velocity[:n] = state.velocity
        effort[:n] = state.effort
        fresh[:n] = state.fresh
        mimics.positions(state.position, position[n:])
        mimics.velocities(state.velocity, velocity[n:])
        effort[n:] = np.nan
        np.take(fresh[:n], mimics.leader, out=fresh[n:])
        tau_ext = data["tau_ext"][i]
        if self._tau_ext is not None:
            tau_ext[:n] = self._tau_ext
        else:
            tau_ext[:n] = np.nan
        tau_ext[n:] = np.nan

    def outputs(self) -> Mapping[str, SampleRing]:
        return {"joint_states": self.ring}
