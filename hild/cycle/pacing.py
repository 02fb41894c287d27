"""The paced loop: calls ``engine.step`` at ``update_rate`` on the wall clock or the sim clock (docs/architecture.md,
"The cycle" and "Clocks").

``CycleThread`` is a thread of the daemon when the cycle runs in the daemon's own process
(``realtime.cycle_process: false``, embedding); the cycle process runs the same loop on its main thread
(``hild.cycle.process.CrossingCycle`` calls ``run`` itself). Either way the loop paces itself, because asyncio
cannot pace below 1 ms (its epoll wait rounds up to whole milliseconds). It sleeps to an absolute deadline minus a
short spin, then busy-waits the rest: deadlines never drift, and the wake-up is accurate to microseconds instead of
the kernel's timer slack. A cycle that overruns its period skips the missed periods (no burst to catch up) and
counts them. The duration recorded is wake-up → hardware writes done (``engine.write_done_ns``): what can delay a
command. Work after the write (the telemetry tap) counts toward overruns, not toward the duration.

Clocks: ``wall`` gives controllers the measured time since start; ``sim`` gives ``t = k · period`` exactly, paced
at ``real_time_factor`` × real time, or as fast as possible when it is 0 (lockstep twin).
"""

from __future__ import annotations

import threading
import time

from hild.config.model import RealtimeSection
from hild.cycle.engine import Engine
from hild.cycle.realtime import apply_thread_settings

SPIN_NS = 200_000  # the default of realtime.spin_us


def wait_until(deadline_ns: int, spin_ns: int = SPIN_NS) -> None:
    """Sleep to ``spin_ns`` before ``deadline_ns`` (perf_counter_ns), then busy-wait to it."""
    remaining = deadline_ns - time.perf_counter_ns() - spin_ns
    if remaining > 0:
        time.sleep(remaining / 1e9)
    while time.perf_counter_ns() < deadline_ns:
        pass


class CycleThread(threading.Thread):
    def __init__(self, engine: Engine, clock_source: str, real_time_factor: float, realtime: RealtimeSection) -> None:
        super().__init__(name="hild-cycle", daemon=True)
        self.engine = engine
        self.clock_source = clock_source
        self.real_time_factor = real_time_factor
        self.realtime = realtime
        self.error: BaseException | None = None
        self._stop_requested = threading.Event()
        self._stop_begun = False

    def stop(self) -> None:
        self._stop_requested.set()

    def run(self) -> None:
        engine = self.engine
        engine.realtime_report.update(apply_thread_settings(self.realtime))
        try:
            if self.clock_source == "sim":
                self._run_sim()
            else:
                self._run_wall()
        except BaseException as exc:  # a bug in the cycle itself: report it, then still release the hardware
            self.error = exc
            engine.events.emit("error", "cycle", f"cycle thread crashed: {type(exc).__name__}: {exc}")
        finally:
            engine.stop()

    def step(self, t: float, dt: float) -> None:
        """One cycle: the engine's step (the cycle process adds what crosses the shared region around it)."""
        self.engine.step(t, dt)

    def _descending(self) -> bool:
        """Asked to stop: start the engine's stop sequence once, and keep cycling while its descent runs."""
        if not self._stop_begun:
            self._stop_begun = True
            return self.engine.begin_stop()
        return not self.engine.stopping_done

    def _run_wall(self) -> None:
        engine, stats, stopping = self.engine, self.engine.stats, self._stop_requested
        period_ns = round(engine.period * 1e9)
        spin_ns = self.realtime.spin_us * 1000
        start = time.perf_counter_ns()
        deadline = start
        prev_wake = start - period_ns
        while not stopping.is_set() or self._descending():
            deadline += period_ns
            wait_until(deadline, spin_ns)
            wake = time.perf_counter_ns()
            self.step((wake - start) / 1e9, (wake - prev_wake) / 1e9)
            end = time.perf_counter_ns()
            overrun = end > deadline + period_ns
            if overrun:
                deadline += ((end - deadline) // period_ns) * period_ns
            stats.record(engine.write_done_ns - wake, abs(wake - prev_wake - period_ns), overrun)
            prev_wake = wake

    def _run_sim(self) -> None:
        engine, stats, stopping = self.engine, self.engine.stats, self._stop_requested
        period = engine.period
        rtf = self.real_time_factor
        period_ns = round(period * 1e9)
        spin_ns = self.realtime.spin_us * 1000
        start = time.perf_counter_ns()
        t0 = engine.t
        k = 0
        prev_wake = start
        while not stopping.is_set() or self._descending():
            k += 1
            deadline = start + round(k * period_ns / rtf) if rtf > 0 else 0
            if rtf > 0:
                wait_until(deadline, spin_ns)
            wake = time.perf_counter_ns()
            self.step(t0 + k * period, period)
            end = time.perf_counter_ns()
            overrun = rtf > 0 and end > deadline + round(period_ns / rtf)
            if overrun:  # fell behind real time: re-sync instead of bursting to catch up
                start += end - deadline
            error = abs(wake - prev_wake - round(period_ns / rtf)) if rtf > 0 else 0
            stats.record(engine.write_done_ns - wake, error, overrun)
            prev_wake = wake
