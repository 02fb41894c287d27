"""servo: follows a stream of targets (teleop, AI policies) with ruckig online tracking.

Streamed targets arrive at the client's rate, with jitter, gaps and noise. Forwarding them would hand that
roughness to the arm (ros2_controllers #1594, #1579); here ruckig plans from the current desired state
``(p, v, a)`` to the latest target every time one arrives and steps that plan every cycle, so the command stays
within the joints' velocity, acceleration and jerk limits whatever the stream does. Silence is safe: after
``command_timeout`` (cycle clock) the joints brake, jerk-limited, to a stop and hold there.

Phases: ``HOLD`` (at rest: before the first target and after a stop) → ``TRACK`` (ruckig position control
toward the latest target; the joints planned together in time, or each on its own while the stream is fast, see
``_track``) → ``CRUISE`` (a target with velocities was reached: keep its velocity until the next target, braking
per joint in time for the soft limits) → ``STOP`` (ruckig velocity control to rest on timeout or planning error)
→ ``HOLD``. The API side validates and clamps targets and hands each over as one fixed-size record of numbers
(:class:`TargetRecord`); the cycle only copies it into ruckig and steps it, and spells out what was clamped only
when it reports it. The ruckig bindings return fresh lists, so a cycle costs a few small
lists; nothing else.
"""

from __future__ import annotations

import enum
import math
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal, NamedTuple

import numpy as np

from hild.arrays import JointState, ServoCommand
from hild.config.params import Field, Params, dynamic, model_validator
from hild.controller import Controller, ControllerContext, and_more, unknown_keys
from hild.controllers.motion_common import PlansMotion, first_taken_over
from hild.crossing.mailboxes import LatestNumbers
from hild.modes import Source
from hild.motion.chunks import CHUNK_LEAD, ChunkPlayer, ChunkRecord, Verdict, clip_target, parse_chunk
from hild.motion.online import (
    ControlInterface,
    InputParameter,
    OutputParameter,
    Result,
    Ruckig,
    RuckigError,
    Synchronization,
)

# Plan a hair inside the limits, so rounding in ruckig's profiles never trips the supervisor's velocity, slew
# or soft position limits (which compare with no tolerance and would report a limit that is not really hit).
VELOCITY_MARGIN = 1e-6  # relative
POSITION_MARGIN = 1e-6  # rad
# A new clamping event only after this long (cycle clock) without a clamped target: one event per episode.
CLAMP_EVENT_QUIET = 1.0  # s
# Cycles of travel allowed for when deciding to brake before a soft limit (one cycle may run late).
BRAKE_LOOKAHEAD_CYCLES = 2.0
# A target within this many cycles of the last one is part of a fast stream: its plan is replaced before it
# ends, so each joint plans on its own (see ``_track``). A jittery 1 kHz stream at a 1 kHz cycle has gaps of 2.
FAST_STREAM_CYCLES = 2.0
# Toward a first chunk the joints race (each on its own, time-optimally) until the next chunk starts or until the plan
# reaches the target within this many leads (CHUNK_LEAD); 1 lead: a lone chunk was chased for 0.8 s, overshooting.
RACE_UNTIL = 2.0

ALLOWED_INTERFACES = ({"position"}, {"position", "velocity"})


