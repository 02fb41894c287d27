"""Action chunks: a policy's timed joint positions, played back as a moving target for the servo's ruckig path.

Policies (LeRobot's ACT, diffusion, pi0) emit *chunks*: e.g. 50 joint positions 20 ms apart, computed from an
observation that is 50–300 ms old by the time the chunk arrives, a new one every 100 ms. JTC-style upsampling
(each chunk a trajectory from the current state that comes to rest at its last point) jerks at every handoff and
lags by the inference delay. Here a chunk is a function of time: step ``k`` is where the joints should be at
``stamp + k·dt`` on the control clock (``stamp``: the joint_states stamp of the observation the policy used). Each
cycle the player samples it at ``t − stamp`` (the part already in the past is skipped: the inference delay is
compensated), interpolated as a cubic Hermite spline (position and velocity, C¹), and hands that moving target to
the servo, whose ruckig tracking keeps the command within the velocity, acceleration and jerk limits.

Handoffs: a new chunk joins the older ones still overlapping it (temporal ensembling: the target is their average at
the same instant, weighted ``exp(−age/ensemble)``), and whatever the change of members makes the target jump by
(position, velocity, acceleration) is absorbed by :class:`HandoffBlend`, an offset decaying to zero on a quintic
within a share of the limits: the target stays continuous, so ruckig's short lead keeps it within reach even when
successive chunks disagree, and the arm never comes to rest between overlapping chunks.

Late chunks: within ``slowdown`` (chunk time) of the running chunk's end, with no successor, playback slows:
chunk time advances at ``s = sqrt(remaining / slowdown)`` of real time, a constant deceleration of time that
reaches the last point at zero speed in ``2·slowdown`` s. A successor arriving meanwhile takes over at full
speed; none, and the joints rest at the last point (the servo's ``command_timeout`` still stops them earlier).

Two halves, as every streamed input: :func:`parse_chunk` (client domain) validates and clamps the JSON and
:class:`ChunkRecord` hands it over as one fixed-size float64 record; :class:`ChunkPlayer` (cycle) copies it into
arrays preallocated for :data:`MAX_CHUNK_STEPS` steps and samples them without allocating (the lists ruckig's
bindings take aside).
"""

from __future__ import annotations

import enum
import math
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from hild.crossing.mailboxes import LatestNumbers

# The servo aims at the chunk this far ahead (chunk time) and asks ruckig to take this long to get there: the plan
# then follows the chunk's path instead of racing to each cycle's sample (time-optimal re-planning every cycle
# bangs between the acceleration limits). On the bench's reference (hild bench --only chunks, seeds 1–4): no lead
# 28 mrad RMS; 0.15 s 4.9; 0.1 s 1.8; 0.08 s 1.0 (max 1.8); 0.06 s 0.5 (but max 3.9–5.0: a plan now and then not
# reachable in time); 0.04 s 12 (falls back to racing). Shorter lags less, longer forgives more.
CHUNK_LEAD = 0.08  # s
# Chunks kept for temporal ensembling (the running one and the newest older ones); an older chunk leaves once its
# weight is below MIN_WEIGHT (at 10 Hz and the default ensemble time constant, after 3 handoffs).
ENSEMBLE_SLOTS = 6
MIN_WEIGHT = 0.02
MAX_CHUNK_STEPS = 100  # fixes the record's size: 2 s at 50 Hz, more than any policy's chunk in use
MAX_STEP_PERIOD = 1.0  # s; a longer step is no action chunk
MIN_STEP_PERIOD = 1e-4  # s
CHUNK_KEYS = ("stamp", "dt", "positions", "velocities")
_FLOAT_MAX = sys.float_info.max

# Clamps the servo applies to one step, in place: (positions, velocities) → rows (joint, reason, requested, result).
Clamp = Callable[[list[float], list[float]], Sequence[Sequence[float]]]


