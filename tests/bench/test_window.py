"""Measurement windows read from LoopStats without the cycle's help: counts noted at open, slots copied out of the
rolling arrays, cycles the arrays no longer hold counted and said. Synthetic records only, no timing."""

from __future__ import annotations

import numpy as np
import pytest

from hild.bench.window import (
    ClockLag,
    StatsWindow,
    clock_lag_ns,
    lag_at,
    overwritten,
    plan_copy,
    ring_slots,
    stall_history,
    window_note,
)
from hild.crossing.stats import LoopStats, stats_bytes


def record(stats: LoopStats, first: int, n: int, overrun_every: int = 0) -> None:
    """Cycles ``first … first + n − 1``: duration = 1000·k ns, period error = k ns."""
    for k in range(first, first + n):
        stats.record(1000 * k, k, bool(overrun_every) and k % overrun_every == 0)


def test_ring_slots_copies_counts_in_order_across_the_wrap() -> None:
    ring = np.array([10, 11, 12, 3, 4, 5, 6, 7, 8, 9])  # counts 3 … 12 of a ring of 10
    assert ring_slots(ring, 5, 9).tolist() == [5, 6, 7, 8]
    assert ring_slots(ring, 8, 13).tolist() == [8, 9, 10, 11, 12]
    assert ring_slots(ring, 3, 13).tolist() == list(range(3, 13))
    assert ring_slots(ring, 7, 7).size == 0
    copy = ring_slots(ring, 4, 6)
    copy[0] = -1
    assert ring[4] == 4  # a copy, not a view the writer changes under the reader
    with pytest.raises(ValueError):
        ring_slots(ring, 0, 11)


def test_plan_copy_keeps_at_most_one_ring_and_counts_the_rest_lost() -> None:
    assert plan_copy(100, 105, 10) == (100, 0)
    assert plan_copy(100, 110, 10) == (100, 0)
    assert plan_copy(100, 125, 10) == (115, 15)


def test_overwritten_counts_the_copied_slots_a_later_count_reused() -> None:
    assert overwritten(begin=100, after=110, size=10) == 0
    assert overwritten(begin=100, after=113, size=10) == 3
    assert overwritten(begin=100, after=105, size=10) == 0


def test_a_window_holds_exactly_the_cycles_recorded_between_open_and_close() -> None:
    stats = LoopStats(window=10)
    record(stats, 0, 25, overrun_every=7)  # before the window: not counted
    window = StatsWindow(stats)
    window.open()
    record(stats, 25, 6, overrun_every=7)  # 28 is the window's one overrun
    w = window.close()
    assert w["cycles"] == 6 and w["overruns"] == 1 and w["lost"] == 0 and not w["restarted"]
    assert w["duration_ns"].tolist() == [1000 * k for k in range(25, 31)]
    assert w["period_error_ns"].tolist() == list(range(25, 31))
    assert window_note(w["cycles"], w["lost"], w["restarted"]) is None


def test_takes_during_the_window_keep_more_cycles_than_the_arrays_hold() -> None:
    stats = LoopStats(window=10)
    window = StatsWindow(stats)
    window.open()
    for block in range(4):
        record(stats, 8 * block, 8)
        window.take()
    w = window.close()
    assert w["cycles"] == 32 and w["lost"] == 0
    assert w["period_error_ns"].tolist() == list(range(32))


def test_more_cycles_than_the_arrays_hold_between_two_looks_are_said_lost() -> None:
    stats = LoopStats(window=10)
    record(stats, 0, 3)
    window = StatsWindow(stats)
    window.open()
    record(stats, 3, 25)
    w = window.close()
    assert w["cycles"] == 25 and w["lost"] == 15
    assert w["period_error_ns"].tolist() == list(range(18, 28))  # the last ten, the ones still there
    note = window_note(w["cycles"], w["lost"], w["restarted"])
    assert note is not None and "15 of 25 cycles were overwritten" in note


