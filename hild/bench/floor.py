"""The floor: what this machine gives a Python cycle before hild adds anything, measured in the same run.

* **Empty thread**: ``hild.cycle.pacing.CycleThread`` itself — same sleep+spin pacing, same real-time settings, same
  ``LoopStats`` bookkeeping — driving an engine whose ``step`` does nothing. It runs in a child process of its own
  (``python -m hild.bench.floor``) with the daemon's process settings (switch interval, gc freeze, optional
  ``mlockall``), so the only difference from a scenario is the work inside the cycle and what shares the process.
  Lateness (wake − deadline) is recovered from the cycle clock: the wall clock's ``t`` is wake − start and every
  deadline is start + k·T, so lateness = t mod T (exact below one period, which is all but overruns).
* **Library probes** (:mod:`hild.bench.probes`): raw Zenoh on loopback, python-can's virtual bus, MuJoCo's
  step. Each is imported only when it runs, so a missing library is a line in the report, not a failed run.
"""

from __future__ import annotations

import argparse
import importlib
import json
import queue
import subprocess
import sys
import time
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any

import numpy as np

from hild.bench.measure import cycle_running, measure_window
from hild.bench.report import summarize_ns
from hild.config.model import RealtimeSection
from hild.crossing.events import EventLog
from hild.crossing.stats import LoopStats
from hild.cycle.realtime import CpuLatencyRequest, apply_process_settings, freeze_heap

PROBES = {  # the floor section's name → (module in hild.bench.probes, function)
    "zenoh": ("zenoh_loopback", "zenoh_round_trip"),
    "can_virtual": ("can_virtual", "virtual_round_trip"),
    "mj_step": ("mj_step", "mj_step"),
}
WARMUP_S = 0.5


class EmptyEngine:
    """The part of ``Engine`` that ``CycleThread`` and ``measure_window`` use, with a ``step`` that only notes its
    lateness (kept at the loop statistics' count, so it covers the same window)."""

    def __init__(self, rate: float, capacity: int) -> None:
        self.period = 1.0 / rate
        self.period_ns = round(self.period * 1e9)
        self.stats = LoopStats(window=capacity)
        self.realtime_report: dict[str, str] = {}
        self.events = EventLog()
        self.lateness = np.zeros(capacity, dtype=np.int64)
        self.write_done_ns = 0
        self._asked: queue.SimpleQueue[tuple[Callable[[], Any], Future[Any]]] = queue.SimpleQueue()

    def submit(self, action: Callable[[], Any]) -> Future[Any]:
        """Run ``action`` on the cycle thread at its next step, as ``Engine.submit`` does."""
        future: Future[Any] = Future()
        self._asked.put((action, future))
        return future

    def step(self, t: float, dt: float) -> None:
        self.write_done_ns = time.perf_counter_ns()  # nothing to write: the cycle's work ends here
        if not self._asked.empty():
            action, future = self._asked.get_nowait()
            future.set_result(action())
        self.lateness[self.stats.cycles % len(self.lateness)] = round(t * 1e9) % self.period_ns

    def stop(self) -> None:
        pass


def empty_thread(rate: float, seconds: float, realtime: RealtimeSection) -> dict[str, Any]:
    """Run the empty cycle at ``rate`` for ``seconds`` (after a short warm-up); loop figures plus lateness."""
    capacity = max(10_000, int(rate * seconds) + 1000)
    engine = EmptyEngine(rate, capacity)
    with cycle_running(engine, realtime):
        window = measure_window(engine, warmup=WARMUP_S, seconds=seconds)
    figures = window.figures()
    figures["lateness_us"] = summarize_ns(engine.lateness[: min(window.cycles, capacity)])
    figures["rate_hz"] = rate
    figures["realtime"] = dict(engine.realtime_report)
    return figures


def measure_empty_threads(rates: list[float], seconds: float, realtime: RealtimeSection) -> list[dict[str, Any]]:
    """The empty thread at each rate, in a child process with the daemon's process settings."""
    command = [
        sys.executable,
        "-m",
        "hild.bench.floor",
        "--seconds",
        str(seconds),
        "--realtime",
        realtime.model_dump_json(),
        "--rates",
        *(str(r) for r in rates),
    ]
    done = subprocess.run(command, capture_output=True, text=True, timeout=60 + 2 * len(rates) * seconds)
    if done.returncode != 0:
        raise RuntimeError(f"the empty-thread floor failed (exit {done.returncode}):\n{done.stderr[-2000:]}")
    result: list[dict[str, Any]] = json.loads(done.stdout)
    return result


def probe(name: str) -> Callable[..., dict[str, Any]]:
    """The probe called ``name`` (a callable returning a dict), imported now: its library loads with it."""
    if name not in PROBES:
        raise LookupError(f"no probe {name!r} (known: {', '.join(PROBES)})")
    module, function = PROBES[name]
    found: Callable[..., dict[str, Any]] = getattr(importlib.import_module(f"hild.bench.probes.{module}"), function)
    return found


def run_probe(name: str, **kwargs: Any) -> dict[str, Any]:
    """A probe's figures, or ``{"error": ...}`` when it is missing or fails (the rest of the run goes on)."""
    try:
        return probe(name)(**kwargs)
    except Exception as exc:
        return {"error": f"{type(exc).__name__}: {exc}"}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="The empty-thread floor (run by hild bench in a child process).")
    parser.add_argument("--rates", type=float, nargs="+", required=True)
    parser.add_argument("--seconds", type=float, required=True)
    parser.add_argument("--realtime", default="{}", help="the RealtimeSection, as JSON")
    args = parser.parse_args(argv)
    realtime = RealtimeSection.model_validate_json(args.realtime)
    process = apply_process_settings(realtime)
    latency = CpuLatencyRequest()
    process["cpu_dma_latency"] = latency.hold(realtime.cpu_dma_latency_us)  # as the daemon holds it
    process["gc"] = freeze_heap(realtime)
    rows = []
    try:
        for rate in args.rates:
            row = empty_thread(rate, args.seconds, realtime)
            row["realtime"] = {**process, **row["realtime"]}
            rows.append(row)
    finally:
        latency.release()
    print(json.dumps(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
