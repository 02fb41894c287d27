"""Segment tables: a run of back-to-back segments held as a few contiguous arrays, the form a long plan crosses in.

A goal crosses to the cycle process as a pickle that the cycle unpickles when it polls its queue. As a list of
segment objects, a goal of 10 000 points took 200–450 ms to unpickle (each segment an object with its own arrays
and derived matrices), which the cycle must never pay. As a table it is a handful of arrays, so unpickling creates
the same few Python objects whatever the length, and the cycle samples straight from the arrays: a cursor that
moves forward with time finds the row (``np.searchsorted`` after a jump), and only rows it reaches are unpacked
(polynomials a chunk at a time, a ruckig leg's phases when it enters the leg).
A table samples the numbers its segment objects would: the same coefficients and phases through the same
arithmetic, at the same per-row times.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from hild.motion.segments import (
    DEGREE,
    HoldSegment,
    PhaseSegment,
    PolynomialSegment,
    RuckigSegment,
    Segment,
    _phase_extrema,
    evaluate_stacked,
    polynomial_bounds,
    sample_phases,
    stack_derivatives,
)

POLYNOMIAL = 0  # the row is coefficients[rows[i]] (J, 6): a PolynomialSegment, or a HoldSegment lasting 0 s
PHASES = 1  # the row is phases[:, spans[r] : spans[r + 1]] (J, P, 6) for r = rows[i]: a ruckig leg (PhaseSegment)
_PHASE_COLUMNS = 6  # start, p0, v0, a0, jerk, length
CHUNK = 64  # polynomial rows stacked with their derivatives at once: one numpy call per chunk, not per row


def _accumulate(start: float, durations: np.ndarray) -> np.ndarray:
    """Row start times, summed one after the other from ``start`` as :class:`~hild.motion.trajectory.Trajectory`
    sums its segments' durations (``np.cumsum`` adds sequentially), so a row starts at the very float it would as a
    segment object."""
    return np.cumsum(np.concatenate(([float(start)], durations[:-1])))


class SegmentTable:
    """Rows played back to back: row ``i`` starts at ``starts[i]`` on the clock of the trajectory that plays it and
    lasts ``durations[i]``.

    ``sample`` takes that clock's time rather than a time from the table's start, so each row is sampled at
    ``t - starts[i]`` exactly as a segment object placed there would be. A table placed elsewhere is re-placed
    with :meth:`placed` (O(rows), in numpy). Like a segment, a table keeps sampling state (its cursor and the
    unpacked row): one thread samples it. ``__init__`` checks nothing, so that unpickling stays O(1); the
    constructors below check.
    """

    def __init__(
        self,
        starts: np.ndarray,
        durations: np.ndarray,
        kinds: np.ndarray,
        rows: np.ndarray,
        coefficients: np.ndarray,
        phases: np.ndarray,
        spans: np.ndarray,
    ) -> None:
        for arr in (starts, durations, kinds, rows, coefficients, phases, spans):
            arr.flags.writeable = False
        self.starts, self.durations, self.kinds, self.rows = starts, durations, kinds, rows
        self.coefficients, self.phases, self.spans = coefficients, phases, spans
        self.joints = int(coefficients.shape[1])
        self._n = len(starts)
        self.start = float(starts[0])
        self.end = float(starts[-1] + durations[-1])  # the sum continued, as a trajectory would
        j = self.joints
        # Polynomial rows from _chunk_base on, stacked with their derivatives as PolynomialSegment stacks its own.
        self._chunk = np.zeros((min(CHUNK, len(coefficients)), 3 * j, DEGREE + 1))
        self._chunk_base = -len(self._chunk) - 1
        self._stacked = np.zeros((3 * j, DEGREE + 1))  # the current row's: a view into _chunk once one is entered
        self._powers = np.ones(DEGREE + 1)
        self._out = np.empty(3 * j)
        self._p, self._v, self._a = self._out[:j], self._out[j : 2 * j], self._out[2 * j :]
        self._leg = -1  # which phase leg is in _leg_rows
        self._leg_rows: list[Any] = []
        self._leg_cursor: list[int] = []
        self._cursor, self._from, self._until, self._start, self._duration, self._kind = 0, 0.0, 0.0, 0.0, 0.0, 0
        self._enter(0)

    def __reduce__(self) -> tuple[Any, ...]:
        """Crosses as its seven arrays: O(1) Python objects whatever the number of rows."""
        arrays = (self.starts, self.durations, self.kinds, self.rows, self.coefficients, self.phases, self.spans)
        return SegmentTable, arrays

    def __len__(self) -> int:
        return self._n

    # ---- constructors (off the cycle) -------------------------------------------------------------------------
    @classmethod
    def polynomials(cls, coefficients: np.ndarray, durations: np.ndarray, start: float = 0.0) -> SegmentTable:
        """Polynomial rows (coefficients (N, J, 6), durations (N,) ≥ 0) placed at ``start``."""
        coeffs = np.array(coefficients, dtype=np.float64)  # private copies: the table makes them read-only
        d = np.array(durations, dtype=np.float64)
        if coeffs.ndim != 3 or coeffs.shape[2] != DEGREE + 1 or d.shape != coeffs.shape[:1] or not len(d):
            raise ValueError(f"expected coefficients (N >= 1, J, {DEGREE + 1}) and durations (N,); found "
                             f"{coeffs.shape} and {d.shape}")  # fmt: skip
        if not (np.isfinite(coeffs).all() and np.isfinite(d).all() and (d >= 0.0).all()):
            raise ValueError("coefficients must be finite and durations finite and >= 0")
        n, joints = len(d), coeffs.shape[1]
        return cls(
            _accumulate(start, d),
            d,
            np.full(n, POLYNOMIAL, dtype=np.int8),
            np.arange(n, dtype=np.int64),
            coeffs,
            np.zeros((joints, 0, _PHASE_COLUMNS)),
            np.zeros(1, dtype=np.int64),
        )

    @classmethod
    def of(cls, segments: Sequence[Segment], joints: int, start: float = 0.0) -> SegmentTable:
        """The table of hild's own segments, placed at ``start``: polynomials (a hold is one lasting 0 s, which
        samples its position exactly) and ruckig legs as their phase tables, as they cross on their own."""
        if not segments:
            raise ValueError("a segment table needs at least one segment")
        kinds, rows, durations = [], [], []
        coefficients: list[np.ndarray] = []
        legs: list[np.ndarray] = []
        for i, segment in enumerate(segments):
            if getattr(segment, "joints", joints) != joints:
                raise ValueError(f"segment {i} has {getattr(segment, 'joints', '?')} joints, not {joints}")
            if isinstance(segment, PolynomialSegment | HoldSegment):
                if isinstance(segment, HoldSegment):
                    coeffs = np.zeros((joints, DEGREE + 1))
                    coeffs[:, 0] = segment.position
                else:
                    coeffs = segment.coefficients
                kinds.append(POLYNOMIAL)
                rows.append(len(coefficients))
                coefficients.append(coeffs)
            elif isinstance(segment, PhaseSegment | RuckigSegment):
                table = (
                    segment.table if isinstance(segment, PhaseSegment) else PhaseSegment.of(segment.trajectory).table
                )
                kinds.append(PHASES)
                rows.append(len(legs))
                legs.append(table)
            else:
                raise TypeError(f"segment {i}: a table holds hild's own segments, not {type(segment).__name__}")
            durations.append(float(segment.duration))
        d = np.array(durations)
        return cls(
            _accumulate(start, d),
            d,
            np.array(kinds, dtype=np.int8),
            np.array(rows, dtype=np.int64),
            np.array(coefficients) if coefficients else np.zeros((0, joints, DEGREE + 1)),
            np.concatenate(legs, axis=1) if legs else np.zeros((joints, 0, _PHASE_COLUMNS)),
            np.cumsum([0, *(leg.shape[1] for leg in legs)], dtype=np.int64),
        )

    def placed(self, start: float) -> SegmentTable:
        """The same rows starting at ``start`` (start times summed anew: O(rows) in numpy; the data is shared)."""
        return SegmentTable(_accumulate(start, self.durations), self.durations, self.kinds, self.rows, *self._data())

    def rows_from(self, k: int) -> SegmentTable:
        """The rows from ``k`` on, where they are (views: O(1)). ``k`` must leave at least one row."""
        if not 0 <= k < self._n:
            raise ValueError(f"rows_from({k}) of a table of {self._n} rows")
        return SegmentTable(self.starts[k:], self.durations[k:], self.kinds[k:], self.rows[k:], *self._data())

    def _data(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.coefficients, self.phases, self.spans

    # ---- cycle side -------------------------------------------------------------------------------------------
    def _seek(self, t: float) -> None:
        """Enter the last row starting at or before ``t`` (row 0 before the first), as ``bisect_right`` would find.

        Time moves forward, so that is the next row; anything else (a jump, rows of zero length) is a binary
        search."""
        starts, k, n = self.starts, self._cursor + 1, self._n
        if not (k < n and starts[k] <= t and (k + 1 == n or t < starts[k + 1])):
            k = max(int(np.searchsorted(starts, t, side="right")) - 1, 0)
        self._enter(k)

    def _enter(self, k: int) -> None:
        """Make row ``k`` current: its times as Python floats, its data unpacked (once per row, not per cycle)."""
        n = self._n
        self._cursor = k
        self._from = self.starts.item(k) if k > 0 else -np.inf  # the row is current while _from <= t < _until
        self._until = self.starts.item(k + 1) if k + 1 < n else np.inf
        self._start, self._duration = self.starts.item(k), self.durations.item(k)
        self._kind = self.kinds.item(k)
        r = self.rows.item(k)
        if self._kind == POLYNOMIAL:
            if not 0 <= r - self._chunk_base < len(self._chunk):
                base = min(r, len(self.coefficients) - len(self._chunk))
                stack_derivatives(self.coefficients[base : base + len(self._chunk)], self._chunk)
                self._chunk_base = base
            self._stacked = self._chunk[r - self._chunk_base]
        elif r != self._leg:
            self._leg_rows = self.phases[:, self.spans.item(r) : self.spans.item(r + 1)].tolist()
            self._leg_cursor = [0] * self.joints
            self._leg = r

    def sample(self, t: float, p: np.ndarray, v: np.ndarray, a: np.ndarray) -> None:
        """p, v, a at ``t`` on the trajectory's clock; before the first row its start, after the last its end."""
        if t >= self.end:
            if self._cursor != self._n - 1:
                self._enter(self._n - 1)
            tau = self._duration  # the last row at its very end, as its segment would be sampled there
        else:
            if not (self._from <= t < self._until):
                self._seek(t)
            x, d = t - self._start, self._duration
            tau = 0.0 if x <= 0.0 else (d if x >= d else x)
        if self._kind == POLYNOMIAL:
            evaluate_stacked(self._stacked, tau, self._powers, self._out)
            p[:] = self._p
            v[:] = self._v
            a[:] = self._a
        else:
            sample_phases(self._leg_rows, self._leg_cursor, tau, p, v, a)

    # ---- off the cycle ------------------------------------------------------------------------------------------
    def position_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-joint min and max position over all rows."""
        lo, hi = np.full(self.joints, np.inf), np.full(self.joints, -np.inf)
        polynomial = self.kinds == POLYNOMIAL
        if polynomial.any():
            lo, hi = polynomial_bounds(self.coefficients[self.rows[polynomial]], self.durations[polynomial])
        for r in self.rows[~polynomial].tolist():
            # Padding rows repeat a joint's last phase and a joint that never moves has one row of length 0 at its
            # position, so every row's extrema are on the curve; together they include the leg's start and end.
            for j, joint in enumerate(self.phases[:, self.spans[r] : self.spans[r + 1]].tolist()):
                for _, p0, v0, a0, jerk, length in joint:
                    low, high = _phase_extrema(p0, v0, a0, jerk, length)
                    lo[j], hi[j] = min(lo[j], low), max(hi[j], high)
        return lo, hi
