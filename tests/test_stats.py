"""Loop statistics: counters are always current; percentiles may be reused by a caller polled fast."""

import numpy as np
import pytest

from hild.crossing.stats import LoopStats, percentiles


def _fill(stats: LoopStats, duration_ns: int, count: int) -> None:
    for _ in range(count):
        stats.record(duration_ns, 0, False)


def test_percentiles_over_the_window() -> None:
    stats = LoopStats(window=100)
    _fill(stats, 50_000, 99)
    stats.record(900_000, 0, True)
    summary = stats.summary()
    assert summary["cycles"] == 100 and summary["overruns"] == 1
    assert summary["duration_us"] == {"p50": 50.0, "p99": 58.5, "p999": 815.9, "max": 900.0}


def test_max_age_reuses_percentiles_but_never_counters() -> None:
    stats = LoopStats(window=100)
    _fill(stats, 50_000, 100)
    first = stats.summary(max_age=60.0)
    _fill(stats, 400_000, 100)  # the whole window is now 400 µs
    cached = stats.summary(max_age=60.0)
    assert cached["cycles"] == 200  # counters are current
    assert cached["duration_us"] == first["duration_us"]  # percentiles reused within max_age
    fresh = stats.summary()  # max_age 0: recomputed
    assert fresh["duration_us"]["p50"] == 400.0


def test_reset_forgets_cached_percentiles() -> None:
    stats = LoopStats(window=100)
    _fill(stats, 50_000, 100)
    stats.summary(max_age=60.0)
    stats.reset()
    _fill(stats, 70_000, 10)
    assert stats.summary(max_age=60.0)["duration_us"]["p50"] == 70.0


def test_percentiles_of_known_values_in_the_unit_asked_for() -> None:
    one_to_a_thousand_us = np.arange(1, 1001) * 1000  # ns
    figures = percentiles(one_to_a_thousand_us, "ns")
    assert figures == {"p50": 500.5, "p99": 990.0, "p999": 999.0, "max": 1000.0}  # numpy's linear interpolation
    assert percentiles(one_to_a_thousand_us, "ns", to="ms", digits=3) == {
        "p50": 0.5,
        "p99": 0.99,
        "p999": 0.999,
        "max": 1.0,
    }


@pytest.mark.parametrize(("scale", "unit"), [(1.0, "s"), (1e3, "ms"), (1e6, "us"), (1e9, "ns")])
def test_the_same_durations_give_the_same_figures_whatever_unit_they_come_in(scale: float, unit: str) -> None:
    seconds = [0.000_010, 0.000_020, 0.000_030, 0.000_250]
    assert percentiles([v * scale for v in seconds], unit) == percentiles(seconds, "s")  # type: ignore[arg-type]
    assert percentiles(seconds, "s")["max"] == 250.0


def test_percentiles_of_nothing_are_zeros() -> None:
    assert percentiles([], "s") == {"p50": 0.0, "p99": 0.0, "p999": 0.0, "max": 0.0}


def test_the_loop_summary_keeps_the_largest_value_since_reset_even_once_the_window_has_moved_on() -> None:
    stats = LoopStats(window=10)
    stats.record(900_000, 0, False)
    _fill(stats, 50_000, 10)  # the 900 µs cycle is out of the window
    assert stats.summary()["duration_us"] == {"p50": 50.0, "p99": 50.0, "p999": 50.0, "max": 900.0}
