"""Trajectory segments: the pieces a trajectory is played from, each sampled into caller-owned arrays.

``sample`` runs on the cycle thread every cycle, so it writes into the arrays it is given and only touches
buffers preallocated at construction (which also means one segment must not be sampled from two threads at
once). Time ``t`` is relative to the segment's start and clamped into ``[0, duration]``, so a segment never
extrapolates.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np

DEGREE = 5  # quintic is the highest order a trajectory point can ask for (position, velocity, acceleration)


class Segment(Protocol):
    duration: float

    def sample(self, t: float, p: np.ndarray, v: np.ndarray, a: np.ndarray) -> None: ...

    def position_bounds(self) -> tuple[np.ndarray, np.ndarray]: ...


def _vector(name: str, value: Any, joints: int | None = None) -> np.ndarray:
    arr = np.array(value, dtype=np.float64)
    if arr.ndim != 1 or (joints is not None and arr.shape[0] != joints):
        expected = "a 1-D array" if joints is None else f"shape ({joints},)"
        raise ValueError(f"{name}: expected {expected}, found shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} must be finite; found {arr.tolist()}")
    return arr


def _positive_duration(duration: float) -> float:
    duration = float(duration)
    if not (duration > 0.0 and np.isfinite(duration)):
        raise ValueError(f"a polynomial segment needs a finite duration > 0; found {duration}")
    return duration


class PolynomialSegment:
    """``p(τ) = Σ_k c_k τ^k`` per joint, ``k = 0..5``, ``τ`` in seconds from the segment's start.

    Position, velocity and acceleration coefficients are stacked into one (3J, 6) matrix at construction, so a
    sample is one small matrix-vector product plus three copies.
    """

    def __init__(self, coefficients: np.ndarray, duration: float) -> None:
        coeffs = np.array(coefficients, dtype=np.float64)
        if coeffs.ndim != 2 or coeffs.shape[1] != DEGREE + 1:
            raise ValueError(f"coefficients: expected shape (J, {DEGREE + 1}), found {coeffs.shape}")
        if not np.isfinite(coeffs).all():
            raise ValueError("coefficients must be finite")
        self.duration = _positive_duration(duration)
        self.joints = coeffs.shape[0]
        coeffs.flags.writeable = False
        self.coefficients = coeffs
        self._stacked = stack_derivatives(coeffs, np.empty((3 * self.joints, DEGREE + 1)))
        self._powers = np.ones(DEGREE + 1)
        self._out = np.empty(3 * self.joints)
        j = self.joints
        self._p, self._v, self._a = self._out[:j], self._out[j : 2 * j], self._out[2 * j :]
        self._bounds: tuple[np.ndarray, np.ndarray] | None = None

    def __reduce__(self) -> tuple[Any, ...]:
        """Crosses to the cycle process as its coefficients: the derived matrices are rebuilt there."""
        return PolynomialSegment, (self.coefficients, self.duration)

    # ---- constructors ---------------------------------------------------------------------------------------
    @classmethod
    def linear(cls, p0: np.ndarray, p1: np.ndarray, duration: float) -> PolynomialSegment:
        """Constant velocity from ``p0`` to ``p1`` (a positions-only trajectory, as ros2_controllers' JTC)."""
        duration = _positive_duration(duration)
        p0 = _vector("p0", p0)
        p1 = _vector("p1", p1, len(p0))
        return cls(linear_coefficients(p0, p1, duration), duration)

    @classmethod
    def cubic(
        cls, p0: np.ndarray, v0: np.ndarray, p1: np.ndarray, v1: np.ndarray, duration: float
    ) -> PolynomialSegment:
        """Cubic Hermite: matches position and velocity at both ends."""
        T = _positive_duration(duration)
        p0 = _vector("p0", p0)
        j = len(p0)
        v0, p1, v1 = _vector("v0", v0, j), _vector("p1", p1, j), _vector("v1", v1, j)
        return cls(cubic_coefficients(p0, v0, p1, v1, T), T)

    @classmethod
    def quintic(
        cls,
        p0: np.ndarray,
        v0: np.ndarray,
        a0: np.ndarray,
        p1: np.ndarray,
        v1: np.ndarray,
        a1: np.ndarray,
        duration: float,
    ) -> PolynomialSegment:
        """Quintic: matches position, velocity and acceleration at both ends."""
        T = _positive_duration(duration)
        p0 = _vector("p0", p0)
        j = len(p0)
        v0, a0 = _vector("v0", v0, j), _vector("a0", a0, j)
        p1, v1, a1 = _vector("p1", p1, j), _vector("v1", v1, j), _vector("a1", a1, j)
        return cls(quintic_coefficients(p0, v0, a0, p1, v1, a1, T), T)

    # ---- cycle side -----------------------------------------------------------------------------------------
    def sample(self, t: float, p: np.ndarray, v: np.ndarray, a: np.ndarray) -> None:
        tau = 0.0 if t <= 0.0 else (self.duration if t >= self.duration else t)
        evaluate_stacked(self._stacked, tau, self._powers, self._out)
        p[:] = self._p
        v[:] = self._v
        a[:] = self._a

    # ---- off the cycle --------------------------------------------------------------------------------------
    def position_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Exact per-joint extrema (:func:`polynomial_bounds`)."""
        if self._bounds is None:
            lo, hi = polynomial_bounds(self.coefficients[None], np.array([self.duration]))
            lo.flags.writeable = hi.flags.writeable = False
            self._bounds = (lo, hi)
        return self._bounds


# ---- polynomial arithmetic, shared by a segment and a table of them (hild.motion.tables) ---------------------------
def _power(T: Any, k: int) -> Any:
    """``T ** k`` as Python computes it for a float, elementwise for an array of durations.

    numpy's own power differs from C's ``pow`` in the last bit for a few per cent of values (measured: 5 % for
    k = 3..5), and a table of segments must hold the very coefficients the segment objects hold."""
    if isinstance(T, np.ndarray):
        return np.array([x**k for x in T.ravel().tolist()]).reshape(T.shape)
    return T**k


def linear_coefficients(p0: np.ndarray, p1: np.ndarray, T: Any) -> np.ndarray:
    """Coefficients (..., J, 6) of constant velocity from ``p0`` to ``p1`` (..., J) in ``T`` (a float, or durations
    (..., 1))."""
    coeffs = np.zeros((*p0.shape, DEGREE + 1))
    coeffs[..., 0] = p0
    coeffs[..., 1] = (p1 - p0) / T
    return coeffs


def cubic_coefficients(p0: np.ndarray, v0: np.ndarray, p1: np.ndarray, v1: np.ndarray, T: Any) -> np.ndarray:
    """Cubic Hermite coefficients (..., J, 6); shapes as :func:`linear_coefficients`."""
    h = p1 - p0
    coeffs = np.zeros((*p0.shape, DEGREE + 1))
    coeffs[..., 0] = p0
    coeffs[..., 1] = v0
    coeffs[..., 2] = (3.0 * h - (2.0 * v0 + v1) * T) / _power(T, 2)
    coeffs[..., 3] = (-2.0 * h + (v0 + v1) * T) / _power(T, 3)
    return coeffs


def quintic_coefficients(
    p0: np.ndarray, v0: np.ndarray, a0: np.ndarray, p1: np.ndarray, v1: np.ndarray, a1: np.ndarray, T: Any
) -> np.ndarray:
    """Quintic coefficients (..., J, 6) matching p, v, a at both ends; shapes as :func:`linear_coefficients`."""
    h = p1 - p0
    T2, T3, T4, T5 = (_power(T, k) for k in (2, 3, 4, 5))
    coeffs = np.zeros((*p0.shape, DEGREE + 1))
    coeffs[..., 0] = p0
    coeffs[..., 1] = v0
    coeffs[..., 2] = 0.5 * a0
    coeffs[..., 3] = (20.0 * h - (8.0 * v1 + 12.0 * v0) * T - (3.0 * a0 - a1) * T2) / (2.0 * T3)
    coeffs[..., 4] = (-30.0 * h + (14.0 * v1 + 16.0 * v0) * T + (3.0 * a0 - 2.0 * a1) * T2) / (2.0 * T4)
    coeffs[..., 5] = (12.0 * h - 6.0 * (v1 + v0) * T + (a1 - a0) * T2) / (2.0 * T5)
    return coeffs


_K = np.arange(1, DEGREE + 1, dtype=np.float64)


def stack_derivatives(coeffs: np.ndarray, out: np.ndarray) -> np.ndarray:
    """``out`` (..., 3J, 6) ← the position, velocity and acceleration coefficients of ``coeffs`` (..., J, 6), so
    that one matrix-vector product with τ's powers samples all three. Returns ``out``."""
    j = coeffs.shape[-2]
    out[..., :j, :] = coeffs
    out[..., j:, -1] = 0.0
    np.multiply(coeffs[..., 1:], _K, out=out[..., j : 2 * j, :-1])
    np.multiply(out[..., j : 2 * j, 1:], _K, out=out[..., 2 * j :, :-1])
    return out


def evaluate_stacked(stacked: np.ndarray, tau: float, powers: np.ndarray, out: np.ndarray) -> None:
    """``out`` (3J,) ← p, v, a at ``tau`` from :func:`stack_derivatives`' matrix; ``powers`` (6,) is scratch whose
    first element is 1."""
    tau2 = tau * tau
    powers[1] = tau
    powers[2] = tau2
    powers[3] = tau2 * tau
    powers[4] = tau2 * tau2
    powers[5] = tau2 * tau2 * tau
    stacked.dot(powers, out=out)


def polynomial_bounds(coefficients: np.ndarray, durations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact per-joint extrema over polynomials (M, J, 6) lasting ``durations`` (M,): each one at both ends and
    where its derivative vanishes inside.

    Every candidate time is clipped into the segment and the polynomial evaluated there, so a spurious or inexact
    root can only add a point that is on the curve; it never widens the bounds beyond it.
    """
    m, joints, _ = coefficients.shape
    T = durations[:, None, None]
    # The derivative in normalised time s = τ / duration ∈ [0, 1]: there a coefficient's size is its weight, so
    # negligible top-order terms (rounding left by the constructors) can be dropped; left in, they make the
    # companion-matrix roots meaningless.
    derivative = coefficients[..., 1:] * _K * T ** (_K - 1.0)
    tau = _critical_points(derivative.reshape(m * joints, DEGREE)).reshape(m, joints, -1) * T
    values = np.zeros_like(tau)
    for c in np.moveaxis(coefficients, -1, 0)[::-1]:  # Horner, all segments, joints and candidates at once
        values *= tau
        values += c[..., None]
    return values.min(axis=(0, 2)), values.max(axis=(0, 2))


def _critical_points(derivative: np.ndarray) -> np.ndarray:
    """Candidate extremum times in [0, 1] per row: both ends and every real(ish) root of the derivative.

    ``derivative`` is (J, 5), lowest order first, in normalised time. Roots are found per degree for all joints
    at once: closed forms up to quadratics (linear and cubic segments), batched companion-matrix eigenvalues
    above. Only real parts are kept and clipped, so a complex or spurious root adds a point on the curve at
    worst; where a quadratic has no real root its vertex is used, since rounding may have hidden a double root.
    """
    joints, terms = derivative.shape
    s = np.zeros((joints, terms + 1))
    s[:, 1] = 1.0
    magnitude = np.abs(derivative)
    significant = magnitude > 1e-14 * magnitude.max(axis=1, keepdims=True)
    degree = np.where(significant.any(axis=1), terms - 1 - np.argmax(significant[:, ::-1], axis=1), 0)
    d = derivative
    rows = degree == 1
    s[rows, 2] = -d[rows, 0] / d[rows, 1]
    rows = degree == 2
    if rows.any():
        c0, c1, c2 = d[rows, 0], d[rows, 1], d[rows, 2]
        vertex = -c1 / (2.0 * c2)
        half_width = np.sqrt(np.maximum(c1 * c1 - 4.0 * c2 * c0, 0.0)) / (2.0 * np.abs(c2))
        s[rows, 2], s[rows, 3], s[rows, 4] = vertex - half_width, vertex + half_width, vertex
    for n in range(3, terms):
        rows = degree == n
        if rows.any():
            monic = d[rows, :n] / d[rows, n : n + 1]
            companion = np.zeros((len(monic), n, n))
            companion[:, 1:, :-1] = np.eye(n - 1)
            companion[:, :, -1] = -monic
            s[rows, 2 : 2 + n] = np.linalg.eigvals(companion).real
    return np.clip(s, 0.0, 1.0)


class RuckigSegment:
    """A ruckig trajectory: anything with ``duration``, ``degrees_of_freedom`` and ``at_time`` (and, for the
    bounds, ruckig's ``profiles`` and ``intermediate_durations``).

    This module never imports ruckig; :mod:`hild.motion.planning` builds these.
    """

    def __init__(self, trajectory: Any) -> None:
        self.trajectory = trajectory
        self.duration = float(trajectory.duration)
        self.joints = int(trajectory.degrees_of_freedom)
        self._bounds: tuple[np.ndarray, np.ndarray] | None = None

    def sample(self, t: float, p: np.ndarray, v: np.ndarray, a: np.ndarray) -> None:
        tau = 0.0 if t <= 0.0 else (self.duration if t >= self.duration else t)
        p[:], v[:], a[:] = self.trajectory.at_time(tau)

    def position_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Exact per-joint extrema, from the trajectory's constant-jerk phases.

        Not ruckig's ``position_extrema``: in the community version it misses extrema of some profiles
        (pantor/ruckig#215; seen here on a leg whose velocity changes sign inside a phase).
        """
        if self._bounds is None:
            start = np.array(self.trajectory.at_time(0.0)[0], dtype=np.float64)
            end = np.array(self.trajectory.at_time(self.duration)[0], dtype=np.float64)
            lo, hi = _ruckig_position_bounds(_ruckig_phases(self.trajectory), start, end)
            lo.flags.writeable = hi.flags.writeable = False
            self._bounds = (lo, hi)
        return self._bounds

    def __reduce__(self) -> tuple[Any, ...]:
        """Crosses to the cycle process as its table of phases."""
        return PhaseSegment.of(self.trajectory).__reduce__()


def _phase_extrema(p0: float, v0: float, a0: float, jerk: float, length: float) -> tuple[float, float]:
    """Min and max of ``p0 + v0·τ + a0·τ²/2 + jerk·τ³/6`` over ``τ ∈ [0, length]``."""
    taus = [0.0, length]
    if jerk == 0.0:
        if a0 != 0.0:
            taus.append(-v0 / a0)
    else:
        taus.append(-a0 / jerk)  # the vertex of v: where a double root blurred by rounding lands
        disc = a0 * a0 - 2.0 * jerk * v0
        if disc >= 0.0:
            root = math.sqrt(disc)
            taus += [(-a0 + root) / jerk, (-a0 - root) / jerk]
    values = [
        p0 + tau * (v0 + tau * (a0 / 2.0 + tau * jerk / 6.0)) for tau in taus if 0.0 <= tau <= length
    ]  # the same integration as ruckig's at_time
    return min(values), max(values)


Phase = tuple[float, float, float, float, float, float]  # start, p0, v0, a0, jerk, length


def _ruckig_phases(trajectory: Any) -> list[list[Phase]]:
    """Per joint, the constant-jerk phases of a ruckig trajectory, in time order, mirroring
    ``Trajectory::at_time``: per section an optional two-phase brake pre-profile (first section only), seven
    constant-jerk phases, then constant acceleration until the section ends. Phases of zero length are left out
    (the arrays of an unused phase may be stale: seen on a brake's second phase)."""
    ends = list(trajectory.intermediate_durations)
    starts = [0.0, *ends[:-1]]
    joints: list[list[Phase]] = [[] for _ in range(int(trajectory.degrees_of_freedom))]
    for section, profiles in enumerate(trajectory.profiles):
        for j, profile in enumerate(profiles):
            raw: list[tuple[float, ...]] = []
            brake = profile.brake
            if section == 0 and brake.duration > 0.0:
                raw += zip(brake.p, brake.v, brake.a, brake.j, brake.t, strict=True)
            p, v, a, t = profile.p, profile.v, profile.a, profile.t  # each attribute read copies a list
            raw += zip(p[:7], v[:7], a[:7], profile.j, t, strict=True)
            elapsed = starts[section] + sum(phase[4] for phase in raw)
            raw.append((p[7], v[7], a[7], 0.0, max(ends[section] - elapsed, 0.0)))
            at = starts[section]
            for p0, v0, a0, jerk, length in raw:
                if length > 0.0:
                    joints[j].append((at, p0, v0, a0, jerk, length))
                at += length
    return joints


def _ruckig_position_bounds(
    phases: list[list[Phase]], start: np.ndarray, end: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per-joint position extrema over the phases (and the end points, for a joint with no phase of length)."""
    lo, hi = np.minimum(start, end), np.maximum(start, end)
    for j, joint in enumerate(phases):
        for _, p0, v0, a0, jerk, length in joint:
            low, high = _phase_extrema(p0, v0, a0, jerk, length)
            lo[j] = min(lo[j], low)
            hi[j] = max(hi[j], high)
    return lo, hi


def sample_phases(
    rows: Sequence[Sequence[Sequence[float]]],
    cursor: list[int],
    tau: float,
    p: np.ndarray,
    v: np.ndarray,
    a: np.ndarray,
) -> None:
    """p, v, a at ``tau`` (already clamped into the leg) from per-joint phase rows (start, p0, v0, a0, jerk,
    length), as ruckig's ``at_time`` integrates. ``cursor`` holds each joint's current phase: played forward, a
    joint costs O(1)."""
    for j, joint in enumerate(rows):
        k = cursor[j]
        if tau < joint[k][0]:
            k = 0
        last = len(joint) - 1
        while k < last and tau >= joint[k + 1][0] and joint[k + 1][5] > 0.0:
            k += 1
        cursor[j] = k
        at, p0, v0, a0, jerk, length = joint[k]
        x = min(tau - at, length) if length > 0.0 else 0.0
        p[j] = p0 + x * (v0 + x * (a0 / 2.0 + x * jerk / 6.0))
        v[j] = v0 + x * (a0 + x * jerk / 2.0)
        a[j] = a0 + x * jerk


class PhaseSegment:
    """A ruckig trajectory as a table of constant-jerk phases: what a :class:`RuckigSegment` becomes when it
    crosses to the cycle process (ruckig's own object cannot be pickled). Samples as ruckig's ``at_time`` does.

    ``table`` is (J, P, 6): start, p0, v0, a0, jerk, length per joint and phase, padded with copies of the
    joint's last phase. Sampling keeps a cursor per joint, so a trajectory played forward costs O(1) per joint.
    """

    def __init__(self, table: np.ndarray, duration: float, start: np.ndarray, end: np.ndarray) -> None:
        self.table = np.ascontiguousarray(table, dtype=np.float64)
        self.duration = float(duration)
        self.joints = self.table.shape[0]
        self.start, self.end = np.asarray(start, dtype=np.float64), np.asarray(end, dtype=np.float64)
        self._rows = [[tuple(phase) for phase in joint] for joint in self.table.tolist()]
        self._cursor = [0] * self.joints

    @classmethod
    def of(cls, trajectory: Any) -> PhaseSegment:
        duration = float(trajectory.duration)
        start = np.array(trajectory.at_time(0.0)[0], dtype=np.float64)
        end = np.array(trajectory.at_time(duration)[0], dtype=np.float64)
        phases = _ruckig_phases(trajectory)
        width = max(1, max(len(joint) for joint in phases))
        table = np.zeros((len(phases), width, 6))
        for j, joint in enumerate(phases):
            rows = joint or [(0.0, end[j], 0.0, 0.0, 0.0, 0.0)]  # a joint that never moves
            table[j, : len(rows)] = rows
            table[j, len(rows) :] = rows[-1]
        return cls(table, duration, start, end)

    def __reduce__(self) -> tuple[Any, ...]:
        return PhaseSegment, (self.table, self.duration, self.start, self.end)

    def sample(self, t: float, p: np.ndarray, v: np.ndarray, a: np.ndarray) -> None:
        tau = 0.0 if t <= 0.0 else (self.duration if t >= self.duration else t)
        sample_phases(self._rows, self._cursor, tau, p, v, a)

    def position_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        phases = [[tuple(r) for r in joint if r[5] > 0.0] for joint in self.table.tolist()]
        return _ruckig_position_bounds(phases, self.start.copy(), self.end.copy())  # type: ignore[arg-type]


class HoldSegment:
    """Stand still at ``position`` with zero velocity and acceleration; lasts 0 s but samples at any ``t``."""

    duration = 0.0

    def __init__(self, position: np.ndarray | Sequence[float]) -> None:
        pos = _vector("position", position)
        pos.flags.writeable = False
        self.position = pos
        self.joints = len(pos)

    def sample(self, t: float, p: np.ndarray, v: np.ndarray, a: np.ndarray) -> None:
        p[:] = self.position
        v.fill(0.0)
        a.fill(0.0)

    def position_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return self.position, self.position
