"""One measurement of an in-process cycle: warm up, restart the loop statistics, count a window, return it.

Every in-process measurement (the bench's empty-thread floor, the tools) follows this recipe, so it lives here once,
with :func:`start_engine` (a config's engine as the daemon starts it), :func:`lockstep_engine` (the same on the sim
clock, as fast as it goes) and :func:`cycle_running` (the cycle thread as the daemon runs it, always stopped). The
statistics are restarted *on the cycle thread* (``submit``), between two cycles, so no record races the reset; the
window is then read without the cycle's help (:class:`hild.bench.window.StatsWindow`), copied every ``take_every``
seconds so a window may be longer than the rolling arrays.
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from hild.bench.report import loop_figures
from hild.bench.window import DRAIN_S, StatsWindow, recorded
from hild.config import load_config
from hild.config.loader import LoadedConfig
from hild.config.model import RealtimeSection
from hild.crossing.stats import LoopStats
from hild.cycle.engine import Engine
from hild.cycle.pacing import CycleThread
from hild.cycle.realtime import apply_process_settings, freeze_heap, thaw_heap

RESTART_TIMEOUT = 5.0  # s for the cycle thread to take the restart
POLL_S = 0.002  # s between two looks at the count while waiting for a number of cycles


class Measured(Protocol):
    """What a measured engine offers: its loop statistics and a way to run an action on its cycle thread."""

    stats: LoopStats

    def submit(self, action: Callable[[], Any]) -> Future[Any]: ...


@dataclass(frozen=True)
class Window:
    """The cycles of one window: counts from the cycle, every duration and period error it was possible to copy."""

    cycles: int
    overruns: int  # counted up to the moment the window was closed (a few cycles past ``cycles`` at most)
    duration_ns: np.ndarray
    period_error_ns: np.ndarray
    lost: int  # cycles overwritten in the rolling arrays before they were copied (not in the arrays)
    warmup_cycles: int  # cycles run before the window opened
    seconds: float

    def figures(self) -> dict[str, Any]:
        """The bench's loop figures of this window (``hild.bench.report.loop_figures``)."""
        return loop_figures(self.cycles, self.overruns, self.duration_ns, self.period_error_ns)


def restart(stats: LoopStats, also: Callable[[], None] | None = None) -> Callable[[], int]:
    """An action for the cycle thread: reset ``stats`` (and run ``also``); returns how many cycles they had
    counted."""

    def action() -> int:
        before = stats.cycles
        stats.reset()
        if also is not None:
            also()
        return before

    return action


def measure_window(
    engine: Measured,
    *,
    warmup: float,
    seconds: float | None = None,
    cycles: int | None = None,
    take_every: float = DRAIN_S,
    also_restart: Callable[[], None] | None = None,
) -> Window:
    """Let a running cycle warm up for ``warmup`` s, restart its statistics, then count ``seconds`` of cycles or
    exactly ``cycles`` cycles (give one of the two). ``also_restart``: the caller's own counters, restarted on the
    cycle thread together with the statistics."""
    if (seconds is None) == (cycles is None):
        raise ValueError("measure a window of seconds or of cycles, one of the two")
    time.sleep(warmup)
    warmup_cycles = int(engine.submit(restart(engine.stats, also_restart)).result(RESTART_TIMEOUT))
    window = StatsWindow(engine.stats)
    window.open(from_start=True)
    started = time.monotonic()
    end = started + seconds if seconds is not None else math.inf
    next_take = started + take_every
    while time.monotonic() < end and (cycles is None or recorded(engine.stats) < cycles):
        now = time.monotonic()
        if now >= next_take:
            window.take()
            next_take = now + take_every
        time.sleep(POLL_S if cycles is not None else max(0.0, min(next_take, end) - now))
    closed = window.close()
    elapsed = time.monotonic() - started
    duration, period_error = closed["duration_ns"], closed["period_error_ns"]
    counted = closed["cycles"] if cycles is None else cycles
    return Window(
        cycles=counted,
        overruns=closed["overruns"],
        duration_ns=duration[:counted],
        period_error_ns=period_error[:counted],
        lost=closed["lost"],
        warmup_cycles=warmup_cycles,
        seconds=elapsed,
    )


class RateRefused(ValueError):
    """The config cannot run at the rate asked for; the reason is reported instead of numbers."""


def lockstep_engine(config: Path, rate: float | None = None) -> Engine:
    """The config's engine on the sim clock as fast as it goes (lockstep), optionally at another update rate,
    started. At another rate each twin's ``substeps`` is scaled so its physics step stays what the config chose."""
    loaded = load_config(config)
    cfg = loaded.config
    update: dict[str, Any] = {"clock": cfg.clock.model_copy(update={"source": "sim", "real_time_factor": 0.0})}
    if rate is not None and rate != cfg.update_rate:
        try:
            type(cfg).model_validate({**cfg.model_dump(), "update_rate": rate})
        except ValueError as exc:  # pydantic's ValidationError: keep its first message, not the whole report
            errors = getattr(exc, "errors", None)
            reason = errors()[0]["msg"] if callable(errors) else str(exc)
            raise RateRefused(f"update_rate {rate:g} not allowed: {reason}") from None
        for name, params in loaded.driver_params.items():
            substeps = getattr(params, "substeps", None)
            if substeps is None:
                raise RateRefused(f"hardware {name!r} has no substeps to keep its physics step at {rate:g} Hz")
            scaled = max(1, round(substeps * cfg.update_rate / rate))
            loaded.driver_params[name] = params.model_copy(update={"substeps": scaled})
        update["update_rate"] = rate
    loaded.config = cfg.model_copy(update=update)
    engine = Engine(loaded)
    engine.start()
    return engine


def start_engine(loaded: LoadedConfig, activate: Sequence[str] = ()) -> Engine:
    """The config's engine, started with the daemon's process settings, with ``activate`` controllers active."""
    apply_process_settings(loaded.config.realtime)
    engine = Engine(loaded)
    engine.start()
    if activate:
        result = engine.switch(list(activate), [])
        if not result.ok:
            engine.stop()
            raise RuntimeError(f"cannot activate {', '.join(activate)}: {result.error}")
    return engine


@contextlib.contextmanager
def cycle_running(
    engine: Any, realtime: RealtimeSection, clock: str = "wall", real_time_factor: float = 1.0
) -> Iterator[CycleThread]:
    """A started engine on ``CycleThread`` as the daemon runs it (heap frozen first); stopped, joined and the heap
    thawed on the way out, whatever happened inside."""
    freeze_heap(realtime)
    cycle = CycleThread(engine, clock, real_time_factor, realtime)
    cycle.start()
    try:
        yield cycle
    finally:
        cycle.stop()
        cycle.join(5.0)
        thaw_heap()