class ServoParams(Params):
    joints: list[str] = Field(min_length=1, description="Joints commanded, in the order of the target values.")
    command_interfaces: list[Literal["position", "velocity"]] = Field(
        default_factory=lambda: ["position", "velocity"],
        description="[position, velocity] (planned velocity as feed-forward) or [position].",
    )
    command_timeout: float = dynamic(
        default=0.5, gt=0.0, description="Seconds without a target after which the joints brake to a stop and hold."
    )
    velocity_scale: float = dynamic(
        default=1.0,
        gt=0.0,
        le=1.0,
        description="Fraction of the joints' velocity limits. Lowered while moving, the joints brake to it smoothly.",
    )
    acceleration_scale: float = dynamic(
        default=1.0, gt=0.0, le=1.0, description="Fraction of the acceleration limits; jerk scales with it."
    )
    chunk_slowdown: float = dynamic(
        default=0.3,
        ge=0.0,
        le=10.0,
        description="Chunk time (s) before a policy chunk's end from which, with no successor, playback slows "
        "to reach its last point at rest (2× this long); 0: no slow-down.",
    )
    chunk_ensemble: float = dynamic(
        default=0.3,
        ge=0.0,
        le=10.0,
        description="Time constant (s) of temporal ensembling: the target averages the running policy chunk with "
        "the older ones still overlapping it, each weighted exp(−age/this), age its stamp's before the running "
        "chunk's; 0: the running chunk alone.",
    )

    @model_validator(mode="after")
    def _consistent(self) -> ServoParams:
        if len(set(self.joints)) != len(self.joints):
            raise ValueError(f"joints listed twice in {self.joints}")
        kinds = set(self.command_interfaces)
        if len(kinds) != len(self.command_interfaces) or kinds not in ALLOWED_INTERFACES:
            raise ValueError(f"command_interfaces must be [position, velocity] or [position], not {kinds}")
        return self


class Phase(enum.IntEnum):
    HOLD = 0
    TRACK = 1
    CRUISE = 2
    STOP = 3


# Enum members looked up once: reading ``Phase.TRACK`` or ruckig's ``Result.Finished`` costs 0.2–0.4 µs in Python
# 3.11, several times a cycle; comparing by identity with these costs nothing (tools/servo_cost.py).
_HOLD, _TRACK, _CRUISE, _STOP = Phase.HOLD, Phase.TRACK, Phase.CRUISE, Phase.STOP
_WORKING, _FINISHED = Result.Working, Result.Finished
_POSITION, _VELOCITY = ControlInterface.Position, ControlInterface.Velocity
_PER_JOINT, _TOGETHER = Synchronization.No, Synchronization.Time


class ClampReason(enum.IntEnum):
    SOFT_LIMIT = 1  # a position beyond a soft limit
    VELOCITY_LIMIT = 2  # a velocity beyond the (scaled) velocity limit
    STOP_BEFORE_SOFT_LIMIT = 3  # a velocity the joint could not brake from before a soft limit


_CLAMP_TEXT = {
    ClampReason.SOFT_LIMIT: ("position", "soft limit"),
    ClampReason.VELOCITY_LIMIT: ("velocity", "velocity limit"),
    ClampReason.STOP_BEFORE_SOFT_LIMIT: ("velocity", "to stop before the soft limit"),
}


class Clamp(NamedTuple):
    """One value the API side changed: numbers, so it crosses in the target's record; the cycle words it."""

    joint: int  # index into params.joints
    reason: ClampReason
    requested: float
    result: float


def clamp_note(joints: Sequence[str], clamps: Sequence[Sequence[float]], heading: str = "target clamped") -> str:
    """The event text for ``clamps`` (rows of joint, reason, requested, result)."""
    notes = []
    for joint, reason, requested, result in clamps:
        what, why = _CLAMP_TEXT[ClampReason(int(reason))]
        notes.append(f"{joints[int(joint)]} {what} {requested:.4g} → {result:.4g} ({why})")
    return f"{heading}: " + "; ".join(notes)


@dataclass(frozen=True, slots=True)
class ServoTarget:
    """A validated target, as the API side hands it over."""

    positions: list[float]
    velocities: list[float]  # zeros when the client gave none
    moving: bool  # some velocity is non-zero: keep going once reached
    clamped: Sequence[Clamp] = ()  # what was clamped, empty if nothing: reported once per clamping episode