@dataclass(frozen=True, slots=True)
class Chunk:
    """A validated chunk, as the API side hands it over: clamped positions and velocities, (steps, n)."""

    stamp: float
    dt: float
    positions: np.ndarray
    velocities: np.ndarray
    clamps: int = 0  # values changed by the clamp
    first_clamp: tuple[float, ...] = ()  # (step, joint, reason, requested, result) of the first one


def parse_chunk(payload: Any, joints: Sequence[str], clamp: Clamp) -> Chunk:
    """Validate ``{"stamp", "dt", "positions": [[…n…] × steps], "velocities"?: […]}`` and clamp each step.

    Without velocities each step gets the slope of its neighbours (central differences, one-sided at the ends),
    so the interpolation passes through the points with a continuous velocity (a Catmull-Rom spline).
    """
    if not isinstance(payload, dict):
        raise ValueError('expected an object {"stamp": s, "dt": s, "positions": [[...], ...], "velocities"?: [...]}')
    unknown = [k for k in payload if k not in CHUNK_KEYS]
    if unknown:
        raise ValueError(f"unknown keys {sorted(map(str, unknown))[:3]}; expected {', '.join(CHUNK_KEYS)}")
    missing = [k for k in CHUNK_KEYS[:3] if k not in payload]
    if missing:
        raise ValueError(f"missing {', '.join(missing)}")
    stamp = _number(payload["stamp"], "stamp")
    dt = _number(payload["dt"], "dt")
    if not MIN_STEP_PERIOD <= dt <= MAX_STEP_PERIOD:
        raise ValueError(f"dt must be within [{MIN_STEP_PERIOD:g}, {MAX_STEP_PERIOD:g}] s, not {dt:g}")
    positions = _table(payload["positions"], "positions", joints, None)
    given = payload.get("velocities")
    if given is None:
        velocities = np.gradient(positions, dt, axis=0)
    else:
        velocities = _table(given, "velocities", joints, len(positions))
    clamps, first = 0, ()
    p_rows, v_rows = positions.tolist(), velocities.tolist()
    for step, (p, v) in enumerate(zip(p_rows, v_rows, strict=True)):
        changed = clamp(p, v)
        if changed and not clamps:
            first = (float(step), *map(float, changed[0]))
        clamps += len(changed)
    return Chunk(stamp, dt, np.array(p_rows), np.array(v_rows), clamps, first)


