"""follow: leader–follower teleoperation — this robot's joints follow another hild robot's measured joints.

The leader is any robot publishing ``hild/<leader>/joint_states`` on the Zenoh network (a hild robot in teach mode,
moved by hand; or one running a trajectory). Each leader sample is mapped per follower joint (a leader joint's
name, ``scale``, ``offset``: arms of different kinds), clamped to the follower's limits and handed to the servo's
jerk-limited path as a target with its velocity, so what the servo promises holds here: the command never steps,
a far first sample is approached within the velocity, acceleration and jerk limits from where the follower is, and
silence (``command_timeout``) brakes to a stop and holds.

Two things the servo's own clients do not need:

- **A dead-man**: with ``deadman.required`` the follower moves only while ``ctrl/<follow>/enable`` says
  ``{"enable": true}`` and was said again within ``deadman.timeout`` (cycle clock). A release — or its silence —
  stops writing the joints at once, so the supervisor holds them in that very cycle (a dead-man is a stop, not a
  glide); the next enable starts again from where the arm is. The provenance says so: ``source`` is LEADER while
  engaged, HOLD while released.
- **Degradation**: under delay and loss the stream arrives late and in gaps. The gap is the larger of the time
  between two samples taken and the samples missing by ``seq``; above ``degrade_after`` stream periods the velocity
  limit falls linearly with it, down to ``min_speed`` at ``command_timeout``, and ruckig brakes to it jerk-limited.
  It recovers as the stream does (at once to slow down, a fifth of the way per sample to speed up again).

Leader samples that cannot be followed (a joint missing, a non-finite value, a stale ``fresh`` flag) are never
followed: they are counted and reported as one warning per episode (and once when valid samples return), so a
wrong leader does not flood the event log at its stream rate.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from hild.arrays import JointState, ServoCommand
from hild.config.params import Field, Params, dynamic, model_validator
from hild.controller import ControllerContext, and_more, unknown_keys
from hild.controllers.servo import Phase, ServoController, ServoParams, ServoTarget, stopping_distance
from hild.modes import Source
from hild.motion.chunks import clip_target
from hild.motion.online import (
    ControlInterface,
    InputParameter,
    OutputParameter,
    Result,
    Ruckig,
    RuckigError,
    Synchronization,
)

# The velocity scale changes ruckig's limits only when it moved by this much: no new limits on every cycle.
SPEED_STEP = 0.02
# Per sample, how far a shrinking gap estimate moves toward the new gap (a growing one is taken at once).
GAP_RECOVERY = 0.2
# A sample behind the last one followed is late (reordered on the network) and dropped, unless it is a leader that
# restarted: its seq this far below, or its stamp (the leader's cycle clock, which restarts at 0) this much older.
SEQ_RESTART = 1000
STAMP_RESTART = 1.0  # s
# Each leader sample is aimed at where the leader will be a *lead* after it arrived (its position extrapolated at its
# velocity), with its velocity, and ruckig is asked to take exactly the lead to get there (``minimum_duration``, the
# chunk player's technique): the plan follows the leader's path instead of racing to each sample. Racing (a
# time-optimal plan to each sample's position and velocity) is a feedback loop of unbounded gain behind a jerk limit:
# it overshoots, brakes, overshoots — 0.16 rad on a 0.8 rad/s wave. A lead shorter than the time the jerk limit
# needs to build up the acceleration limit is that loop again: in lockstep (tests/controllers/test_follow.py's wave,
# a/j = 0.1 s, the extrapolation then a cycle short) a lead of 0.4·a/j oscillates (50 ms lag, 0.19 rad errors);
# 0.8·a/j lagged 2 ms (errors 1.7 mrad), 1.5·a/j 2.6 ms, 2.5·a/j 3.6 ms, at a 500 Hz stream and a 100 Hz one alike.
# On the bench's recorded streams (hard moves, at the follower's acceleration limits) 0.8–1.2·a/j did best.
LEAD_PER_JERK_TIME = 0.8  # the lead, in units of the slowest joint's acceleration / jerk
MIN_LEAD_CYCLES = 4
LEAD_SLACK = 1.001  # a joint's plan this much longer than the lead is not one in the lead (see _step)
MAX_REAIMS = 3  # per joint and sample: aims further along the leader's path when the lead cannot be made
MAX_LEAD_FACTOR = 4.0  # … at most this many leads ahead


class JointMapping(Params):
    joint: str | None = Field(default=None, description="The leader's joint; default: the follower joint's name.")
    scale: float = Field(default=1.0, description="Follower position = scale · leader position + offset.")
    offset: float = Field(default=0.0, description="rad (or m): added after scaling.")

    @model_validator(mode="after")
    def _finite(self) -> JointMapping:
        if not (math.isfinite(self.scale) and math.isfinite(self.offset)):
            raise ValueError("scale and offset must be finite")
        return self


class Deadman(Params):
    required: bool = Field(
        default=True, description="Follow only while ctrl/<follow>/enable says true, refreshed within timeout."
    )
    timeout: float = dynamic(default=0.5, gt=0.0, description="s: an enable not repeated within this releases.")


class FollowParams(ServoParams):
    leader: str = Field(min_length=1, description="The leader robot's name: follows hild/<leader>/joint_states.")
    joint_map: dict[str, JointMapping] = Field(
        default_factory=dict, description="Per follower joint: the leader joint, scale and offset (default 1:1)."
    )
    rate: float = Field(default=100.0, gt=0.0, description="Hz: the leader's expected joint_states rate.")
    deadman: Deadman = Field(default_factory=Deadman)
    degrade_after: float = dynamic(
        default=4.0, ge=1.0, description="Stream periods of gap above which the follower slows down."
    )
    min_speed: float = dynamic(
        default=0.2, gt=0.0, le=1.0, description="Fraction of the velocity limits at a gap of command_timeout."
    )
    anticipate: bool = Field(
        default=True,
        description="Aim at the leader's position extrapolated at its velocity a lead ahead (0.8 · the slowest "
        "joint's acceleration/jerk, at least 4 cycles), with its velocity, reached in exactly the lead: lag about a "
        "control period. false: aim at the leader's position at rest, time-optimally (lags a few stream periods).",
    )

    @model_validator(mode="after")
    def _mapped(self) -> FollowParams:
        extra = sorted(set(self.joint_map) - set(self.joints))
        if extra:
            raise ValueError(f"joint_map names joints that are not in joints: {extra}")
        if "/" in self.leader or "*" in self.leader or "$" in self.leader:
            raise ValueError(f"leader must be a robot name, not a key expression: {self.leader!r}")
        return self


class FollowController(ServoController):
    Params = FollowParams
    KIND = "follow"
    SOURCE = Source.LEADER

    def __init__(self, context: ControllerContext, params: FollowParams) -> None:
        super().__init__(context, params)
        mapping = [params.joint_map.get(j, JointMapping()) for j in params.joints]
        self._leader_joints = [m.joint or j for m, j in zip(mapping, params.joints, strict=True)]
        self._scale = [m.scale for m in mapping]
        self._offset = [m.offset for m in mapping]
        period = 1.0 / context.update_rate
        jerk_time = max(a / j for a, j in zip(self._amax, self._jmax, strict=True))
        self.lead = max(LEAD_PER_JERK_TIME * jerk_time, MIN_LEAD_CYCLES * period)  # s: see LEAD_PER_JERK_TIME
        # The extrapolation: a lead past the sample. The cycle that takes it plans from the command of the cycle
        # before and writes one cycle on, so the plan ends a lead after the cycle that took the sample — a cycle or
        # less after it arrived (extrapolating a cycle less lagged a cycle: 2 ms, in lockstep and on the bench's
        # recorded streams).
        self._ahead = self.lead
        # Per joint, a ruckig of its own: ruckig honours a minimum duration only for joints timed together, and
        # timing them together sends all the joints the long way round whenever one of them cannot make it in the
        # lead (a target velocity blocks some durations: a synchronized plan of 0.3 s where each joint alone needs
        # 0.08 s, measured on the bench's recorded stream — joints moving backwards).
        self._joint_inp = [InputParameter(1) for _ in params.joints]
        self._joint_out = [OutputParameter(1) for _ in params.joints]
        self._joint_otg: list[Ruckig] = []
        self._leading = False  # the joints follow their per-joint plans (TRACK of a moving leader)
        self._sample_p: list[float] = []  # the last sample's target and velocity (cycle side)
        self._sample_v: list[float] = []
        self.reaims = 0  # joint plans aimed further along: the lead could not be made (tests, bench)
        # Doors beside the servo's target: the enable (1 = on) and the sample's seq (written before its target).
        self._enable_door = context.mailboxes.latest_numbers("enable", 1)
        self._seq_door = context.mailboxes.latest_numbers("leader_seq", 1)
        # API half: validating leader samples (a Zenoh thread, or the cycle's take_inputs in one process).
        self._api_lock = threading.Lock()
        self._lookup: tuple[tuple[str, ...], list[int]] | None = None  # the leader's names → our mapping
        self._last_seq: int | None = None
        self._last_stamp = -math.inf
        self.invalid_samples = 0  # leader samples not followed (API half)
        self.stale_samples = 0  # samples older than one already followed (reordered by the network)
        self._invalid_run = 0  # invalid samples in the current episode
        # Cycle half.
        self._enabled = not params.deadman.required
        self._enabled_at = -math.inf
        self._engaged = False
        self._speed = 1.0
        self._gap = 0.0  # s: the stream's gap estimate
        self._arrived = -math.inf  # cycle time the last target was taken
        self._seq: int | None = None
        self.released_at = -math.inf  # cycle time of the last release (tests, bench)

    # ---- API side -----------------------------------------------------------------------------------------
    def inputs(self) -> Mapping[str, Callable[[Any], None]]:
        return {"enable": self.accept_enable}

    def subscriptions(self) -> Mapping[str, Callable[[Any], None]]:
        return {f"hild/{self.params.leader}/joint_states": self.accept_leader}

    def accept_enable(self, payload: Any) -> None:
        """``{"enable": true|false}``: the dead-man; repeat it within ``deadman.timeout`` to keep following."""
        if not self.active:
            raise ValueError(f"controller {self.name} is not active")
        if not isinstance(payload, dict):
            raise ValueError('expected an object {"enable": true|false}')
        unknown, more = unknown_keys(payload, ("enable",))
        if unknown:
            raise ValueError(f"unknown keys {unknown}{and_more(more)}; expected enable")
        enable = payload.get("enable")
        if not isinstance(enable, bool):
            raise ValueError(f"enable must be true or false, not {enable!r}")
        self._enable_door.put((1.0 if enable else 0.0,))

    def accept_leader(self, message: Any) -> None:
        """A leader joint_states message: map, clamp and hand over as a servo target; count what cannot be
        followed. Never raises for the leader's content: the leader is not a client we can answer."""
        if not self.active:
            return  # the leader streams whether or not we follow: nothing to say
        with self._api_lock:  # one sample at a time: the seq order and the episode count are ours
            try:
                seq, positions, velocities = self._leader_sample(message)
            except ValueError as exc:
                self._invalid(str(exc))
                return
            stamp = message.get("stamp")
            stamp = float(stamp) if _finite(stamp) else math.inf
            if self._last_seq is not None and self._late(seq, stamp):
                self.stale_samples += 1
                return
            target = self._aim(positions, velocities)
            self._last_seq, self._last_stamp = seq, stamp
            if self._invalid_run:
                self.context.emit_event(
                    "info", f"leader {self.params.leader}: valid samples again after {self._invalid_run} invalid"
                )
                self._invalid_run = 0
            self._seq_door.put((float(seq),))
            self._slot.put(target)

    def _aim(self, positions: list[float], velocities: list[float]) -> ServoTarget:
        """Where the leader will be a lead after the sample, at its velocity: the plan reaches it in the lead (see
        _track). Clamped as the servo clamps.

        Not with the leader's acceleration: differenced from its velocities (2 ms apart, or over 20 ms) it is
        noisy enough to make things worse — 10–27 mrad RMS against 1–3 on the bench's recorded stream."""
        t = self._ahead
        p = [q + v * t for q, v in zip(positions, velocities, strict=True)]
        v = list(velocities)
        clamped = self._clamp(p, v)
        return ServoTarget(p, v, any(x != 0.0 for x in v), clamped)

    def _late(self, seq: int, stamp: float) -> bool:
        assert self._last_seq is not None
        restarted = seq <= self._last_seq - SEQ_RESTART or stamp < self._last_stamp - STAMP_RESTART
        return seq <= self._last_seq and not restarted

    def _invalid(self, reason: str) -> None:
        self.invalid_samples += 1
        self._invalid_run += 1
        if self._invalid_run == 1:
            self.context.emit_event(
                "warning", f"leader {self.params.leader}: sample not followed ({reason}); counting until valid again"
            )

    def _leader_sample(self, message: Any) -> tuple[int, list[float], list[float]]:
        """The message's seq, and its positions and velocities mapped to the follower's joints; ValueError if it
        cannot be followed."""
        if not isinstance(message, dict):
            raise ValueError("not a joint_states object")
        names, position = message.get("name"), message.get("position")
        seq = message.get("seq")
        if not isinstance(seq, int) or isinstance(seq, bool):
            raise ValueError("no integer seq")
        if not isinstance(names, list) or not isinstance(position, list) or len(names) != len(position):
            raise ValueError("name and position must be lists of one length")
        index = self._index_in(names)
        velocity = message.get("velocity") if self._follow_params().anticipate else None
        if not (isinstance(velocity, list) and len(velocity) == len(names)):
            velocity = None
        fresh = message.get("fresh")
        positions, velocities = [], []
        for k, i in enumerate(index):
            p = position[i]
            v = velocity[i] if velocity is not None else 0.0
            if not _finite(p) or not _finite(v):
                raise ValueError(f"{names[i]}: non-finite or not a number")
            if isinstance(fresh, list) and len(fresh) == len(names) and fresh[i] == 0:
                raise ValueError(f"{names[i]}: reading not fresh")
            positions.append(self._scale[k] * p + self._offset[k])
            velocities.append(self._scale[k] * v)
        return seq, positions, velocities

    def _index_in(self, names: list[Any]) -> list[int]:
        key = tuple(names)
        if self._lookup is None or self._lookup[0] != key:  # once per leader layout, not per sample
            where = {n: i for i, n in enumerate(names) if isinstance(n, str)}
            missing = [j for j in self._leader_joints if j not in where]
            if missing:
                raise ValueError(f"leader joints missing: {missing}")
            self._lookup = (key, [where[j] for j in self._leader_joints])
        return self._lookup[1]

    # ---- cycle side ---------------------------------------------------------------------------------------
    def on_configure(self) -> None:
        super().on_configure()
        self._joint_otg = [Ruckig(1, self._period) for _ in self._joint_inp]
        for joint in self._joint_inp:
            joint.synchronization = Synchronization.Time  # one joint: with None, ruckig pads the end instead

    def on_cleanup(self) -> None:
        super().on_cleanup()
        self._joint_otg = []

    def _hold_at(self, position: list[float]) -> None:
        super()._hold_at(position)
        self._leading = False

    def on_activate(self, state: JointState, last_command: ServoCommand) -> None:
        super().on_activate(state, last_command)
        self._enable_door.clear()
        self._seq_door.clear()
        self._enabled = not self._deadman_params().required
        self._enabled_at = -math.inf
        self._engaged = False
        self.source = Source.HOLD  # until the dead-man engages it (at the first cycle, when none is required)
        self._set_speed(1.0)

    def on_params(self, old: Params) -> None:
        super().on_params(old)  # sets the unscaled limits again: scale them as the stream is
        speed, self._speed = self._speed, 1.0
        self._set_speed(speed)

    def _deadman_params(self) -> Deadman:
        assert isinstance(self.params, FollowParams)
        return self.params.deadman

    def _dead_man_holds(self, t: float) -> bool:
        """Whether the dead-man lets the follower move this cycle (taking a new enable first)."""
        deadman = self._deadman_params()
        fresh = self._enable_door.take()
        if fresh is not None:
            self._enabled = fresh.item(0) != 0.0
            self._enabled_at = t
        if not deadman.required:
            return self._enabled
        return self._enabled and t - self._enabled_at <= deadman.timeout

    def update(self, t: float, dt: float, state: JointState, command: ServoCommand) -> None:
        if not self._dead_man_holds(t):
            if self._engaged:
                self._engaged = False
                self.source = Source.HOLD  # provenance: its joints are held, nobody moves them
                self.released_at = t
                self.context.emit_event("info", "dead-man released: the joints hold")
            self._slot.clear()  # a target from before the release is never followed after it
            return  # nothing written: the supervisor holds the joints from this cycle on
        if not self._engaged:
            self._engage(state, command)
        if self.phase in (Phase.TRACK, Phase.CRUISE):
            self._slow_down_for(max(self._gap, t - self._arrived))
        super().update(t, dt, state, command)

    def _engage(self, state: JointState, command: ServoCommand) -> None:
        """Start from where the arm is, at rest: the first sample is approached jerk-limited, never jumped to."""
        q = state.position[self._index]
        self._hold_at(np.where(np.isfinite(q), q, command.position[self._index]).tolist())
        self._engaged = True  # a target waiting now came after the enable: released, the slot is cleared
        self.source = Source.LEADER
        self.context.emit_event("info", f"following {self._follow_params().leader}")
        self._seq = None
        self._gap = 0.0
        self._set_speed(1.0)

    def _track(self, t: float) -> None:
        """A new leader sample: update the stream's gap (arrival interval, seq gaps), then plan as the servo does,
        at the speed the stream's health allows."""
        self._seq_door.take()  # written before the target: its seq, or a newer sample's (then the next brings it)
        seq = int(self._seq_door.values.item(0))
        period = 1.0 / self._follow_params().rate
        if self._seq is not None and self.phase != Phase.HOLD:
            missed = max(seq - self._seq, 1) * period
            gap = max(t - self._arrived, missed)
            self._gap = gap if gap > self._gap else self._gap + GAP_RECOVERY * (gap - self._gap)
        else:
            self._gap = 0.0
        self._seq, self._arrived = seq, t
        super()._track(t)
        inp = self._inp
        inp.synchronization = self._sync = Synchronization.No  # each joint chases its own leader joint
        self._slow_down_for(self._gap, force=True)
        self._leading = False
        if self._follow_params().anticipate and self._slot.moving():
            self._plan_in_the_lead()

    def _plan_in_the_lead(self) -> None:
        """Each joint: reach the extrapolated sample in the lead, from where it is, on a ruckig of its own (see
        __init__); a joint that cannot aims further along the leader's path (see _step)."""
        inp = self._inp
        self._sample_p, self._sample_v = inp.target_position, inp.target_velocity  # the leader, at the lead
        cp, cv, ca = inp.current_position, inp.current_velocity, inp.current_acceleration
        vmax, amax, jmax = inp.max_velocity, inp.max_acceleration, inp.max_jerk
        for i, joint in enumerate(self._joint_inp):
            joint.current_position, joint.current_velocity, joint.current_acceleration = [cp[i]], [cv[i]], [ca[i]]
            joint.max_velocity, joint.max_acceleration, joint.max_jerk = [vmax[i]], [amax[i]], [jmax[i]]
            self._aim_joint(i, self.lead)
        self._leading = True

    def _aim_joint(self, i: int, horizon: float) -> None:
        """Joint ``i``'s target: the leader ``horizon`` after the plan starts (extrapolated on from the lead at
        the sample's velocity), within the limits, reached in ``horizon``."""
        joint, later, v = self._joint_inp[i], horizon - self.lead, self._sample_v[i]
        tp, tv, ta = [self._sample_p[i] + v * later], [v], [0.0]
        k = slice(i, i + 1)
        clip_target(tp, tv, ta, self._lo[k], self._hi[k], joint.max_velocity, self._amax[k], self._jmax[k])
        joint.target_position, joint.target_velocity, joint.target_acceleration = tp, tv, ta
        joint.control_interface = ControlInterface.Position
        joint.minimum_duration = horizon

    def _step(self, dt: float) -> None:
        if not (self._leading and self.phase is Phase.TRACK):
            self._leading = False
            super()._step(dt)
            return
        inp, vmax = self._inp, self._inp.max_velocity
        p, v, a = list(self._zeros), list(self._zeros), list(self._zeros)
        finished = True
        for i, (joint, out, otg) in enumerate(zip(self._joint_inp, self._joint_out, self._joint_otg, strict=True)):
            if joint.max_velocity[0] != vmax[i]:  # the stream degraded (or recovered): re-planned from here
                joint.max_velocity = [vmax[i]]
                tp, tv, ta = joint.target_position, joint.target_velocity, joint.target_acceleration
                k = slice(i, i + 1)
                clip_target(tp, tv, ta, self._lo[k], self._hi[k], [vmax[i]], self._amax[k], self._jmax[k])
                joint.target_position, joint.target_velocity, joint.target_acceleration = tp, tv, ta
            if joint.control_interface == ControlInterface.Velocity:
                self._brake_joint_before_soft_limits(i, joint)
            if dt > 0.0 and dt != otg.delta_time:
                otg.delta_time = dt
            try:
                result = otg.update(joint, out)
                tries = 0
                while (
                    out.new_calculation
                    and joint.minimum_duration is not None  # None: cruising on its own
                    and out.trajectory.duration > joint.minimum_duration * LEAD_SLACK
                ):
                    # Not in the lead: the joint is too far from the leader's path to join it that soon — often
                    # ahead of it, where it would have to slow down and speed up again, more than the jerk limit
                    # allows in the lead (then ruckig's plan is a long detour that stays ahead). Aim further along
                    # the leader's path instead, at the horizon ruckig said it needs.
                    tries += 1
                    self.reaims += 1
                    if tries > MAX_REAIMS:
                        break
                    self._aim_joint(i, min(out.trajectory.duration, MAX_LEAD_FACTOR * self.lead))
                    result = otg.update(joint, out)
            except RuckigError as exc:
                self._fall_back(str(exc).strip().removeprefix("[ruckig] "), dt)
                return
            if result is not Result.Working and result is not Result.Finished:
                self._fall_back(result.name, dt)
                return
            if result is Result.Finished and joint.control_interface == ControlInterface.Position:
                # There, a lead after the sample (the next one is late; a joint at rest is there all along):
                # cruise on at the leader's velocity, as the servo does. Left to plan to its target, a joint
                # that passed it with a velocity would be planned back to it.
                joint.control_interface = ControlInterface.Velocity
                joint.minimum_duration = None
            finished = finished and result is Result.Finished
            out.pass_to_input(joint)
            p[i], v[i], a[i] = out.new_position[0], out.new_velocity[0], out.new_acceleration[0]
        if not math.isfinite(sum(p) + sum(v)):
            self._fall_back("non-finite output", dt)
            return
        inp.current_position, inp.current_velocity, inp.current_acceleration = p, v, a
        self._p, self._v = p, v
        if finished:  # every joint cruises: the servo's cruise from here (dead reckoning until the next sample)
            self._leading = False
            self._cruise_velocity[:] = [j.target_velocity[0] for j in self._joint_inp]
            self._cruise()

    def _brake_joint_before_soft_limits(self, i: int, joint: InputParameter) -> None:
        """A joint cruising on its own: brake if one more cycle of travel would leave too little room to stop (as
        the servo's cruise does for all of them)."""
        v = joint.target_velocity[0]
        if v == 0.0:
            return
        p = joint.current_position[0]
        room = (self._hi[i] - p if v > 0.0 else p - self._lo[i]) - abs(v) * self._lookahead
        if stopping_distance(abs(v), self._amax[i], self._jmax[i]) >= room:
            joint.target_velocity = [0.0]

    def _fall_back(self, reason: str, dt: float) -> None:
        """A joint's plan failed: stop all of them as the servo does (from the state they are in)."""
        self._leading = False
        self._planning_failed(reason, dt)

    def _follow_params(self) -> FollowParams:
        assert isinstance(self.params, FollowParams)
        return self.params

    def speed_for(self, gap: float) -> float:
        """The velocity scale for a stream gap of ``gap`` s: 1 up to ``degrade_after`` periods, then falling
        linearly to ``min_speed`` at ``command_timeout``."""
        params = self._follow_params()
        start = params.degrade_after / params.rate
        end = max(params.command_timeout, start * 1.0001)
        if gap <= start:
            return 1.0
        return max(params.min_speed, 1.0 - (1.0 - params.min_speed) * (gap - start) / (end - start))

    def _slow_down_for(self, gap: float, force: bool = False) -> None:
        speed = self.speed_for(gap)
        if force or abs(speed - self._speed) >= SPEED_STEP or (speed == 1.0) != (self._speed == 1.0):
            self._set_speed(speed)

    def _set_speed(self, speed: float) -> None:
        """New velocity limits for ruckig (it brakes to a lower one jerk-limited) and targets within them."""
        changed = speed != self._speed
        self._speed = speed
        vmax = [v * speed for v in self._vmax]
        if changed:
            self._inp.max_velocity = vmax
        targets = self._inp.target_velocity
        if any(abs(v) > m for v, m in zip(targets, vmax, strict=True)):
            self._inp.target_velocity = [min(max(v, -m), m) for v, m in zip(targets, vmax, strict=True)]
        cruise = self._cruise_velocity
        for i, m in enumerate(vmax):
            cruise[i] = min(max(cruise[i], -m), m)

    @property
    def speed(self) -> float:
        """The velocity scale the stream's health allows now (1: full speed)."""
        return self._speed

    @property
    def engaged(self) -> bool:
        return self._engaged


def _finite(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
