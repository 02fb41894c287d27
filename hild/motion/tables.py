"""Segment tables: a run of back-to-back segments held as a few contiguous arrays, the form a long plan crosses in.

A goal crosses to the cycle process as a pickle that the cycle unpickles when it polls its queue. As a list of
segment objects, a goal of 10 000 points took 200–450 ms to unpickle (each segment an object with its own arrays
and derived matrices), which the cycle must never pay. As a table it is a handful of arrays, so unpickling creates
the same few Python objects whatever the length, and the cycle samples straight from the arrays: a cursor that
moves forward with time finds the row (``np.searchsorted`` after a jump) and only the row it enters is unpacked.
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
        self._last_duration = float(durations[-1])
        self._cursor = 0
        j = self.joints
        self._stacked = np.zeros((3 * j, DEGREE + 1))  # the polynomial row the cursor last entered, stacked
        self._powers = np.ones(DEGREE + 1)
        self._out = np.empty(3 * j)
        self._p, self._v, self._a = self._out[:j], self._out[j : 2 * j], self._out[2 * j :]
        self._polynomial = -1  # which coefficient row is in _stacked
        self._leg = -1  # which phase leg is in _leg_rows
        self._leg_rows: list[Any] = []
        self._leg_cursor: list[int] = []

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
    def _row(self, t: float) -> int:
        """The last row starting at or before ``t`` (0 before the first), as ``bisect_right`` over the starts.

        Time moves forward, so the answer is the current row or the next one; anything else (a jump, rows of
        zero length) is a binary search."""
        starts, k, last = self.starts, self._cursor, self._n - 1
        if starts[k] <= t:
            if k == last or t < starts[k + 1]:
                return k
            if k + 1 == last or t < starts[k + 2]:
                self._cursor = k + 1
                return k + 1
        k = max(int(np.searchsorted(starts, t, side="right")) - 1, 0)
        self._cursor = k
        return k

    def sample(self, t: float, p: np.ndarray, v: np.ndarray, a: np.ndarray) -> None:
        """p, v, a at ``t`` on the trajectory's clock; before the first row its start, after the last its end."""
        if t >= self.end:
            i, tau = self._n - 1, self._last_duration  # the last row at its very end, as its segment would be
            self._cursor = i
        else:
            i = self._row(t)
            x, d = t - self.starts.item(i), self.durations.item(i)
            tau = 0.0 if x <= 0.0 else (d if x >= d else x)
        r = self.rows.item(i)
        if self.kinds.item(i) == POLYNOMIAL:
            if r != self._polynomial:
                stack_derivatives(self.coefficients[r], self._stacked)
                self._polynomial = r
            evaluate_stacked(self._stacked, tau, self._powers, self._out)
            p[:] = self._p
            v[:] = self._v
            a[:] = self._a
            return
        if r != self._leg:  # a leg's phases become Python floats once, when the cursor enters it
            self._leg_rows = self.phases[:, self.spans.item(r) : self.spans.item(r + 1)].tolist()
            self._leg_cursor = [0] * self.joints
            self._leg = r
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
