"""Jerk-limited planning with ruckig: moves to a point, stops, and untimed waypoint chains.

The only module of the motion library that imports ruckig. Every function returns segments that stay within the
given :class:`KinematicLimits` (a current state already beyond them is first braked back inside, as ruckig does),
or raises :class:`PlanningError` saying what was infeasible.
"""

from __future__ import annotations

import math

import numpy as np
from ruckig import ControlInterface, InputParameter, Result, Ruckig, RuckigError, Synchronization
from ruckig import Trajectory as RTrajectory

from hild.motion.limits import KinematicLimits
from hild.motion.segments import HoldSegment, PolynomialSegment, RuckigSegment, Segment

NUMERICAL_SLACK = 1e-9  # relative excursion beyond a limit that is rounding, clipped rather than rejected
BISECTION_STEPS = 6  # resolution 1/64 of a waypoint velocity when shrinking it
MAX_SHRINKS = 4  # after this many shrinks of one waypoint, its velocity is set to 0
# Peak |v|, |a|, |jerk| of the rest-to-rest minimum-jerk quintic over distance d in time T, times T^k / d.
MIN_JERK_PEAK_VELOCITY = 1.875
MIN_JERK_PEAK_ACCELERATION = 10.0 / math.sqrt(3.0)
MIN_JERK_PEAK_JERK = 60.0


class PlanningError(ValueError):
    """A motion cannot be planned within the limits; the message names the joints and values."""


# ---- input checks -----------------------------------------------------------------------------------------------
def _state(name: str, value: np.ndarray | None, joints: int) -> np.ndarray:
    if value is None:
        return np.zeros(joints)
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != (joints,):
        raise PlanningError(f"{name}: expected shape ({joints},), found {arr.shape}")
    bad = np.flatnonzero(~np.isfinite(arr))
    if bad.size:
        raise PlanningError(f"{name} must be finite; joints {bad.tolist()} have {arr[bad].tolist()}")
    return arr


def _within(name: str, value: np.ndarray, limit: np.ndarray) -> np.ndarray:
    """``value`` clipped into ±limit if it is outside only by rounding; otherwise a PlanningError."""
    outside = np.flatnonzero(np.abs(value) > limit * (1.0 + NUMERICAL_SLACK))
    if outside.size:
        pairs = ", ".join(f"joint {j}: |{value[j]:.6g}| > {limit[j]:.6g}" for j in outside)
        raise PlanningError(f"{name} exceeds its limit ({pairs})")
    return np.clip(value, -limit, limit)


def _input(
    p: np.ndarray, v: np.ndarray, a: np.ndarray, limits: KinematicLimits, interface: ControlInterface
) -> InputParameter:
    inp = InputParameter(limits.joints)
    inp.current_position = p.tolist()
    inp.current_velocity = v.tolist()
    inp.current_acceleration = a.tolist()
    inp.max_velocity = limits.velocity.tolist()
    inp.max_acceleration = limits.acceleration.tolist()
    inp.max_jerk = limits.jerk.tolist()
    inp.control_interface = interface
    return inp


def _calculate(inp: InputParameter, what: str) -> RuckigSegment:
    trajectory = RTrajectory(inp.degrees_of_freedom)
    try:
        result = Ruckig(inp.degrees_of_freedom).calculate(inp, trajectory)
    except RuckigError as exc:
        raise PlanningError(f"{what}: {str(exc).strip()}") from exc
    if result != Result.Working:
        raise PlanningError(f"{what}: ruckig returned {result.name}")
    return RuckigSegment(trajectory)


