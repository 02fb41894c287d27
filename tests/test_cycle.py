"""The cycle thread: sim-clock stepping, statistics, and a clean stop that releases the hardware."""

from __future__ import annotations

import time
from collections.abc import Callable

from hild.config.model import RealtimeSection
from hild.cycle.engine import Engine
from hild.cycle.pacing import CycleThread


def test_sim_clock_steps_exactly_and_stop_releases_hardware(make_engine: Callable[..., Engine]) -> None:
    engine = make_engine()
    stamps: list[float] = []
    step = engine.step
    engine.step = lambda t, dt: (stamps.append(t), step(t, dt))  # type: ignore[method-assign]
    cycle = CycleThread(engine, "sim", 0.0, RealtimeSection())
    cycle.start()
    deadline = time.monotonic() + 30
    while len(stamps) < 2000 and time.monotonic() < deadline:
        time.sleep(0.01)
    cycle.stop()
    cycle.join(10)
    assert not cycle.is_alive() and cycle.error is None
    k = min(len(stamps), 2000)
    assert k == 2000
    assert [round(t / engine.period) for t in stamps[:k]] == list(range(1, k + 1))
    assert all(abs(t - n * engine.period) < 1e-9 for n, t in enumerate(stamps[:k], start=1))
    summary = engine.stats.summary()
    assert summary["cycles"] >= 2000 and summary["overruns"] == 0
    mock = engine.hardware[0].component
    assert not mock.enabled  # deactivated on stop
    assert engine.hardware[0].lifecycle == "unconfigured"


def test_wall_clock_never_runs_faster_than_the_rate(make_engine: Callable[..., Engine]) -> None:
    """Deadlines are absolute and missed periods are skipped: however the machine behaves, the cycle never bursts."""
    engine = make_engine()
    cycle = CycleThread(engine, "wall", 1.0, RealtimeSection())
    started = time.perf_counter()
    cycle.start()
    while engine.stats.summary()["cycles"] < 50:
        time.sleep(0.01)
    cycle.stop()
    cycle.join(10)
    elapsed = time.perf_counter() - started
    cycles = engine.stats.summary()["cycles"]
    assert 50 <= cycles <= elapsed * engine.update_rate + 2
    # The clock controllers see is measured, never ahead of real time (stop adds one final hold cycle).
    assert 0.0 < engine.t <= elapsed + engine.period


class SlowTap:
    """A telemetry tap that takes 3 ms and notes when the cycle's hardware writes were done."""

    def __init__(self, engine: Engine) -> None:
        self.engine = engine
        self.calls: list[tuple[int, int, int]] = []  # (tick, write_done_ns, called at)

    def record(self, t: float, tick: int, *_: object) -> None:
        self.calls.append((tick, self.engine.write_done_ns, time.perf_counter_ns()))
        time.sleep(0.003)


def test_the_tap_runs_after_the_writes_and_counts_toward_overruns_not_the_duration(
    make_engine: Callable[..., Engine],
) -> None:
    engine = make_engine()  # 500 Hz: a period of 2 ms, shorter than the tap
    tap = engine.tap = SlowTap(engine)
    cycle = CycleThread(engine, "wall", 1.0, RealtimeSection())
    cycle.start()
    deadline = time.monotonic() + 10
    while len(tap.calls) < 20 and time.monotonic() < deadline:
        time.sleep(0.01)
    cycle.stop()
    cycle.join(10)
    ticks = [tick for tick, _, _ in tap.calls]
    assert len(ticks) >= 20 and ticks == list(range(ticks[0], ticks[0] + len(ticks)))
    assert all(0 < done <= called for _, done, called in tap.calls)  # this cycle's writes, done before the tap
    summary = engine.stats.summary()
    assert summary["duration_us"]["p99"] < 3000  # wake → writes done: the 3 ms tap is not in it …
    assert summary["overruns"] >= 10  # … but every step it lengthens past the deadline is an overrun
