"""The cycle on a thread of the daemon's own process: the engine in this process behind the same seam.

For lockstep tests, embedding and ``realtime.cycle_process: false``. The cycle thread shares this interpreter with
Zenoh and the asyncio loop (docs/performance.md, "Where the time goes"): streamed inputs are taken by the cycle itself
at the start of each cycle (``take_inputs``), so no other thread takes the interpreter's lock per sample.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import os
import signal
import weakref
from collections.abc import Callable
from typing import Any

from hild.config.loader import LoadedConfig
from hild.crossing.cyclelog import CycleLog, CycleLogPlace, capacity_of
from hild.crossing.events import Event
from hild.crossing.requests import Request
from hild.crossing.snapshot import Snapshot
from hild.crossing.stats import LoopStats
from hild.cycle.engine import Engine
from hild.cycle.pacing import CycleThread
from hild.cycle.realtime import apply_process_settings, freeze_heap
from hild.main.notify import ServiceReport, SystemdNotifier


class LocalCycle:
    inputs_on_arrival = False  # take_inputs: one interpreter-lock handover per cycle, not one per sample
    restarted_after = None
    signals = (signal.SIGINT, signal.SIGTERM)
    signal_meaning = "holding every joint, then stopping"
    releases_hardware = True

    def __init__(self, loaded: LoadedConfig) -> None:
        cfg = loaded.config
        self.loaded = loaded
        # The cycle log in a memfd of its own, so the recorder process maps it as it maps the shared region's.
        self._cycle_log: tuple[int, CycleLogPlace] | None = None
        log: CycleLog | None = None
        if capacity := capacity_of(cfg):
            log, fd, place = CycleLog.memfd(len(cfg.joints), capacity)
            self._cycle_log = (fd, place)
            self._close_cycle_log = weakref.finalize(self, os.close, fd)  # at close(), or when this link is dropped
        self.engine = Engine(loaded, cycle_log=log)
        self.robot = self.engine.robot
        self.joints = self.engine.joints
        self.update_rate = self.engine.update_rate
        self.events = self.engine.events
        self.main_pid = os.getpid()  # the unit's top process
        self.stats = self.engine.stats
        self.realtime_report = self.engine.realtime_report
        self.thread: CycleThread | None = None
        self._clock = (cfg.clock.source, cfg.clock.real_time_factor)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._on_events: Callable[[list[Event]], None] = lambda events: None
        self._wake_pending = False
        self._telemetry: Any = None

    # ---- what the API reads and asks (CycleLink) -------------------------------------------------------------
    @property
    def take_inputs(self) -> Callable[[], None] | None:
        return self.engine.take_inputs

    @take_inputs.setter
    def take_inputs(self, take: Callable[[], None] | None) -> None:
        self.engine.take_inputs = take

    @property
    def change_seq(self) -> int:
        return self.engine.change_seq

    @property
    def cycle(self) -> int:
        return self.engine.cycle

    @property
    def t(self) -> float:
        return self.engine.t

    def request(self, request: Request) -> concurrent.futures.Future[Any]:
        return self.engine.request(request)

    def request_estop(self) -> concurrent.futures.Future[Any]:
        return self.engine.request_estop()

    def snapshot(self) -> Snapshot:
        return self.engine.snapshot()

    def overall_mode(self) -> str:
        return self.engine.overall_mode()

    def status(self) -> dict[str, Any]:
        return self.engine.status()

    def controllers(self) -> dict[str, Any]:
        return self.engine.controllers()

    def cycle_log(self) -> tuple[int, CycleLogPlace] | None:
        return self._cycle_log

    # ---- the daemon's lifecycle (CycleHost) -------------------------------------------------------------------
    @property
    def telemetry_stats(self) -> LoopStats:
        return self.engine.stats

    def service_report(self, notifier: SystemdNotifier) -> ServiceReport:
        return ServiceReport(notifier, self.engine.max_consecutive_overruns)

    def watch(self, loop: asyncio.AbstractEventLoop, on_events: Callable[[list[Event]], None]) -> None:
        self._loop, self._on_events = loop, on_events
        self.engine.wake_client = self._wake_from_cycle

    def _wake_from_cycle(self) -> None:
        """Called from the cycle thread; schedules at most one pending wake-up on the loop."""
        if not self._wake_pending and self._loop is not None:
            self._wake_pending = True
            self._loop.call_soon_threadsafe(self._woken)

    def _woken(self) -> None:
        self._wake_pending = False
        self._on_events(self.take())

    def take(self) -> list[Event]:
        return self.engine.events.drain()

    async def bring_up(self, telemetry: Any) -> None:
        self.realtime_report.update(apply_process_settings(self.loaded.config.realtime))
        self._telemetry = telemetry
        self.engine.bring_up()

    async def go_live(self) -> None:
        """Enable the drives and start cycling at once: an enabled drive waits limp for its first command."""
        realtime = self.loaded.config.realtime
        self.realtime_report["gc"] = freeze_heap(realtime)
        self.thread = CycleThread(self.engine, *self._clock, realtime)
        # Enable the drives only now: the first cycle follows within a thread start, so no drive waits limp
        # (or trips its CAN watchdog) while Zenoh opens and the heap is frozen.
        self.engine.go_live()
        if self._telemetry is not None:
            self.engine.tap = self._telemetry.tap
        self.thread.start()

    def serving(self) -> None:
        """The API is up (nothing to tell: this process is the unit's top process)."""

    def describe(self) -> str:
        return ", the cycle a thread of this process"

    def gone(self) -> tuple[int, str | None] | None:
        if self.thread is None or self.thread.is_alive():
            return None
        return 1, f"the cycle thread ended unexpectedly: {self.thread.error}"

    def stopping(self) -> bool:
        return False  # a stop begins here (a signal, request_stop)

    async def stop(self, timeout: float) -> bool:
        if self.thread is not None:
            self.thread.stop()
            await asyncio.to_thread(self.thread.join, timeout)
        self.engine.tap = None  # the recorder closes next
        return self.thread is None or not self.thread.is_alive()

    def refused(self) -> None:
        self.engine.release()

    def start_failed(self) -> None:
        """Nobody else to tell: this process is the unit's top process."""

    def close(self) -> None:
        """The daemon stops. The cycle log's fd is closed (the engine's mapping stays until it goes: a recorder
        process holds an fd of its own)."""
        self.engine.wake_client = lambda: None
        if self._cycle_log is not None:
            self._cycle_log = None
            self._close_cycle_log()