class TargetRecord:
    """The door for targets: a :class:`ServoTarget` crosses as one record of float64s, so the cycle takes it with
    a copy instead of unpickling an object every cycle of a stream.

    Layout for n joints: positions (n), velocities (n), moving (0/1), the number of clamps k, then 3n rows of
    (joint, reason, requested, result) of which the first k are used (each joint clamps at most its position,
    its velocity to the limit and its velocity to stop in time). The cycle reads it through views made here.
    """

    def __init__(self, door: LatestNumbers, n: int) -> None:
        self.n = n
        self._door = door
        record = door.values
        self.positions, self.velocities = record[:n], record[n : 2 * n]
        self._moving_at, self._count_at = 2 * n, 2 * n + 1
        self._clamps = record[2 * n + 2 :].reshape(3 * n, 4)

    @staticmethod
    def width(n: int) -> int:
        return 2 * n + 2 + 3 * n * 4

    # ---- API side -----------------------------------------------------------------------------------------
    def put(self, target: ServoTarget) -> None:
        n = self.n
        record = np.zeros(self.width(n))
        record[:n] = target.positions
        record[n : 2 * n] = target.velocities
        record[self._moving_at] = 1.0 if target.moving else 0.0
        record[self._count_at] = len(target.clamped)
        if target.clamped:
            record[2 * n + 2 : 2 * n + 2 + 4 * len(target.clamped)] = np.ravel(target.clamped)
        self._door.put(record)

    # ---- cycle side ---------------------------------------------------------------------------------------
    def take(self) -> bool:
        """Whether a new target arrived; if so, the views and the methods below read it until the next take."""
        return self._door.take() is not None

    def clear(self) -> None:
        self._door.clear()

    def moving(self) -> bool:
        return self._door.values.item(self._moving_at) != 0.0

    def clamped(self) -> bool:
        return self._door.values.item(self._count_at) != 0.0

    def clamp_note(self, joints: Sequence[str]) -> str:
        return clamp_note(joints, self._clamps[: int(self._door.values.item(self._count_at))].tolist())


def stopping_distance(speed: float, acceleration: float, jerk: float) -> float:
    """Distance to brake from ``speed`` (at zero acceleration) to rest, jerk-limited and time-optimal.

    The velocity profile of such a stop is point-symmetric about its middle, so the distance is speed·T/2.
    """
    if speed * jerk <= acceleration * acceleration:  # never reaches full deceleration
        return speed * math.sqrt(speed / jerk)
    return 0.5 * speed * (speed / acceleration + acceleration / jerk)


def speed_to_stop_within(distance: float, acceleration: float, jerk: float) -> float:
    """The highest speed (at zero acceleration) that ``stopping_distance`` brings to rest within ``distance``."""
    if distance <= 0.0:
        return 0.0
    if distance * jerk * jerk <= acceleration**3:
        return (distance * distance * jerk) ** (1.0 / 3.0)
    ratio = acceleration * acceleration / (2.0 * jerk)
    return -ratio + math.sqrt(ratio * ratio + 2.0 * distance * acceleration)