def test_a_reset_during_the_window_is_said_and_the_window_counts_from_it() -> None:
    stats = LoopStats(window=10)
    record(stats, 0, 8)
    window = StatsWindow(stats)
    window.open()
    record(stats, 8, 4)
    stats.reset()
    record(stats, 100, 3)
    w = window.close()
    assert w["restarted"] and w["cycles"] == 3 and w["period_error_ns"].tolist() == [100, 101, 102]
    assert "reset during the window" in str(window_note(w["cycles"], w["lost"], w["restarted"]))


def test_the_window_reads_statistics_another_object_writes_into_shared_memory() -> None:
    buffer = memoryview(bytearray(stats_bytes(10)))
    writer = LoopStats(10, buffer=buffer)  # the cycle process's view of the cell
    reader = LoopStats(10, buffer=buffer)  # the daemon's view: it never records
    record(writer, 0, 5)
    window = StatsWindow(reader)
    window.open()
    record(writer, 5, 7, overrun_every=3)
    w = window.close()
    assert w["cycles"] == 7 and w["overruns"] == 2  # 6, 9
    assert w["duration_ns"].tolist() == [1000 * k for k in range(5, 12)]


class RacingRing:
    """A rolling window whose count moves on by ``step`` each time it is read: the writer racing the copy."""

    def __init__(self, size: int, count: int, step: int) -> None:
        self.values = np.arange(size, dtype=np.int64)
        self._count, self.step = count, step

    @property
    def count(self) -> int:
        now = self._count
        self._count += self.step
        return now


class RacingStats:
    def __init__(self, size: int, count: int, step: int) -> None:
        self.duration = RacingRing(size, count, step)
        self.period_error = RacingRing(size, count, step)
        self.overruns = 0


def test_slots_overwritten_while_they_were_copied_are_dropped_and_counted() -> None:
    stats = RacingStats(size=10, count=0, step=6)
    window = StatsWindow(stats)  # type: ignore[arg-type]
    window.open()  # reads count 0 (each ring once)
    window.read_to = 0
    w = window.close()  # sees 6, copies counts 0 … 5; after the copy the writer is at 12: counts 0, 1 reused
    assert w["lost"] == 2 and len(w["duration_ns"]) == 4


def test_the_control_clocks_lag_is_the_part_of_each_stall_beyond_two_periods() -> None:
    period = 1_000_000
    errors = np.array([3_000, 999_999, 1_000_000, 1_500_000, 40_000_000, 2_000])  # Δwake: …, 2.5 T, 41 T
    assert clock_lag_ns(errors, period) == 500_000 + 39_000_000
    assert clock_lag_ns(np.array([], dtype=np.int64), period) == 0


def test_clock_lag_reads_every_period_error_from_the_first_cycle() -> None:
    stats = LoopStats(window=10)
    for e in (0, 2_500_000, 0, 0):  # a stall of 3.5 periods before anybody looked: 1.5 periods lost
        stats.record(100, e, False)
    lag = ClockLag(stats, 1_000_000)
    assert lag.take() == 1_500_000 and lag.certain
    for _ in range(25):  # more than the ring holds between two looks: a stall there could have been missed
        stats.record(100, 0, False)
    assert lag.take() == 1_500_000 and not lag.certain


def test_each_stall_is_keyed_by_the_control_time_of_its_cycle() -> None:
    period = 1_000_000
    # cycles woke at 10, 11, 12, 15.5 (a stall: 3.5 T, lag +1.5 T), 16.5, 17.5 ms on the cycle clock
    errors = np.array([0, 0, 0, 2_500_000, 0, 0])
    (entry,) = stall_history(errors, period, last_wake_ns=17_500_000, lag_before_ns=200_000)
    assert entry == (15_500_000 - 1_700_000, 1_700_000)  # that cycle's stamp, and the lag from it on
    assert lag_at([(0.0138, 1_700_000)], 0.0137) == 0 and lag_at([(0.0138, 1_700_000)], 0.0138) == 1_700_000


def test_clock_lag_keeps_a_history_when_given_the_last_wake() -> None:
    stats = LoopStats(window=10)
    for e in (0, 0, 1_500_000, 0):
        stats.record(100, e, False)
    lag = ClockLag(stats, 1_000_000)
    assert lag.take(last_wake_ns=6_500_000) == 500_000
    assert lag.history == [(0.005, 500_000)]  # woke at 5.5 ms, stamped 5.0 ms
