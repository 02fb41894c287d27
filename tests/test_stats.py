"""Loop statistics: counters are always current; percentiles may be reused by a caller polled fast."""

from hild.stats import LoopStats


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