class ServoController(PlansMotion, Controller):
    Params = ServoParams
    KIND = "servo"
    SOURCE = Source.STREAM  # its targets; its chunks are Source.POLICY
    MEASURED = ("position",)  # starts from and follows the measured position

    def __init__(self, context: ControllerContext, params: ServoParams) -> None:
        super().__init__(context, params)
        self._index = context.index_of(params.joints)
        self._modes = np.zeros(len(self._index), dtype=np.int64)
        n = len(self._index)
        lim = context.limits
        missing = [
            j
            for j, k in zip(params.joints, self._index, strict=True)
            if not _positive(lim.acceleration[k], lim.jerk[k])
        ]
        if missing:
            raise ValueError(f"{context.name}: servo needs limits.acceleration and limits.jerk for joints {missing}")
        first = int(self._index[0])
        contiguous = bool((np.diff(self._index) == 1).all())
        self._where: slice | np.ndarray = slice(first, first + n) if contiguous else self._index
        self._writes_velocity = "velocity" in params.command_interfaces
        self._period = 1.0 / context.update_rate

        self._scale_limits(params)
        self._soft_lower, self._soft_upper = lim.soft_lower[self._index].tolist(), lim.soft_upper[self._index].tolist()
        self._lo = [p + POSITION_MARGIN for p in self._soft_lower]
        self._hi = [p - POSITION_MARGIN for p in self._soft_upper]
        self._lookahead = BRAKE_LOOKAHEAD_CYCLES * self._period
        self._fast_stream = FAST_STREAM_CYCLES * self._period * (1.0 + 1e-9)  # a hair over: clock rounding

        self._slot = TargetRecord(context.mailboxes.latest_numbers("target", TargetRecord.width(n)), n)
        self._chunks = ChunkPlayer(context.mailboxes.latest_numbers("chunk", ChunkRecord.width(n)), n)
        self._chunks.blend.limits(self._vmax, self._amax, self._jmax)
        self._chunks.ensemble = params.chunk_ensemble
        self._last_chunk_note = [-math.inf] * len(Verdict)  # per refusal: one event a second of each
        self._zeros = [0.0] * n
        self._otg: Ruckig | None = None
        self._jerk_pending = False  # a lowered jerk not yet in ruckig's input (see on_params)
        self._inp = InputParameter(n)
        self._out = OutputParameter(n)
        self._p: list[float] = list(self._zeros)  # desired state written each cycle
        self._v: list[float] = self._zeros
        self._cruise_velocity = list(self._zeros)  # per-joint target velocity while cruising (0 once braking)
        # The target being tracked, as handed to ruckig: a target equal to it is not handed over again. Code that
        # sets ruckig's target position or velocity other than through ``_track`` must clear these.
        self._target_p: list[float] = []
        self._target_v: list[float] = []
        self._sync = Synchronization.Time  # what ruckig's input holds: set only when it changes
        self._moving = False
        self._racing = False  # toward a first chunk (see _play_chunk)
        self.phase = Phase.HOLD
        self._last_target = -math.inf
        self._last_clamp = -math.inf

    def _scale_limits(self, params: ServoParams) -> None:
        """Per-joint limits as Python floats: the per-cycle braking check reads them without numpy overhead."""
        lim = self.context.limits
        self._vlimit = (lim.velocity[self._index] * params.velocity_scale).tolist()  # what clients are told
        self._vmax = [v * (1.0 - VELOCITY_MARGIN) for v in self._vlimit]  # what ruckig plans with
        self._amax = (lim.acceleration[self._index] * params.acceleration_scale).tolist()
        self._jmax = (lim.jerk[self._index] * params.acceleration_scale).tolist()

    def on_configure(self) -> None:
        self._otg = Ruckig(len(self._index), self._period)
        self._inp.target_acceleration = self._zeros
        self._inp.synchronization = self._sync
        self._plan_within_limits()

    def _plan_within_limits(self) -> None:
        inp = self._inp
        inp.max_velocity = self._vmax
        inp.max_acceleration = self._amax
        inp.max_jerk = self._jmax

    def on_params(self, old: Params) -> None:
        """New scales apply from the next cycle: ruckig replans from the current position, velocity and
        acceleration, so a joint faster than a lowered limit brakes to it — the command never steps.

        A lowered jerk waits (per joint) until the joint can reach its new limits with it: the motion under way
        was planned with the old jerk, and braking it with a lower one overshoots even the old velocity limit.
        Targets already accepted were clamped to the old limits; ruckig holds the new ones all the same."""
        assert isinstance(self.params, ServoParams)
        jerk_before = self._inp.max_jerk
        self._scale_limits(self.params)
        self._chunks.blend.limits(self._vmax, self._amax, self._jmax)
        self._chunks.ensemble = self.params.chunk_ensemble
        self._plan_within_limits()
        if self.phase != Phase.HOLD:
            self._inp.max_jerk = [max(a, b) for a, b in zip(jerk_before, self._jmax, strict=True)]
            self._jerk_pending = self._inp.max_jerk != self._jmax
        vmax = self._vmax  # a target or cruise velocity above the new limit is one ruckig would refuse to plan
        self._cruise_velocity[:] = [min(max(v, -m), m) for v, m in zip(self._cruise_velocity, vmax, strict=True)]
        self._target_v = [min(max(v, -m), m) for v, m in zip(self._inp.target_velocity, vmax, strict=True)]
        self._inp.target_velocity = self._target_v

    def _adopt_pending_jerk(self) -> None:
        """Each joint takes its lowered jerk once braking with it stays within its new limits."""
        inp = self._inp
        jerk, v, a = inp.max_jerk, inp.current_velocity, inp.current_acceleration
        pending = False
        for i in range(len(jerk)):
            new = self._jmax[i]
            if jerk[i] != new:
                if abs(a[i]) <= self._amax[i] and abs(v[i]) + a[i] * a[i] / (2.0 * new) <= self._vlimit[i]:
                    jerk[i] = new
                else:
                    pending = True
        inp.max_jerk = jerk
        self._jerk_pending = pending

    def on_cleanup(self) -> None:
        self._otg = None

    # ---- API side -----------------------------------------------------------------------------------------
    def inputs(self) -> Mapping[str, Callable[[Any], None]]:
        return {"target": self.accept, "chunk": self.accept_chunk}

    def accept_chunk(self, payload: Any) -> None:
        """Validate a policy's action chunk (hild/motion/chunks.py), clamp each step as a target, hand it over."""
        if not self.active:
            raise ValueError(f"controller {self.name} is not active")
        self._chunks.record.put(parse_chunk(payload, self.params.joints, self._clamp))

    def accept(self, payload: Any) -> None:
        """Validate ``{"positions": [...], "velocities"?: [...]}`` (controller joint order), clamp, hand over."""
        if not self.active:
            raise ValueError(f"controller {self.name} is not active")
        if not isinstance(payload, dict):
            raise ValueError('expected an object {"positions": [...], "velocities"?: [...]}')
        unknown, more = unknown_keys(payload, ("positions", "velocities"))
        if unknown:
            raise ValueError(f"unknown keys {unknown}{and_more(more)}; expected positions and optional velocities")
        if "positions" not in payload:
            raise ValueError("missing positions")
        positions = self._numbers(payload["positions"], "positions")
        given = payload.get("velocities")
        velocities = self._numbers(given, "velocities") if given is not None else list(self._zeros)
        clamped = self._clamp(positions, velocities)
        moving = any(v != 0.0 for v in velocities)
        self._slot.put(ServoTarget(positions, velocities, moving, clamped))

    def _numbers(self, values: Any, what: str) -> list[float]:
        joints = self.params.joints
        if not isinstance(values, list):
            raise ValueError(f"{what} must be a list of {len(joints)} numbers, not {type(values).__name__}")
        if len(values) != len(joints):
            raise ValueError(f"expected {len(joints)} {what} for {joints}; found {len(values)}")
        for i, v in enumerate(values):
            if isinstance(v, bool):
                raise ValueError(f"{what}[{i}] ({joints[i]}) is a boolean; expected a number")
            if not isinstance(v, int | float):
                raise ValueError(f"{what}[{i}] ({joints[i]}) is not a number: {v!r}")
            if not -_FLOAT_MAX <= v <= _FLOAT_MAX:  # NaN and inf fail; so do ints too big for a float
                shown = v if isinstance(v, float) else "an integer beyond the float range"
                raise ValueError(f"{what}[{i}] ({joints[i]}) must be finite, not {shown}")
        return [float(v) for v in values]

    def _clamp(self, positions: list[float], velocities: list[float]) -> list[Clamp]:
        """Clamp in place to the soft limits and the (scaled) velocity limits; say what was changed.

        Values within the limits but inside the planning margins are pulled in silently: nothing to report.
        A velocity pointing at a nearby soft limit is also reduced to one the joint can still brake from before
        the limit once the target is reached: the dead reckoning that follows must never cross it.
        """
        clamps = []
        for i in range(len(positions)):
            p, v, lo, hi, vmax = positions[i], velocities[i], self._lo[i], self._hi[i], self._vmax[i]
            if not lo <= p <= hi:
                positions[i] = min(max(p, lo), hi)
                if not self._soft_lower[i] <= p <= self._soft_upper[i]:
                    clamps.append(Clamp(i, ClampReason.SOFT_LIMIT, p, positions[i]))
            if abs(v) > vmax:
                velocities[i] = math.copysign(vmax, v)
                if abs(v) > self._vlimit[i]:
                    clamps.append(Clamp(i, ClampReason.VELOCITY_LIMIT, v, velocities[i]))
            v = velocities[i]
            if v != 0.0:
                room = (hi - positions[i] if v > 0.0 else positions[i] - lo) - vmax * self._lookahead
                safe = speed_to_stop_within(room, self._amax[i], self._jmax[i])
                if abs(v) > safe:
                    velocities[i] = math.copysign(safe, v)
                    clamps.append(Clamp(i, ClampReason.STOP_BEFORE_SOFT_LIMIT, v, velocities[i]))
        return clamps

    # ---- cycle side ---------------------------------------------------------------------------------------
    def on_activate(self, state: JointState, last_command: ServoCommand) -> None:
        """Start at rest where the joints are (where a reading is missing, at the last command): no jump."""
        q = state.position[self._index]
        start = np.where(np.isfinite(q), q, last_command.position[self._index]).tolist()
        self._hold_at(start)
        self._slot.clear()
        self._end_chunk()
        self._chunks.reset()
        self.source = self.SOURCE  # what its targets are (a subclass's own: follow's leader)
        self._last_target = -math.inf
        self._last_clamp = -math.inf
        self._last_chunk_note = [-math.inf] * len(Verdict)

    def _follow_measured(self, state: JointState) -> None:
        """A joint is faulted or e-stopped: forget the stream and rest where the arm is, so a reset resumes
        from there; targets sent meanwhile are dropped."""
        q = state.position[self._index]
        self._hold_at(np.where(np.isfinite(q), q, self._p).tolist())
        self._slot.clear()
        self._end_chunk()
        self._chunks.reset()

    def update(self, t: float, dt: float, state: JointState, command: ServoCommand) -> None:
        if first_taken_over(self.context.joint_modes, self._index, self._modes) >= 0:
            self._follow_measured(state)
            return
        if self._slot.take():
            self._end_chunk()
            self.source = self.SOURCE
            self._track(t)
        elif self._chunks.record.take():
            self._start_chunk(t)
        elif (self.phase is _TRACK or self.phase is _CRUISE) and t - self._last_target > self.params.command_timeout:
            self.context.emit_event(
                "warning", f"no target for {self.params.command_timeout:g} s: stopping, then holding"
            )
            self._end_chunk()
            self._stop()
        if self._chunks.playing:
            self._play_chunk(dt)
        if self.phase is _CRUISE:
            self._brake_before_soft_limits()
        if self.phase is not _HOLD:
            self._step(dt)
            if self.phase is _STOP:  # planning failed: the chunk is over too
                self._end_chunk()
        command.position[self._where] = self._p
        if self._writes_velocity:
            command.velocity[self._where] = self._v
        command.written[self._where] = True

    def _track(self, t: float) -> None:
        """Plan toward the target just taken (plain lists: ruckig's bindings copy them fastest).

        A target that is part of a fast stream is planned per joint (``Synchronization.No``): its plan is
        replaced within a cycle or two, so only its first samples ever run, and synchronizing the joints only
        held back the ones that were not the slowest, at twice ruckig's re-planning cost per joint (4.9 against
        2.1 µs on 3 joints, 8.9 against 3.4 on 6, every cycle: docs/performance.md, "The servo's cost per
        target"). Every joint keeps its own limits either way. A single target, or a slow stream, still moves
        the joints together in time (``Synchronization.Time``). A target equal to the one being tracked changes
        nothing in the plan and is not handed to ruckig again; it still counts for the timeout.
        """
        inp, target = self._inp, self._slot
        positions, velocities = target.positions.tolist(), target.velocities.tolist()
        fast = t - self._last_target <= self._fast_stream
        self._last_target = t
        # The same target again (a stream holding still): the plan under way already goes there.
        same = self.phase is _TRACK and positions == self._target_p and velocities == self._target_v
        if not same:
            if self.phase is not _TRACK:
                inp.control_interface = _POSITION
            sync = _PER_JOINT if fast else _TOGETHER
            if sync is not self._sync:
                inp.synchronization = self._sync = sync
            inp.target_position = self._target_p = positions
            inp.target_velocity = self._target_v = velocities
            self._cruise_velocity[:] = velocities
            self._moving = target.moving()
            self.phase = _TRACK
        if target.clamped():
            if t - self._last_clamp >= CLAMP_EVENT_QUIET:
                self.context.emit_event("warning", target.clamp_note(self.params.joints))
            self._last_clamp = t

    def _start_chunk(self, t: float) -> None:
        """A policy's chunk arrived: play it from ``t − stamp`` on (the inference delay skipped), or say why not."""
        chunks = self._chunks
        running = chunks.playing
        verdict = chunks.start(t)
        if verdict != Verdict.STARTED:
            if t - self._last_chunk_note[verdict] >= CLAMP_EVENT_QUIET:
                # an overtaken chunk is normal when inference times jitter; a chunk out of time is the client's error
                level = "info" if verdict == Verdict.STALE else "warning"
                self.context.emit_event(level, chunks.refusal(verdict, t))
                self._last_chunk_note[verdict] = t
            return
        self._racing = not running  # a successor is blended in and tracked along the path (see _play_chunk)
        self.source = Source.POLICY
        self._moving = False
        self._last_target = t
        if chunks.clamped():
            if t - self._last_clamp >= CLAMP_EVENT_QUIET:
                step, row = chunks.first_clamp()
                note = clamp_note(self.params.joints, [row], f"chunk clamped at step {step}")
                self.context.emit_event("warning", note)
            self._last_clamp = t

    def _play_chunk(self, dt: float) -> None:
        """Aim ruckig at the chunk ``CHUNK_LEAD`` ahead, to be reached in that time: a moving target whose path
        ruckig follows within the limits instead of racing to it (time-optimal re-planning every cycle chatters).

        Except toward a first chunk (after a rest, a stream or a stop: nothing to blend from), often far from the
        joints and moving: there each joint races to the target on its own, time-optimally, until the next chunk
        starts or the plan reaches the target within ``RACE_UNTIL`` leads. A synchronized plan with the lead as its
        minimum duration, asked for a target out of reach, stretches to whatever duration every joint can meet
        (0.3–0.6 s: a joint's reachable durations have gaps) and leaves the path; on the bench that relapsed once in
        five seeds (80 mrad 1.2–1.4 s after the start), never with the race (seeds 1–8)."""
        chunks, inp = self._chunks, self._inp
        chunks.aim(dt, self.params.chunk_slowdown, CHUNK_LEAD)
        p, v, a = chunks.target.tolist()
        clip_target(p, v, a, self._lo, self._hi, self._vmax, self._amax, self._jmax)
        inp.control_interface = ControlInterface.Position
        inp.synchronization = self._sync = _TOGETHER
        inp.target_position = p
        inp.target_velocity = v
        inp.target_acceleration = a
        inp.minimum_duration = chunks.lead_time  # the last approach too: no time-optimal dash to the end
        if self._racing:  # a first chunk: until its successor or until within reach, each joint time-optimally
            if self._out.trajectory.duration <= RACE_UNTIL * chunks.lead_time and self.phase is _TRACK:
                self._racing = False
            else:
                inp.minimum_duration = None
                inp.synchronization = self._sync = _PER_JOINT
        self.phase = Phase.TRACK

    def _end_chunk(self) -> None:
        """Playback over (a target took over, a timeout, a planning error): plain targets are reached at rest
        acceleration, time-optimally."""
        if self._chunks.playing or self._inp.minimum_duration is not None:
            self._chunks.stop()
            self._inp.minimum_duration = None
            self._inp.target_acceleration = self._zeros
            self._target_p = self._target_v = []  # ruckig was aimed at the chunk: no streamed target is "the same"

    def _cruise(self) -> None:
        self._to_velocity(self._cruise_velocity, _CRUISE)

    def _stop(self) -> None:
        self._to_velocity(self._zeros, _STOP)

    def _to_velocity(self, velocity: list[float], phase: Phase) -> None:
        """Reach ``velocity`` jerk-limited, each joint on its own (no position target while streaming stops)."""
        inp = self._inp
        inp.control_interface = _VELOCITY
        inp.synchronization = self._sync = _PER_JOINT
        inp.target_velocity = velocity
        self.phase = phase

    def _hold_at(self, position: list[float]) -> None:
        inp = self._inp
        inp.current_position = position
        inp.current_velocity = self._zeros
        inp.current_acceleration = self._zeros
        self._p, self._v = position, self._zeros
        self.phase = _HOLD
        if self._jerk_pending:
            inp.max_jerk = self._jmax
            self._jerk_pending = False
        if self._otg is not None:
            self._otg.reset()

    def _brake_before_soft_limits(self) -> None:
        """Per cruising joint: if one more cycle of travel would leave too little room to stop, brake now."""
        cruise, p, braked = self._cruise_velocity, self._p, False
        for i in range(len(cruise)):
            v = cruise[i]
            if v == 0.0:
                continue
            room = (self._hi[i] - p[i] if v > 0.0 else p[i] - self._lo[i]) - abs(v) * self._lookahead
            if stopping_distance(abs(v), self._amax[i], self._jmax[i]) >= room:
                cruise[i] = 0.0
                braked = True
        if braked:
            self._inp.target_velocity = cruise

    def _step(self, dt: float) -> None:
        otg, inp, out = self._otg, self._inp, self._out
        assert otg is not None, "servo used before on_configure"
        if dt > 0.0 and dt != otg.delta_time:
            otg.delta_time = dt  # the wall clock's real period: the plan advances with real time
        try:
            result = otg.update(inp, out)
            reason = "" if result is _WORKING or result is _FINISHED else result.name
        except RuckigError as exc:
            result, reason = Result.ErrorInvalidInput, str(exc).strip().removeprefix("[ruckig] ")
        if not reason:
            p, v = out.new_position, out.new_velocity
            if not math.isfinite(sum(p) + sum(v)):  # a NaN or inf anywhere makes the sum non-finite
                reason = "non-finite output"
        if reason:
            self._planning_failed(reason, dt)
            return
        out.pass_to_input(inp)
        self._p, self._v = p, v
        if self._jerk_pending:
            self._adopt_pending_jerk()
        if result is _FINISHED:
            if self.phase is _TRACK and self._moving:
                self._cruise()
            elif self.phase is _STOP:
                self._hold_at(p)

    def _planning_failed(self, reason: str, dt: float) -> None:
        """Stop as on timeout; if even the stop cannot be planned, hold the last desired position. Never a NaN."""
        if self.phase is not _STOP:
            self.context.emit_event("error", f"ruckig could not plan ({reason}): stopping, then holding")
            self._stop()
            self._step(dt)
        else:
            self.context.emit_event("error", f"ruckig could not plan the stop ({reason}): holding")
            self._hold_at(list(self._p))


_FLOAT_MAX = sys.float_info.max


def _positive(*values: float) -> bool:
    return all(math.isfinite(v) and v > 0.0 for v in values)
