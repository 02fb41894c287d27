"""A trajectory as segments played back to back, and the timed (JTC-style) segments it is built from."""

from __future__ import annotations

import bisect
from collections.abc import Sequence

import numpy as np

from hild.motion.segments import (
    PolynomialSegment,
    Segment,
    cubic_coefficients,
    linear_coefficients,
    quintic_coefficients,
)
from hild.motion.tables import SegmentTable


class Trajectory:
    """Segments played back to back from t = 0; after the end it holds the final position with v = a = 0.

    A :class:`~hild.motion.tables.SegmentTable` among the segments is a whole run of them (a long timed goal, a
    waypoint chain) and one entry here: its rows carry their start times, so it is handed the trajectory's own time
    (a table placed elsewhere is re-placed first, in numpy). Entry start times live in a Python list so the
    per-cycle lookup is one ``bisect`` (O(log n) over a few entries, no numpy call overhead).
    """

    def __init__(self, segments: Sequence[Segment | SegmentTable], joints: int) -> None:
        if not segments:
            raise ValueError("a trajectory needs at least one segment")
        self.joints = int(joints)
        parts: list[Segment | SegmentTable] = []
        starts: list[float] = []
        offsets: list[float] = []  # subtracted from t before sampling: a segment's start, 0 for a table
        elapsed = 0.0
        for i, segment in enumerate(segments):
            starts.append(elapsed)
            if isinstance(segment, SegmentTable):
                if segment.start != elapsed:
                    segment = segment.placed(elapsed)
                offsets.append(0.0)
                elapsed = segment.end
            else:
                duration = float(segment.duration)
                if not (duration >= 0.0 and np.isfinite(duration)):
                    raise ValueError(f"segment {i} has duration {duration}; expected finite and >= 0")
                offsets.append(elapsed)
                elapsed += duration
            parts.append(segment)
        self.segments: tuple[Segment | SegmentTable, ...] = tuple(parts)
        self._starts = starts
        self._offsets = offsets
        self.duration = elapsed
        p, v, a = np.empty(self.joints), np.empty(self.joints), np.empty(self.joints)
        for i, segment in enumerate(self.segments):
            joints = getattr(segment, "joints", None)  # hild's segments say; sampling proves it for any other
            try:
                if joints is not None and joints != self.joints:
                    raise ValueError(f"it has {joints}")
                if joints is None or i == len(self.segments) - 1:
                    _sample_end(segment, p, v, a)
            except ValueError as exc:
                raise ValueError(f"segment {i} does not have {self.joints} joints: {exc}") from exc
        p.flags.writeable = False
        self._final = p
        self._bounds: tuple[np.ndarray, np.ndarray] | None = None

    def sample(self, t: float, p: np.ndarray, v: np.ndarray, a: np.ndarray) -> int:
        """Write the desired state at ``t`` into ``p, v, a``; return the entry used (``len`` once finished)."""
        if t >= self.duration:
            p[:] = self._final
            v.fill(0.0)
            a.fill(0.0)
            return len(self.segments)
        i = bisect.bisect_right(self._starts, t) - 1
        if i < 0:
            i = 0
        self.segments[i].sample(t - self._offsets[i], p, v, a)
        return i

    def end_state(self, p: np.ndarray, v: np.ndarray, a: np.ndarray) -> None:
        """The state the last entry ends in, before the final hold zeroes v and a: where a stop must start."""
        _sample_end(self.segments[-1], p, v, a)

    def finished(self, t: float) -> bool:
        return t >= self.duration

    def final_position(self) -> np.ndarray:
        return self._final.copy()

    def start_times(self) -> np.ndarray:
        """Start time of each entry, shape (len(segments),)."""
        return np.array(self._starts)

    def position_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-joint min and max position over the whole trajectory (e.g. to check position limits)."""
        if self._bounds is None:
            lo = np.full(self.joints, np.inf)
            hi = np.full(self.joints, -np.inf)
            for segment in self.segments:
                seg_lo, seg_hi = segment.position_bounds()
                np.minimum(lo, seg_lo, out=lo)
                np.maximum(hi, seg_hi, out=hi)
            lo.flags.writeable = hi.flags.writeable = False
            self._bounds = (lo, hi)
        return self._bounds


def _sample_end(segment: Segment | SegmentTable, p: np.ndarray, v: np.ndarray, a: np.ndarray) -> None:
    if isinstance(segment, SegmentTable):
        segment.sample(segment.end, p, v, a)
    else:
        segment.sample(segment.duration, p, v, a)


def _points(name: str, value: np.ndarray | None, shape: tuple[int, int]) -> np.ndarray | None:
    if value is None:
        return None
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != shape:
        raise ValueError(f"{name}: expected shape {shape}, found {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} must be finite")
    return arr


def _timed_points(times: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    t = np.asarray(times, dtype=np.float64)
    pos = np.asarray(positions, dtype=np.float64)
    if t.ndim != 1 or len(t) == 0:
        raise ValueError(f"times: expected shape (N,) with N >= 1, found {t.shape}")
    if pos.ndim != 2 or pos.shape[0] != len(t):
        raise ValueError(f"positions: expected shape ({len(t)}, J), found {pos.shape}")
    if not (np.isfinite(t).all() and np.isfinite(pos).all()):
        raise ValueError("times and positions must be finite")
    not_increasing = np.flatnonzero(np.diff(t) <= 0.0)
    if not_increasing.size:
        i = int(not_increasing[0])
        raise ValueError(f"times must be strictly increasing; point {i + 1} at {t[i + 1]} s follows {t[i]} s")
    return t, pos


def timed_segments(
    times: np.ndarray,
    positions: np.ndarray,
    velocities: np.ndarray | None,
    accelerations: np.ndarray | None,
) -> list[Segment]:
    """The N-1 segments between consecutive timed points, interpolated as ros2_controllers' JTC does.

    Positions only → linear; with velocities → cubic Hermite; with velocities and accelerations → quintic.
    """
    t, pos = _timed_points(times, positions)
    vel = _points("velocities", velocities, pos.shape)
    acc = _points("accelerations", accelerations, pos.shape)
    if acc is not None and vel is None:
        raise ValueError("accelerations need velocities too (quintic interpolation uses both)")
    segments: list[Segment] = []
    for i in range(len(t) - 1):
        duration = float(t[i + 1] - t[i])
        if vel is None:
            segments.append(PolynomialSegment.linear(pos[i], pos[i + 1], duration))
        elif acc is None:
            segments.append(PolynomialSegment.cubic(pos[i], vel[i], pos[i + 1], vel[i + 1], duration))
        else:
            segments.append(
                PolynomialSegment.quintic(pos[i], vel[i], acc[i], pos[i + 1], vel[i + 1], acc[i + 1], duration)
            )
    return segments


def timed_table(
    times: np.ndarray,
    positions: np.ndarray,
    velocities: np.ndarray | None,
    accelerations: np.ndarray | None,
) -> SegmentTable | None:
    """:func:`timed_segments` as one table placed at ``times[0]`` (None for a single point): the same coefficients,
    computed for all segments at once, so a goal of 10 000 points is prepared in milliseconds and crosses to the
    cycle process as a few arrays."""
    t, pos = _timed_points(times, positions)
    vel = _points("velocities", velocities, pos.shape)
    acc = _points("accelerations", accelerations, pos.shape)
    if acc is not None and vel is None:
        raise ValueError("accelerations need velocities too (quintic interpolation uses both)")
    if len(t) < 2:
        return None
    durations = t[1:] - t[:-1]
    T = durations[:, None]
    if vel is None:
        coefficients = linear_coefficients(pos[:-1], pos[1:], T)
    elif acc is None:
        coefficients = cubic_coefficients(pos[:-1], vel[:-1], pos[1:], vel[1:], T)
    else:
        coefficients = quintic_coefficients(pos[:-1], vel[:-1], acc[:-1], pos[1:], vel[1:], acc[1:], T)
    return SegmentTable.polynomials(coefficients, durations, start=float(t[0]))


def point_velocities(times: np.ndarray, positions: np.ndarray, velocities: np.ndarray | None) -> np.ndarray:
    """Velocity at each point (N, J): the given ones, else the slope of the following linear segment.

    The splice into point 0 ends with this velocity, so the handover into the first segment has no velocity
    step; the last point gets 0 because the trajectory holds there.
    """
    t, pos = _timed_points(times, positions)
    vel = _points("velocities", velocities, pos.shape)
    if vel is not None:
        return vel.copy()
    out = np.zeros_like(pos)
    out[:-1] = np.diff(pos, axis=0) / np.diff(t)[:, None]
    return out


def splice(
    p: np.ndarray,
    v: np.ndarray,
    a: np.ndarray,
    target_p: np.ndarray,
    target_v: np.ndarray,
    target_a: np.ndarray,
    duration: float,
) -> PolynomialSegment:
    """A quintic from the current desired state to a point, so a new goal never jumps in p, v or a."""
    return PolynomialSegment.quintic(p, v, a, target_p, target_v, target_a, duration)
