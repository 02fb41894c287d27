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
    sample is one small matrix-vector product plus three copies (about 2 µs for six joints).
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
        k = np.arange(DEGREE + 1, dtype=np.float64)
        velocity = np.zeros_like(coeffs)
        velocity[:, :-1] = coeffs[:, 1:] * k[1:]
        acceleration = np.zeros_like(coeffs)
        acceleration[:, :-1] = velocity[:, 1:] * k[1:]
        self._stacked = np.ascontiguousarray(np.vstack([coeffs, velocity, acceleration]))
        self._powers = np.ones(DEGREE + 1)
        self._out = np.empty(3 * self.joints)
        j = self.joints
        self._p, self._v, self._a = self._out[:j], self._out[j : 2 * j], self._out[2 * j :]
        self._bounds: tuple[np.ndarray, np.ndarray] | None = None

    # ---- constructors ---------------------------------------------------------------------------------------
    @classmethod
    def linear(cls, p0: np.ndarray, p1: np.ndarray, duration: float) -> PolynomialSegment:
        """Constant velocity from ``p0`` to ``p1`` (a positions-only trajectory, as ros2_controllers' JTC)."""
        duration = _positive_duration(duration)
        p0 = _vector("p0", p0)
        p1 = _vector("p1", p1, len(p0))
        coeffs = np.zeros((len(p0), DEGREE + 1))
        coeffs[:, 0] = p0
        coeffs[:, 1] = (p1 - p0) / duration
        return cls(coeffs, duration)

    @classmethod
    def cubic(
        cls, p0: np.ndarray, v0: np.ndarray, p1: np.ndarray, v1: np.ndarray, duration: float
    ) -> PolynomialSegment:
        """Cubic Hermite: matches position and velocity at both ends."""
        T = _positive_duration(duration)
        p0 = _vector("p0", p0)
        j = len(p0)
        v0, p1, v1 = _vector("v0", v0, j), _vector("p1", p1, j), _vector("v1", v1, j)
        h = p1 - p0
        coeffs = np.zeros((j, DEGREE + 1))
        coeffs[:, 0] = p0
        coeffs[:, 1] = v0
        coeffs[:, 2] = (3.0 * h - (2.0 * v0 + v1) * T) / T**2
        coeffs[:, 3] = (-2.0 * h + (v0 + v1) * T) / T**3
        return cls(coeffs, T)

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
        h = p1 - p0
        coeffs = np.zeros((j, DEGREE + 1))
        coeffs[:, 0] = p0
        coeffs[:, 1] = v0
        coeffs[:, 2] = 0.5 * a0
        coeffs[:, 3] = (20.0 * h - (8.0 * v1 + 12.0 * v0) * T - (3.0 * a0 - a1) * T**2) / (2.0 * T**3)
        coeffs[:, 4] = (-30.0 * h + (14.0 * v1 + 16.0 * v0) * T + (3.0 * a0 - 2.0 * a1) * T**2) / (2.0 * T**4)
        coeffs[:, 5] = (12.0 * h - 6.0 * (v1 + v0) * T + (a1 - a0) * T**2) / (2.0 * T**5)
        return cls(coeffs, T)

    # ---- cycle side -----------------------------------------------------------------------------------------
    def sample(self, t: float, p: np.ndarray, v: np.ndarray, a: np.ndarray) -> None:
        tau = 0.0 if t <= 0.0 else (self.duration if t >= self.duration else t)
        tau2 = tau * tau
        pw = self._powers
        pw[1] = tau
        pw[2] = tau2
        pw[3] = tau2 * tau
        pw[4] = tau2 * tau2
        pw[5] = tau2 * tau2 * tau
        self._stacked.dot(pw, out=self._out)
        p[:] = self._p
        v[:] = self._v
        a[:] = self._a

    # ---- off the cycle --------------------------------------------------------------------------------------
    def position_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Exact per-joint extrema: the polynomial at both ends and where its derivative vanishes inside.

        Every candidate time is clipped into the segment and the polynomial evaluated there, so a spurious or
        inexact root can only add a point that is on the curve; it never widens the bounds beyond it.
        """
        if self._bounds is None:
            k = np.arange(1, DEGREE + 1, dtype=np.float64)
            # The derivative in normalised time s = τ / duration ∈ [0, 1]: there a coefficient's size is its
            # weight, so negligible top-order terms (rounding left by the constructors) can be dropped; left in,
            # they make the companion-matrix roots meaningless.
            derivative = self.coefficients[:, 1:] * k * self.duration ** (k - 1.0)
            s = _critical_points(derivative)
            tau = s * self.duration
            values = np.zeros_like(tau)
            for c in self.coefficients.T[::-1]:  # Horner, all joints and candidates at once
                values *= tau
                values += c[:, None]
            lo, hi = values.min(axis=1), values.max(axis=1)
            lo.flags.writeable = hi.flags.writeable = False
            self._bounds = (lo, hi)
        return self._bounds


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
            lo, hi = _ruckig_position_bounds(self.trajectory)
            lo.flags.writeable = hi.flags.writeable = False
            self._bounds = (lo, hi)
        return self._bounds


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


def _ruckig_position_bounds(trajectory: Any) -> tuple[np.ndarray, np.ndarray]:
    """Per-joint position extrema, mirroring ruckig's ``Trajectory::at_time``.

    Per section and joint: an optional two-phase brake pre-profile (first section only), seven constant-jerk
    phases, then constant acceleration until the section ends.
    """
    start = np.array(trajectory.at_time(0.0)[0], dtype=np.float64)
    end = np.array(trajectory.at_time(float(trajectory.duration))[0], dtype=np.float64)
    lo, hi = np.minimum(start, end), np.maximum(start, end)  # even if a joint has no phase of non-zero length
    ends = list(trajectory.intermediate_durations)
    starts = [0.0, *ends[:-1]]
    for section, profiles in enumerate(trajectory.profiles):
        for j, profile in enumerate(profiles):
            phases: list[tuple[float, ...]] = []
            elapsed = starts[section]
            brake = profile.brake
            if section == 0 and brake.duration > 0.0:
                phases += zip(brake.p, brake.v, brake.a, brake.j, brake.t, strict=True)
                elapsed += brake.duration
            p, v, a, t = profile.p, profile.v, profile.a, profile.t  # each attribute read copies a list
            phases += zip(p[:7], v[:7], a[:7], profile.j, t, strict=True)
            elapsed += sum(t)
            phases.append((p[7], v[7], a[7], 0.0, max(ends[section] - elapsed, 0.0)))
            for phase in phases:
                if phase[4] <= 0.0:  # the arrays of an unused phase may be stale (seen: a brake's second phase)
                    continue
                low, high = _phase_extrema(*phase)
                lo[j] = min(lo[j], low)
                hi[j] = max(hi[j], high)
    return lo, hi


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