# ---- point to point ---------------------------------------------------------------------------------------------
def plan_move(
    p: np.ndarray,
    v: np.ndarray,
    a: np.ndarray,
    target_p: np.ndarray,
    target_v: np.ndarray | None,
    limits: KinematicLimits,
    min_duration: float | None = None,
) -> RuckigSegment:
    """Time-optimal jerk-limited move to ``target_p`` (with ``target_v``, acceleration 0), joints synchronized.

    ``min_duration`` stretches the move to at least that long; it never makes it faster than the limits allow.
    """
    j = limits.joints
    p, v, a = _state("p", p, j), _state("v", v, j), _state("a", a, j)
    target_p = _state("target_p", target_p, j)
    target_v = _within("target_v", _state("target_v", target_v, j), limits.velocity)
    inp = _input(p, v, a, limits, ControlInterface.Position)
    inp.target_position = target_p.tolist()
    inp.target_velocity = target_v.tolist()
    inp.target_acceleration = [0.0] * j
    inp.synchronization = Synchronization.Time
    if min_duration is not None:
        if not (min_duration >= 0.0 and math.isfinite(min_duration)):
            raise PlanningError(f"min_duration must be finite and >= 0; found {min_duration}")
        inp.minimum_duration = float(min_duration)
    return _calculate(inp, "move")


def plan_stop(p: np.ndarray, v: np.ndarray, a: np.ndarray, limits: KinematicLimits) -> RuckigSegment:
    """Jerk-limited stop to v = a = 0, for cancel, abort and timeout.

    Each joint brakes on its own as hard as its limits allow (no synchronization): that is the shortest stop
    and stopping distance per joint. Synchronizing would slow the braking of all but the slowest joint, and
    ruckig's velocity interface does not bound velocity, so a stretched joint could end up over its limit.
    """
    j = limits.joints
    p, v, a = _state("p", p, j), _state("v", v, j), _state("a", a, j)
    inp = _input(p, v, a, limits, ControlInterface.Velocity)
    inp.target_velocity = [0.0] * j
    inp.target_acceleration = [0.0] * j
    inp.synchronization = Synchronization.No
    return _calculate(inp, "stop")


# ---- untimed waypoints ------------------------------------------------------------------------------------------
def _leg_tolerance(span: np.ndarray) -> np.ndarray:
    return 1e-9 + 1e-6 * span


def _stays_in_box(segment: Segment, w0: np.ndarray, w1: np.ndarray) -> bool:
    tol = _leg_tolerance(np.abs(w1 - w0))
    box_lo, box_hi = np.minimum(w0, w1) - tol, np.maximum(w0, w1) + tol
    if isinstance(segment, RuckigSegment):  # ruckig's own extrema are cheap but can miss some: reject early only
        extrema = segment.trajectory.position_extrema
        if any(b.min < lo or b.max > hi for b, lo, hi in zip(extrema, box_lo, box_hi, strict=True)):
            return False
    lo, hi = segment.position_bounds()
    return bool(np.all(lo >= box_lo) and np.all(hi <= box_hi))


def _rest_to_rest_quintic(w0: np.ndarray, w1: np.ndarray, limits: KinematicLimits) -> PolynomialSegment:
    """Minimum-jerk move from rest to rest: monotone in every joint, and slow enough for all limits."""
    d = np.abs(w1 - w0)
    duration = max(
        float(np.max(MIN_JERK_PEAK_VELOCITY * d / limits.velocity)),
        float(np.max(np.sqrt(MIN_JERK_PEAK_ACCELERATION * d / limits.acceleration))),
        float(np.max(np.cbrt(MIN_JERK_PEAK_JERK * d / limits.jerk))),
    )
    zero = np.zeros_like(w0)
    return PolynomialSegment.quintic(w0, zero, zero, w1, zero, zero, duration)


def _leg(
    w0: np.ndarray, v0: np.ndarray, w1: np.ndarray, v1: np.ndarray, limits: KinematicLimits, index: int
) -> Segment:
    """One leg between waypoints with the given boundary velocities and zero boundary accelerations."""
    at_rest = not (v0.any() or v1.any())
    if at_rest and np.array_equal(w0, w1):
        return HoldSegment(w0)
    inp = _input(w0, v0, np.zeros_like(w0), limits, ControlInterface.Position)
    inp.target_position = w1.tolist()
    inp.target_velocity = v1.tolist()
    inp.target_acceleration = [0.0] * limits.joints
    inp.synchronization = Synchronization.Time
    return _calculate(inp, f"leg {index} (waypoint {index} to {index + 1})")


