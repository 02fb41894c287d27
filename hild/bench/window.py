"""A measurement window read from the loop statistics, without the cycle's help.

``LoopStats`` keeps rolling arrays of the last ``window`` cycle durations and period errors, each with a count of
every value ever recorded; the cycle writes a slot, then bumps the count. In one-process mode the arrays are the
engine's; with the cycle in a process of its own they live in shared memory and only the cycle process writes
them. Either way the bench only reads:

* **open** notes the counts (and the overrun counter);
* **take** (every ``DRAIN_S`` while the window is open, and once more at collect) copies the slots between the
  count it read last and the count now out of the rolling arrays, so a window may be longer than the arrays;
* a copy can race the writer: slots that the cycle overwrote while they were being copied (their count is more
  than one array length behind the count read after the copy) are dropped, and counted;
* if more cycles passed between two takes than the arrays hold, the oldest are gone: the window says how many
  (``lost``) rather than pretending it saw every cycle.

The pure parts (``ring_slots``, ``plan_copy``, ``overwritten``, ``clock_lag_ns``) are what the tests check.

**The control clock's lag.** Controllers stamp their samples (joint_states) with the engine's control clock, which
stops advancing by more than ``MAX_STEP_PERIODS`` periods per cycle: after a stall it lags the cycle clock by the
stall (``hild.cycle.engine``). With the cycle in another process that lag is not in the shared region, but every stall
is in the period errors: a cycle woken more than two periods after the last has a period error e > T, and the
control clock lost e − T (a wake early by e < T cannot be told apart from one late by e, and is never a stall).
:class:`ClockLag` reads every period error from the cycle's start and sums that.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hild.crossing.stats import LoopStats

DRAIN_S = 2.0  # s between takes: far below what the arrays hold at 1 kHz (10 000 cycles = 10 s)


def ring_slots(values: np.ndarray, start: int, end: int) -> np.ndarray:
    """A copy of the values recorded as counts ``start … end − 1`` of a ring of ``len(values)`` slots
    (count k lives in slot k mod len). Needs ``0 ≤ end − start ≤ len(values)``."""
    size = len(values)
    n = end - start
    if n < 0 or n > size:
        raise ValueError(f"{n} values asked of a ring of {size}")
    if n == 0:
        return np.empty(0, dtype=values.dtype)
    first = start % size
    if first + n <= size:
        return values[first : first + n].copy()
    return np.concatenate((values[first:], values[: first + n - size]))


def plan_copy(read_to: int, end: int, size: int) -> tuple[int, int]:
    """(first count to copy, counts already lost) when ``read_to`` is the first count not yet read, ``end`` the
    count now and ``size`` the ring's length: at most the last ``size`` counts are still there."""
    if end - read_to > size:
        return end - size, end - size - read_to
    return read_to, 0


def overwritten(begin: int, after: int, size: int) -> int:
    """How many of the copied counts from ``begin`` on the writer may have overwritten during the copy, given the
    count ``after`` read once the copy was done (slot of count k is reused by count k + size)."""
    return max(0, after - size - begin)


def recorded(stats: LoopStats) -> int:
    """Counts whose duration *and* period error are both in their slots (each slot is written before its count)."""
    return min(stats.duration.count, stats.period_error.count)


@dataclass
class StatsWindow:
    """One measurement window over ``stats``; see the module docstring."""

    stats: LoopStats
    start: int = 0
    read_to: int = 0
    overruns_at_start: int = 0
    lost: int = 0
    restarted: bool = False  # the counts went backwards (somebody reset the statistics): the window is cut there
    _duration: list[np.ndarray] = field(default_factory=list)
    _period_error: list[np.ndarray] = field(default_factory=list)

    def open(self, *, from_start: bool = False) -> None:
        """Start at the count now, or (``from_start``) at the first cycle the statistics ever recorded."""
        self.overruns_at_start = 0 if from_start else self.stats.overruns
        self.start = self.read_to = 0 if from_start else recorded(self.stats)
        self.lost = 0
        self.restarted = False
        self._duration, self._period_error = [], []

    def take(self) -> tuple[np.ndarray, np.ndarray]:
        """Copy what the cycle recorded since the last take; returns (durations, period errors) of that."""
        stats = self.stats
        end = recorded(stats)
        if end < self.read_to:  # reset under us: what was recorded since is all that is left of this window
            self.restarted = True
            self.start = self.read_to = 0
            self.overruns_at_start = 0
            end = recorded(stats)
        size = len(stats.duration.values)
        begin, gone = plan_copy(self.read_to, end, size)
        duration = ring_slots(stats.duration.values, begin, end)
        period_error = ring_slots(stats.period_error.values, begin, end)
        late = min(end - begin, overwritten(begin, recorded(stats), size))
        if late:
            duration, period_error = duration[late:], period_error[late:]
        self.lost += gone + late
        self._duration.append(duration)
        self._period_error.append(period_error)
        self.read_to = end
        return duration, period_error

    def forget(self) -> None:
        """Drop the copies kept so far (counts and ``lost`` stay)."""
        self._duration, self._period_error = [], []

    def close(self) -> dict[str, Any]:
        """The window: cycles and overruns counted by the cycle, and every duration and period error copied."""
        self.take()
        duration = np.concatenate(self._duration) if self._duration else np.empty(0, np.int64)
        period_error = np.concatenate(self._period_error) if self._period_error else np.empty(0, np.int64)
        return {
            "cycles": self.read_to - self.start,
            "overruns": self.stats.overruns - self.overruns_at_start,
            "duration_ns": duration,
            "period_error_ns": period_error,
            "lost": self.lost,
            "restarted": self.restarted,
        }