def _number(value: Any, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{what} must be a number, not {value!r}")
    if not -_FLOAT_MAX <= value <= _FLOAT_MAX:
        raise ValueError(f"{what} must be finite, not {value!r}")
    return float(value)


def _table(rows: Any, what: str, joints: Sequence[str], steps: int | None) -> np.ndarray:
    n = len(joints)
    if not isinstance(rows, list):
        raise ValueError(f"{what} must be a list of steps, each a list of {n} numbers; not {type(rows).__name__}")
    if steps is not None and len(rows) != steps:
        raise ValueError(f"{what} has {len(rows)} steps; positions has {steps}")
    if not 2 <= len(rows) <= MAX_CHUNK_STEPS:
        raise ValueError(f"a chunk has 2 to {MAX_CHUNK_STEPS} steps; {what} has {len(rows)}")
    for k, row in enumerate(rows):
        if not isinstance(row, list) or len(row) != n:
            found = f"{len(row)} values" if isinstance(row, list) else type(row).__name__
            raise ValueError(f"{what}[{k}] must be a list of {n} numbers for {list(joints)}; found {found}")
        for i, value in enumerate(row):
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ValueError(f"{what}[{k}][{i}] ({joints[i]}) is not a number: {value!r}")
            if not -_FLOAT_MAX <= value <= _FLOAT_MAX:
                raise ValueError(f"{what}[{k}][{i}] ({joints[i]}) must be finite, not {value!r}")
    return np.array(rows, dtype=np.float64)


class ChunkRecord:
    """The door for chunks: one record of float64s, sized for :data:`MAX_CHUNK_STEPS`, so a chunk crosses as a
    copy and the cycle never unpickles.

    Layout for n joints: stamp, dt, steps, clamp count, the first clamp (step, joint, reason, requested, result),
    then positions (MAX_CHUNK_STEPS × n) and velocities (MAX_CHUNK_STEPS × n), of which the first ``steps`` rows
    are used.
    """

    HEADER = 9

    def __init__(self, door: LatestNumbers, n: int) -> None:
        self.n = n
        self._door = door
        record = door.values
        size = MAX_CHUNK_STEPS * n
        self.header = record[: self.HEADER]
        self.positions = record[self.HEADER : self.HEADER + size].reshape(MAX_CHUNK_STEPS, n)
        self.velocities = record[self.HEADER + size : self.HEADER + 2 * size].reshape(MAX_CHUNK_STEPS, n)

    @classmethod
    def width(cls, n: int) -> int:
        return cls.HEADER + 2 * MAX_CHUNK_STEPS * n

    def put(self, chunk: Chunk) -> None:
        """API side: one record (allocated here, in the client domain: the cycle only copies it)."""
        n, steps = self.n, len(chunk.positions)
        record = np.zeros(self.width(n))
        first = chunk.first_clamp or (0.0,) * 5
        record[: self.HEADER] = (chunk.stamp, chunk.dt, steps, chunk.clamps, *first)
        size = MAX_CHUNK_STEPS * n
        record[self.HEADER : self.HEADER + steps * n] = chunk.positions.ravel()
        record[self.HEADER + size : self.HEADER + size + steps * n] = chunk.velocities.ravel()
        self._door.put(record)

    def take(self) -> bool:
        """Cycle side: whether a new chunk arrived; the views read it until the next take."""
        return self._door.take() is not None

    def clear(self) -> None:
        self._door.clear()


class Verdict(enum.IntEnum):
    STARTED = 0
    STALE = 1  # stamped before the running chunk: an older observation, dropped (counted)
    PAST = 2  # ends before now: nothing of it left to play
    FUTURE = 3  # stamped after now: not the control clock


class ChunkPlayer:
    """Cycle side: the running chunk, its playback time and speed; samples the servo's target each cycle."""

    def __init__(self, door: LatestNumbers, n: int) -> None:
        self.record = ChunkRecord(door, n)
        self.n = n
        # The newest chunks, a ring of ENSEMBLE_SLOTS: slot i, step k: position, velocity (two steps: one (4, n) view)
        self._pv = np.zeros((ENSEMBLE_SLOTS, MAX_CHUNK_STEPS, 2, n))
        self._slot_steps = [0] * ENSEMBLE_SLOTS
        self._slot_dt = [1.0] * ENSEMBLE_SLOTS
        self._slot_stamp = [-math.inf] * ENSEMBLE_SLOTS
        self._live = [False] * ENSEMBLE_SLOTS  # in the ensemble
        self._newest = 0  # the running chunk's slot
        self._steps = 0  # the running chunk's
        self._step = 1.0  # the running chunk's dt
        self.ensemble = 0.0  # s: the older chunks' weights decay with their age by this time constant; 0: newest only
        self._at_end = False  # the target was the running chunk's last point, at rest
        self._mixed = False  # the last sample averaged older chunks in
        self._stack = np.zeros((4 * ENSEMBLE_SLOTS, n))  # the members' steps around the instant (see _sample_ensemble)
        self._stack_weights = [np.zeros((3, 4 * m)) for m in range(ENSEMBLE_SLOTS + 1)]  # per member count
        self._rows: tuple[list[float], list[float], list[float]] = ([], [], [])
        self.stamp = -math.inf  # of the chunk last started: an older one is stale
        self.tau = 0.0  # chunk time of the next sample, s since stamp
        self.speed = 1.0  # chunk time per real time, < 1 while slowing down
        self.playing = False
        self.dropped = 0  # stale chunks dropped since activation
        self.refused = 0  # chunks refused for their timing (past, future) since activation
        self.target = np.zeros((3, n))  # the sample: position, velocity, acceleration
        self.target_p, self.target_v, self.target_a = self.target
        self.lead_time = 0.0  # s the servo gives ruckig to reach the target
        self._weights = np.zeros((3, 4))  # Hermite weights of (p_k, v_k, p_k+1, v_k+1) for p, v, a
        self.blend = HandoffBlend(n)
        self._last = np.zeros((3, n))  # the last target handed out (chunk + offset): where a successor blends from
        self._blend_pending = False  # the target's source changed: absorb the difference at the next aim

    @property
    def end(self) -> float:
        """Chunk time of the last step."""
        return (self._steps - 1) * self._step

    def reset(self) -> None:
        """Forget the running chunk and any waiting one (activation, a joint taken over)."""
        self.record.clear()
        self.stop()
        self.stamp = -math.inf
        self.dropped = self.refused = 0

    def stop(self) -> None:
        self.playing = False
        self._blend_pending = False
        self.blend.clear()

    def start(self, t: float) -> Verdict:
        """Take the chunk just arrived (``record.take()`` was true) at cycle time ``t``."""
        header = self.record.header
        stamp, dt, steps = header.item(0), header.item(1), int(header.item(2))
        if stamp < self.stamp:
            self.dropped += 1
            return Verdict.STALE
        if stamp > t:
            self.refused += 1
            return Verdict.FUTURE
        if t - stamp > (steps - 1) * dt:
            self.refused += 1
            return Verdict.PAST
        if self.playing:  # overlapping: the ensemble gains a member; blend from the running target into it
            slot = (self._newest + 1) % ENSEMBLE_SLOTS
            self._blend_pending = True
        else:
            slot = 0
            self._live[:] = [False] * ENSEMBLE_SLOTS
        self._pv[slot, :steps, 0] = self.record.positions[:steps]
        self._pv[slot, :steps, 1] = self.record.velocities[:steps]
        self._slot_steps[slot], self._slot_dt[slot], self._slot_stamp[slot] = steps, dt, stamp
        self._live[slot], self._newest, self._at_end = True, slot, False
        self._steps, self._step, self.stamp = steps, dt, stamp
        self.tau, self.speed, self.playing = t - stamp, 1.0, True
        return Verdict.STARTED

    def refusal(self, verdict: Verdict, t: float) -> str:
        """The event text for a chunk :meth:`start` did not take (the values are still in the record)."""
        header = self.record.header
        stamp, dt, steps = header.item(0), header.item(1), int(header.item(2))
        if verdict == Verdict.STALE:
            return (
                f"chunk dropped: stamped {stamp:.4f} s, before the running chunk's {self.stamp:.4f} s "
                f"(an older observation; {self.dropped} dropped since activation)"
            )
        if verdict == Verdict.FUTURE:
            return (
                f"chunk refused: stamp {stamp:.4f} s is ahead of the control clock ({t:.4f} s); stamp each chunk "
                "with the joint_states stamp of the observation the policy used"
            )
        return (
            f"chunk refused: it ends at {stamp + (steps - 1) * dt:.4f} s (stamp {stamp:.4f} + {steps - 1} × {dt:g} s), "
            f"before now ({t:.4f} s): all of it is in the past"
        )

    def clamped(self) -> bool:
        return self.record.header.item(3) != 0.0

    def first_clamp(self) -> tuple[int, list[float]]:
        """The first clamped value's step and (joint, reason, requested, result) row, for the servo's note."""
        header = self.record.header
        return int(header.item(4)), header[5:9].tolist()

    def aim(self, dt: float, slowdown: float, lead: float) -> bool:
        """Sample the target for this cycle into :attr:`target` (position, velocity, acceleration) — the chunk
        ``lead`` s of chunk time ahead, to be reached in ``lead`` s — and advance playback by ``dt``; False once the
        chunk has ended (the target is then its last point, at rest)."""
        end, tau = self.end, self.tau
        if tau >= end:
            self._rest_at_end()
            self.playing = False
            return False
        remaining = end - tau
        self.speed = math.sqrt(remaining / slowdown) if remaining < slowdown else 1.0
        ahead = tau + (lead - dt) * self.speed  # the plan starts from the last command, one cycle back
        self.lead_time = lead
        if ahead >= end:  # the last point, at rest, in the time the slow-down takes to get there
            if not self._at_end:
                self._at_end = True
                self._blend_pending |= self._mixed  # older chunks were in the target: they leave it now
            self._rest_at_end()
            if remaining < slowdown:
                self.lead_time = max(2.0 * math.sqrt(slowdown * remaining), dt)
        else:
            self._sample_ensemble(ahead, self.speed)
        self._absorb_handoff(dt)
        self.tau = min(tau + dt * self.speed, end)
        return True

    def _absorb_handoff(self, dt: float) -> None:
        """At a handoff, start blending out the difference between the running target (the last one, carried one
        cycle on) and the new chunk's sample; every cycle, add what is left of it: the target stays continuous."""
        target, last = self.target, self._last
        if self._blend_pending:
            self._blend_pending = False
            # the last target one cycle on (p + v·dt + a·dt²/2, v + a·dt, a), minus the new chunk's sample
            last[0] += dt * last[1] + (0.5 * dt * dt) * last[2]
            last[1] += dt * last[2]
            np.subtract(last, target, out=last)
            self.blend.start(last)
        self.blend.add_to(target, dt)
        last[:] = target

    def _rest_at_end(self) -> None:
        self.target_p[:] = self._pv[self._newest, self._steps - 1, 0]
        self.target[1:] = 0.0

    def _sample_ensemble(self, tau: float, speed: float) -> None:
        """The running chunk at ``tau``, averaged with the older chunks still in the ring at the same instant (ACT's
        temporal ensembling), each weighted ``exp(−age/ensemble)`` (age: its stamp's, before the running chunk's).
        The weights are constant between handoffs, so the average is as smooth as the chunks; each change of members
        (a new chunk, an older one ending or weighing less than ``MIN_WEIGHT``) is blended in (:meth:`_absorb_handoff`).
        """
        newest, target = self._newest, self.target
        self._mixed = False
        ensemble = self.ensemble
        if ensemble <= 0.0:
            self._sample(newest, tau, speed, target)
            return
        # Every member's two steps around the instant go into one stack, its Hermite weights (times its ensemble
        # weight) into one row each for p, v, a: one (3, 4m) × (4m, n) product for the m members.
        stack, rows, live, stamp = self._stack, self._rows, self._live, self.stamp
        wp, wv, wa = rows
        wp.clear(), wv.clear(), wa.clear()
        total, m = 0.0, 0
        for slot in range(ENSEMBLE_SLOTS):
            if not live[slot]:
                continue
            age = stamp - self._slot_stamp[slot]
            weight = 1.0 if slot == newest else math.exp(-age / ensemble)
            at = tau + age  # the same instant in that chunk's time
            if slot != newest and (weight < MIN_WEIGHT or at >= (self._slot_steps[slot] - 1) * self._slot_dt[slot]):
                live[slot] = False
                self._blend_pending = True
                continue
            h = self._slot_dt[slot]
            k = min(int(at / h), self._slot_steps[slot] - 2)
            u = at / h - k
            u2, u3 = u * u, u * u * u
            c, cv, ca = weight, weight * speed, weight * speed * speed / (h * h)
            cs = cv / h
            wp += (c * (2 * u3 - 3 * u2 + 1), c * h * (u3 - 2 * u2 + u), c * (3 * u2 - 2 * u3), c * h * (u3 - u2))
            wv += (cs * (6 * u2 - 6 * u), cv * (3 * u2 - 4 * u + 1), cs * (6 * u - 6 * u2), cv * (3 * u2 - 2 * u))
            wa += (ca * (12 * u - 6), ca * h * (6 * u - 4), ca * (6 - 12 * u), ca * h * (6 * u - 2))
            stack[4 * m : 4 * m + 4] = self._pv[slot, k : k + 2].reshape(4, self.n)
            total += weight
            m += 1
        weights = self._stack_weights[m]
        weights[0], weights[1], weights[2] = wp, wv, wa
        np.dot(weights, stack[: 4 * m], out=target)
        if m > 1:
            target *= 1.0 / total
            self._mixed = True

    def _sample(self, slot: int, tau: float, speed: float, out: np.ndarray) -> None:
        """Cubic Hermite between the two steps of ``slot`` around ``tau``: one (3, 4) × (4, n) product; velocity and
        acceleration scaled by the playback speed."""
        h = self._slot_dt[slot]
        k = min(int(tau / h), self._slot_steps[slot] - 2)
        u = tau / h - k
        u2, u3 = u * u, u * u * u
        s, s2 = speed / h, speed * speed / (h * h)
        self._weights[:] = (
            (2 * u3 - 3 * u2 + 1, h * (u3 - 2 * u2 + u), 3 * u2 - 2 * u3, h * (u3 - u2)),
            ((6 * u2 - 6 * u) * s, (3 * u2 - 4 * u + 1) * speed, (6 * u - 6 * u2) * s, (3 * u2 - 2 * u) * speed),
            ((12 * u - 6) * s2, (6 * u - 4) * s2 * h, (6 - 12 * u) * s2, (6 * u - 2) * s2 * h),
        )
        np.dot(self._weights, self._pv[slot, k : k + 2].reshape(4, self.n), out=out)


class HandoffBlend:
    """The offset between two chunks where they meet, decaying to zero on a quintic (minimum-jerk) profile.

    A new chunk rarely starts where the running one is: a real policy's successive predictions differ by a few mrad
    (and in velocity). Jumping to the new one puts the target out of reach within the tracker's short lead, and the
    longer synchronized plan that follows leaves the path. Instead the played target is the new chunk plus an offset
    that starts at the difference (position Δp, velocity Δv, acceleration Δa: the target stays continuous in all
    three across the handoff) and reaches zero, with zero velocity and acceleration, after a blend time chosen per
    joint so that each of the offset's terms stays within ``BLEND_FRACTION`` of the joint's velocity, acceleration
    and jerk limits (:func:`blend_time`). A handoff during a blend starts from the blended target: offsets never
    stack.

    Per joint the offset is a polynomial in the time since the handoff, ``Σ c_k·s^k`` (k ≤ 5), until its blend time;
    the coefficients live in a preallocated (6, n) array, evaluated with one (3, 6) × (6, n) product.
    """

    def __init__(self, n: int) -> None:
        self.n = n
        self.coefficients = np.zeros((6, n))
        self.duration = [0.0] * n  # s per joint; 0 once blended out
        self.age = 0.0  # s since the handoff
        self.active = False
        self._powers = np.zeros((3, 6))
        self._offset = np.zeros((3, n))
        self.vmax = [math.inf] * n
        self.amax = [math.inf] * n
        self.jmax = [math.inf] * n

    def limits(self, vmax: Sequence[float], amax: Sequence[float], jmax: Sequence[float]) -> None:
        """The (scaled) limits the blend time is computed from."""
        self.vmax, self.amax, self.jmax = list(vmax), list(amax), list(jmax)

    def clear(self) -> None:
        self.active = False
        self.coefficients[:] = 0.0
        self.duration[:] = [0.0] * self.n

    def start(self, difference: np.ndarray) -> None:
        """Start from ``difference`` (3, n): position, velocity and acceleration, the running target − the new."""
        c = self.coefficients
        self.age = 0.0
        self.active = False
        for i in range(self.n):
            p0, v0, a0 = difference.item(0, i), difference.item(1, i), difference.item(2, i)
            if p0 == 0.0 and v0 == 0.0 and a0 == 0.0:
                self.duration[i] = 0.0
                c[:, i] = 0.0
                continue
            T = blend_time(p0, v0, a0, self.vmax[i], self.amax[i], self.jmax[i])
            T2, T3 = T * T, T * T * T
            c[0, i], c[1, i], c[2, i] = p0, v0, 0.5 * a0
            c[3, i] = -10.0 * p0 / T3 - 6.0 * v0 / T2 - 1.5 * a0 / T
            c[4, i] = 15.0 * p0 / (T3 * T) + 8.0 * v0 / T3 + 1.5 * a0 / T2
            c[5, i] = -6.0 * p0 / (T3 * T2) - 3.0 * v0 / (T2 * T2) - 0.5 * a0 / T3
            self.duration[i] = T
            self.active = True

    def add_to(self, target: np.ndarray, dt: float) -> None:
        """Add the offset at its current age to ``target`` (3, n: p, v, a) in place, then age it by ``dt``."""
        if not self.active:
            return
        s, c, duration = self.age, self.coefficients, self.duration
        blending = False
        for i in range(self.n):  # past its blend time a joint's polynomial is not zero: zero it
            if duration[i] != 0.0:
                if s >= duration[i]:
                    duration[i] = 0.0
                    c[:, i] = 0.0
                else:
                    blending = True
        if not blending:
            self.active = False
            return
        s2, s3 = s * s, s * s * s
        self._powers[:] = (
            (1.0, s, s2, s3, s3 * s, s3 * s2),
            (0.0, 1.0, 2.0 * s, 3.0 * s2, 4.0 * s3, 5.0 * s3 * s),
            (0.0, 0.0, 2.0, 6.0 * s, 12.0 * s2, 20.0 * s3),
        )
        np.dot(self._powers, c, out=self._offset)
        target += self._offset
        self.age = s + dt


# The offset's share of each limit, per term (its start in position, velocity, acceleration): the chunk's own motion
# and the tracker's corrections need the rest. The constants below are the peaks of the quintic's basis functions on
# [0, 1] (H0 for the position difference, H1 velocity, H2 acceleration): velocity H0' 1.875; acceleration H0'' 5.774,
# H1'' 3.94; jerk H0''' 60, H1''' 36, H2''' 9.
BLEND_FRACTION = 0.2
MIN_BLEND = 0.05  # s
MAX_BLEND = 1.0  # s: a difference that needs longer is no disagreement but a jump; the tracker takes the rest


def blend_time(dp: float, dv: float, da: float, vmax: float, amax: float, jmax: float) -> float:
    """The shortest blend time, within [``MIN_BLEND``, ``MAX_BLEND``], at which each term of an offset starting at
    (dp, dv, da) stays within ``BLEND_FRACTION`` of the velocity, acceleration and jerk limits."""
    f = BLEND_FRACTION
    dp, dv, da = abs(dp), abs(dv), abs(da)
    needed = max(
        1.875 * dp / (f * vmax),
        math.sqrt(5.774 * dp / (f * amax)),
        3.94 * dv / (f * amax),
        (60.0 * dp / (f * jmax)) ** (1.0 / 3.0),
        math.sqrt(36.0 * dv / (f * jmax)),
        9.0 * da / (f * jmax),
    )
    return min(max(needed, MIN_BLEND), MAX_BLEND)


def clip_target(
    p: list[float],
    v: list[float],
    a: list[float],
    lo: Sequence[float],
    hi: Sequence[float],
    vmax: Sequence[float],
    amax: Sequence[float],
    jmax: Sequence[float],
) -> None:
    """In place, a target ruckig can plan to: a sample between two clamped steps can still overshoot them a little;
    its velocity within the limit; its acceleration within the limit and small enough that braking it at the jerk
    limit keeps the velocity within its limit (|v| + a²/2j ≤ v_max: else ruckig refuses the target state)."""
    for i in range(len(p)):
        if p[i] < lo[i]:
            p[i] = lo[i]
        elif p[i] > hi[i]:
            p[i] = hi[i]
        limit = vmax[i]
        if v[i] > limit:
            v[i] = limit
        elif v[i] < -limit:
            v[i] = -limit
        room = math.sqrt(2.0 * jmax[i] * (limit - abs(v[i])))
        bound = min(amax[i], room)
        if a[i] > bound:
            a[i] = bound
        elif a[i] < -bound:
            a[i] = -bound