def _rest_leg(waypoints: np.ndarray, i: int, limits: KinematicLimits, fallback: bool = False) -> Segment:
    """Leg ``i`` from rest to rest: ruckig's, or (never seen, but a stop must exist) the minimum-jerk quintic.

    With ``fallback`` the quintic is also used if ruckig's leg leaves its box, which a rest-to-rest leg should
    not do.
    """
    w0, w1 = waypoints[i], waypoints[i + 1]
    zero = np.zeros_like(w0)
    try:
        leg = _leg(w0, zero, w1, zero, limits, i)
    except PlanningError:
        return _rest_to_rest_quintic(w0, w1, limits)
    if fallback and not _stays_in_box(leg, w0, w1):
        return _rest_to_rest_quintic(w0, w1, limits)
    return leg


def _initial_velocities(waypoints: np.ndarray, limits: KinematicLimits) -> np.ndarray:
    """Waypoint velocities to start from: as fast as each leg's direction allows, 0 where a joint turns.

    Each leg's "mean velocity" is its direction scaled so its limiting joint runs at its velocity limit. An
    interior waypoint gets, per joint, the harmonic mean of its two legs' velocities if the joint moves the same
    way in both, else 0 (it reverses or stands still in one of them, and any speed there would overshoot). The ends
    get 0. These are upper estimates; the chain shrinks them until every leg is feasible.
    """
    n, j = waypoints.shape
    velocities = np.zeros((n, j))
    if n < 3:
        return velocities
    d = np.diff(waypoints, axis=0)
    time_at_limit = np.max(np.abs(d) / limits.velocity, axis=1)
    moving = time_at_limit > 0.0
    mean = np.zeros_like(d)
    mean[moving] = d[moving] / time_at_limit[moving, None]
    before, after = mean[:-1], mean[1:]
    same_way = before * after > 0.0
    # Harmonic mean, as monotone cubic interpolation (Fritsch–Carlson) uses: it follows the slower leg, so a
    # joint that barely moves in one of the legs is not rushed through the waypoint.
    harmonic = 2.0 * before * after / np.where(same_way, before + after, 1.0)
    velocities[1:-1] = np.where(same_way, harmonic, 0.0)
    return np.clip(velocities, -limits.velocity, limits.velocity)


def _speed(velocity: np.ndarray, limits: KinematicLimits) -> float:
    """How fast a waypoint is passed, as the largest fraction of a joint's velocity limit."""
    return float(np.max(np.abs(velocity) / limits.velocity))