def clock_lag_ns(period_error_ns: np.ndarray, period_ns: int, max_step_periods: float = 2.0) -> int:
    """How far the control clock fell behind the cycle clock over these cycles: each cycle woken Δ > k·T after
    the last (k = ``max_step_periods``) advanced it by k·T only; Δ = T + e when the period error e ≥ T."""
    stalled = np.asarray(period_error_ns, dtype=np.int64)
    threshold = round((max_step_periods - 1.0) * period_ns)
    over = stalled[stalled > threshold]
    return int((over - threshold).sum())


def stall_history(
    period_error_ns: np.ndarray, period_ns: int, last_wake_ns: int, lag_before_ns: int, max_step_periods: float = 2.0
) -> list[tuple[int, int]]:
    """(control time ns, lag ns after it) for each stall among consecutive cycles whose period errors are given,
    the last of which woke at ``last_wake_ns`` on the cycle clock. Wake times are rebuilt backwards in whole
    periods (deadlines are a grid of T): a cycle came round((T + e)/T) periods after the one before it when e ≥ T,
    else one (its ± e of lateness does not add up: the next wake's lateness takes it back)."""
    errors = np.asarray(period_error_ns, dtype=np.int64)
    threshold = round((max_step_periods - 1.0) * period_ns)
    deltas = np.where(errors >= period_ns, period_ns * np.rint((period_ns + errors) / period_ns), period_ns)
    deltas = deltas.astype(np.int64)
    wakes = last_wake_ns - (np.cumsum(deltas[::-1])[::-1] - deltas)  # wake k = last − Σ deltas after k
    lags = lag_before_ns + np.cumsum(np.where(errors > threshold, errors - threshold, 0))
    stalled = np.nonzero(errors > threshold)[0]
    return [(int(wakes[k] - lags[k]), int(lags[k])) for k in stalled]


class ClockLag:
    """The control clock's lag behind the cycle clock, from every period error since the cycle began; with the
    cycle clock's ``t`` of the last cycle read, also when each stall happened (``history``)."""

    def __init__(self, stats: LoopStats, period_ns: int, max_step_periods: float = 2.0) -> None:
        self.window = StatsWindow(stats)
        self.window.open(from_start=True)
        self.period_ns = period_ns
        self.max_step_periods = max_step_periods
        self.lag_ns = 0
        self.history: list[tuple[float, int]] = []  # (control time s, lag ns from then on)

    def take(self, last_wake_ns: int | None = None) -> int:
        """Read the new period errors; ``last_wake_ns``: the cycle clock of the last recorded cycle, for the
        history (none kept without it)."""
        _, period_error = self.window.take()
        self.window.forget()
        if last_wake_ns is not None:
            for when, lag in stall_history(
                period_error, self.period_ns, last_wake_ns, self.lag_ns, self.max_step_periods
            ):
                self.history.append((when / 1e9, lag))
        self.lag_ns += clock_lag_ns(period_error, self.period_ns, self.max_step_periods)
        return self.lag_ns

    @property
    def certain(self) -> bool:
        """False when some cycles were overwritten before they were read (a stall among them would be missed)."""
        return self.window.lost == 0 and not self.window.restarted


def lag_at(history: list[tuple[float, int]], control_t: float) -> int:
    """The lag (ns) in effect at ``control_t``, from ``history`` = [(control time, lag ns) …] in time order: the
    last entry at or before it (0 before the first)."""
    lag = 0
    for when, value in history:
        if when > control_t:
            break
        lag = value
    return lag


def window_note(cycles: int, lost: int, restarted: bool) -> str | None:
    """What a report must say about a window that did not see every cycle (None when it did)."""
    parts = []
    if lost:
        parts.append(
            f"{lost} of {cycles} cycles were overwritten in the rolling statistics before the bench read them; "
            "percentiles are over the other cycles"
        )
    if restarted:
        parts.append("the loop statistics were reset during the window; it counts from the reset")
    return "; ".join(parts) or None
