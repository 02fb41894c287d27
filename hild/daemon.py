"""The daemon: one asyncio main thread around one cycle thread (DESIGN.md §1).

Start-up order matters for safety: the engine configures the hardware and reads it once, so hold starts where the
arm is; the API opens; the heap is frozen; the drives are enabled last, right before the cycle thread starts.
Shutdown runs the other way: stop accepting commands, hold, release hardware, close.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import signal
import threading

from hild.config.loader import LoadedConfig
from hild.cycle import CycleThread
from hild.engine import Engine
from hild.events import log_event
from hild.hardware import HardwareError
from hild.realtime import apply_process_settings, freeze_heap

log = logging.getLogger("hild.daemon")

CYCLE_JOIN_TIMEOUT = 5.0


class StartupError(RuntimeError):
    pass


class Daemon:
    def __init__(self, loaded: LoadedConfig, listen: list[str] | None = None) -> None:
        self.loaded = loaded
        self.listen = listen
        self.engine = Engine(loaded)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._wake_pending = False
        self._stopping = asyncio.Event()
        self._signals = 0
        self.api = None
        self.cycle: CycleThread | None = None

    # ---- cycle → asyncio doorbell --------------------------------------------------------------------------
    def _doorbell(self) -> None:
        """Called from the cycle thread; schedules at most one pending wake-up on the loop."""
        if not self._wake_pending and self._loop is not None:
            self._wake_pending = True
            self._loop.call_soon_threadsafe(self._on_wake)

    def _on_wake(self) -> None:
        self._wake_pending = False
        events = self.engine.events.drain()
        for event in events:
            log_event(event)
        if self.api is not None:
            self.api.publish(events)

    # ---- signals ---------------------------------------------------------------------------------------------
    def _on_signal(self, signum: int) -> None:
        self._signals += 1
        if self._signals > 1:
            log.error("second %s: forcing exit", signal.Signals(signum).name)
            os._exit(1)
        log.info("%s: holding every joint, then stopping", signal.Signals(signum).name)
        self._stopping.set()

    # ---- run -----------------------------------------------------------------------------------------------
    async def run(self) -> int:
        from hild.api.server import ApiServer  # zenoh lives in the api room

        cfg = self.loaded.config
        self._loop = asyncio.get_running_loop()
        self.engine.doorbell = self._doorbell
        self.engine.realtime_report.update(apply_process_settings(cfg.realtime))
        self.engine.bring_up()  # drives configured and read, still disabled
        try:
            self.api = ApiServer(self.engine, cfg.zenoh, self.listen)
            await self.api.start()
        except Exception as exc:  # e.g. the listen port is taken: release the hardware we just configured
            self.api = None
            self.engine.release()
            raise StartupError(f"cannot open the Zenoh API ({self.listen or cfg.zenoh.listen}): {exc}") from exc
        for sig in (signal.SIGINT, signal.SIGTERM):
            self._loop.add_signal_handler(sig, self._on_signal, sig)
        self.engine.realtime_report["gc"] = freeze_heap(cfg.realtime)
        self.cycle = CycleThread(self.engine, cfg.clock.source, cfg.clock.real_time_factor, cfg.realtime)
        # Enable the drives only now: the first cycle follows within a thread start, so no drive waits limp
        # (or trips its CAN watchdog) while Zenoh opens and the heap is frozen.
        try:
            self.engine.go_live()
        except HardwareError:
            await self.api.close()
            self.api = None
            raise
        self.cycle.start()
        log.info(
            "%s running at %g Hz on the %s clock; Zenoh %s",
            cfg.robot.name,
            cfg.update_rate,
            cfg.clock.source,
            self.listen or cfg.zenoh.listen,
        )
        self._on_wake()
        exit_code = await self._wait_for_stop()
        await self._shutdown()
        return exit_code

    async def _wait_for_stop(self) -> int:
        assert self.cycle is not None
        while not self._stopping.is_set():
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._stopping.wait(), timeout=0.2)
            if not self.cycle.is_alive():
                log.error("the cycle thread ended unexpectedly: %s", self.cycle.error)
                return 1
        return 0

    async def _shutdown(self) -> None:
        assert self.cycle is not None
        self.cycle.stop()
        await asyncio.to_thread(self.cycle.join, CYCLE_JOIN_TIMEOUT)
        if self.cycle.is_alive():
            log.error("the cycle thread did not stop within %g s", CYCLE_JOIN_TIMEOUT)
        self._on_wake()
        if self.api is not None:
            await self.api.close()
        log.info("stopped")


def run_daemon(loaded: LoadedConfig, listen: list[str] | None = None) -> int:
    """Run until a signal; returns the process exit code. Start-up failures are reported, not raised."""
    if threading.current_thread() is not threading.main_thread():
        raise RuntimeError("the daemon must run on the main thread (it owns the signal handlers)")
    try:
        daemon = Daemon(loaded, listen)
    except (HardwareError, ValueError) as exc:  # a driver or model that cannot be built from this config
        log.error("cannot build %s: %s", loaded.path, exc)
        return 1
    try:
        return asyncio.run(daemon.run())
    except (HardwareError, StartupError) as exc:
        for event in daemon.engine.events.drain():
            log_event(event)
        log.error("start-up failed; the hardware was released: %s", exc)
        return 1