class _Chain:
    """Chooses waypoint velocities leg by leg so that every leg is feasible, in its box, and not slow.

    A leg is accepted if ruckig plans it, it stays inside the box spanned by its waypoints, and it takes no
    longer than the same leg from rest to rest. The last condition rejects boundary velocities that fit the box
    only by making the leg crawl, and it means the chain is never slower than stopping at every waypoint.
    """

    def __init__(self, waypoints: np.ndarray, velocities: np.ndarray, limits: KinematicLimits) -> None:
        self.waypoints = waypoints
        self.velocities = velocities  # shrunk in place
        self.limits = limits
        self.rest_durations = [_rest_leg(waypoints, i, limits).duration for i in range(len(waypoints) - 1)]

    def leg(self, i: int) -> Segment | None:
        """Leg ``i`` with the current waypoint velocities, or None if it is not acceptable."""
        w0, w1 = self.waypoints[i], self.waypoints[i + 1]
        try:
            leg = _leg(w0, self.velocities[i], w1, self.velocities[i + 1], self.limits, i)
        except PlanningError:
            return None
        if leg.duration > self.rest_durations[i] * (1.0 + NUMERICAL_SLACK) + 1e-12:
            return None
        return leg if _stays_in_box(leg, w0, w1) else None

    def shrink(self, i: int, k: int) -> None:
        """Scale waypoint ``k``'s velocity down to about the largest fraction that makes leg ``i`` acceptable.

        Acceptable fractions form an interval around the one that passes ``k`` as fast as the leg's other end
        (too slow fails too: the joint cannot brake or speed up in time). So that "matching" fraction is tried
        first; if it works, bisection between it and the failing full velocity finds the top of the interval.
        If it does not, the leg needs both ends slower: halve the match, and a later round shrinks the other end.
        """
        v = self.velocities
        base = v[k].copy()
        match = _speed(v[2 * i + 1 - k], self.limits) / _speed(base, self.limits)
        np.multiply(base, match, out=v[k])
        if match > 0.0 and self.leg(i) is None:
            v[k] *= 0.5
            return
        feasible, infeasible = match, 1.0  # with match 0 both ends are at rest, which is always acceptable
        for _ in range(BISECTION_STEPS):
            scale = 0.5 * (feasible + infeasible)
            np.multiply(base, scale, out=v[k])
            if self.leg(i) is None:
                infeasible = scale
            else:
                feasible = scale
        np.multiply(base, feasible, out=v[k])

    def plan(self) -> list[Segment]:
        """Plan leg after leg, shrinking waypoint velocities until every leg is acceptable.

        A failing leg shrinks whichever boundary velocity is the larger fraction of its limits: a too-fast start
        cannot brake in time, a too-fast end cannot be reached. Shrinking a start velocity changes the previous
        leg's end, so the chain steps back one leg (the backward pass of a velocity profile). Velocities only
        ever shrink, each waypoint at most MAX_SHRINKS times before it is set to 0, and a leg with both ends at
        rest is always acceptable, so this terminates with a valid chain.
        """
        v = self.velocities
        n = len(self.waypoints)
        legs: list[Segment | None] = [None] * (n - 1)
        shrinks = np.zeros(n, dtype=int)
        i = 0
        while i < n - 1:
            leg = self.leg(i)
            if leg is not None:
                legs[i] = leg
                i += 1
                continue
            start_free = bool(v[i].any())  # waypoint 0 and the last waypoint are always 0 here
            end_free = bool(v[i + 1].any())
            if not (start_free or end_free):
                legs[i] = _rest_leg(self.waypoints, i, self.limits, fallback=True)
                i += 1
                continue
            if start_free and end_free:
                k = i if _speed(v[i], self.limits) > _speed(v[i + 1], self.limits) else i + 1
            else:
                k = i if start_free else i + 1
            if shrinks[k] < MAX_SHRINKS:
                self.shrink(i, k)
            else:
                v[k] = 0.0
            shrinks[k] += 1
            if k == i:
                i -= 1  # the previous leg ends at the waypoint that just changed
        return [leg for leg in legs if leg is not None]


def plan_waypoints(
    waypoints: np.ndarray, limits: KinematicLimits, velocities: np.ndarray | None = None
) -> tuple[np.ndarray, list[Segment]]:
    """Jerk-limited motion through untimed waypoints (N, J): returns (waypoint velocities (N, J), N-1 legs).

    One ruckig state-to-state calculation per leg, with acceleration 0 at each waypoint, so position, velocity
    and acceleration are continuous at the waypoints. Without ``velocities`` they are chosen so that every leg
    stays inside the box spanned by its two waypoints (no overshoot) and the arm does not stop at waypoints it
    can pass through; the first and last are 0. Given ``velocities`` are used as they are, after checking them
    against the limits. A repeated waypoint gives a zero-length leg (a :class:`HoldSegment`).
    """
    w = np.asarray(waypoints, dtype=np.float64)
    j = limits.joints
    if w.ndim != 2 or w.shape[0] < 1 or w.shape[1] != j:
        raise PlanningError(f"waypoints: expected shape (N, {j}) with N >= 1, found {w.shape}")
    bad = np.argwhere(~np.isfinite(w))
    if bad.size:
        raise PlanningError(f"waypoints must be finite; (waypoint, joint) {bad.tolist()} are not")
    if velocities is not None:
        vel = np.asarray(velocities, dtype=np.float64)
        if vel.shape != w.shape:
            raise PlanningError(f"velocities: expected shape {w.shape}, found {vel.shape}")
        if not np.isfinite(vel).all():
            raise PlanningError("velocities must be finite")
        vel = np.array([_within(f"velocity at waypoint {k}", vel[k], limits.velocity) for k in range(len(w))])
        legs = [_leg(w[k], vel[k], w[k + 1], vel[k + 1], limits, k) for k in range(len(w) - 1)]
        return vel, legs
    vel = _initial_velocities(w, limits)
    return vel, _Chain(w, vel, limits).plan()
