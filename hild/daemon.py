"""The daemon: one asyncio main thread around one cycle thread (DESIGN.md §1).

Start-up order matters for safety: the Zenoh session opens first and refuses to go on if another daemon of this
robot is on the network (it may drive this very arm: its bus must not even be opened); the engine configures the
hardware and reads it once, so hold starts where the arm is; the API declares its keys; the heap is frozen; the
drives are enabled last, right before the cycle thread starts.
Shutdown runs the other way: stop accepting commands, hold, release hardware, close.

Under systemd (``Type=notify``) the daemon says READY=1 only once the drives are live and the cycle has run a few
cycles with the supervisor holding, pings the watchdog only while the cycle earns it (``hild.notify.WatchdogGate``),
keeps ``STATUS=`` current and says STOPPING=1 when it starts to shut down.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import signal
import threading
from typing import Any

from hild.config.loader import LoadedConfig
from hild.cycle import CycleThread
from hild.engine import STATUS_STATS_MAX_AGE, Engine
from hild.events import log_event
from hild.hardware import HardwareError
from hild.notify import SystemdNotifier, WatchdogGate, status_line
from hild.realtime import CpuLatencyRequest, apply_process_settings, freeze_heap

log = logging.getLogger("hild.daemon")

CYCLE_JOIN_TIMEOUT = 5.0
READY_AFTER_CYCLES = 5  # cycles the live loop must complete (read → supervise → write) before READY=1
READY_POLL = 0.005  # s: how often the asyncio side looks for those first cycles
SERVICE_TICK = 0.2  # s: the asyncio side's housekeeping tick once running (watchdog, status, cycle alive)
STATUS_PERIOD = 2.0  # s: STATUS= refresh; a change of overall mode is sent at the next tick


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
        self.telemetry: Any = None  # hild.telemetry.Telemetry when telemetry.enabled
        self._telemetry_task: asyncio.Task[None] | None = None
        self.notifier = SystemdNotifier()
        self.cpu_latency = CpuLatencyRequest()
        self.watchdog = WatchdogGate(self.engine.max_consecutive_overruns)
        self.ready = False
        self._next_ping = 0.0
        self._next_status = 0.0
        self._last_mode = ""

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
        if self.telemetry is not None and events:
            self.telemetry.log_events(events)

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
        from hild.api.unique import RobotNameTaken

        cfg = self.loaded.config
        self._loop = asyncio.get_running_loop()
        self.engine.doorbell = self._doorbell
        self.notifier.status("bringing up the hardware")
        self.engine.realtime_report.update(apply_process_settings(cfg.realtime))
        self.engine.realtime_report["cpu_dma_latency"] = self.cpu_latency.hold(cfg.realtime.cpu_dma_latency_us)
        self._open_telemetry()  # before the hardware: a sink that cannot open is a start-up error, nothing enabled
        self.api = ApiServer(self.engine, cfg.zenoh, self.listen)
        try:  # one robot name, one daemon: checked before the hardware is touched (the bus may be the other's)
            await self.api.open()
        except RobotNameTaken as exc:
            self._refused()
            raise StartupError(str(exc)) from exc
        except Exception as exc:  # e.g. the listen port is taken
            self._refused()
            raise StartupError(f"cannot open the Zenoh API ({self.listen or cfg.zenoh.listen}): {exc}") from exc
        try:
            self.engine.bring_up()  # drives configured and read, still disabled
        except BaseException:
            await self.api.close()
            self.api = None
            raise
        try:
            await self.api.start()
        except Exception as exc:  # release the hardware we just configured
            self._refused()
            raise StartupError(f"cannot start the Zenoh API ({self.listen or cfg.zenoh.listen}): {exc}") from exc
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
        if self.telemetry is not None:
            self.engine.tap = self.telemetry.tap
            self._telemetry_task = self._loop.create_task(self.telemetry.run(), name="hild-telemetry")
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

    def _refused(self) -> None:
        """The API did not come up: release whatever hardware was configured (none if it failed to open)."""
        self.api = None
        self.engine.release()

    def request_stop(self) -> None:
        """Stop as on SIGTERM (tests and embedding code)."""
        self._stopping.set()

    async def _wait_for_stop(self) -> int:
        assert self.cycle is not None
        ping = self.notifier.ping_period
        tick = SERVICE_TICK if ping is None else min(SERVICE_TICK, ping)
        while not self._stopping.is_set():
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._stopping.wait(), timeout=tick if self.ready else READY_POLL)
            if not self.cycle.is_alive():
                log.error("the cycle thread ended unexpectedly: %s", self.cycle.error)
                return 1
            self._service_tick(asyncio.get_running_loop().time())
        return 0

    # ---- systemd: READY, WATCHDOG, STATUS ------------------------------------------------------------------
    def _service_tick(self, now: float) -> None:
        """READY=1 once the live cycle has run; then earned watchdog pings and a current STATUS=."""
        assert self.cycle is not None
        engine = self.engine
        if not self.ready:
            if engine.cycle <= READY_AFTER_CYCLES:  # the counter counts cycles begun: this many have ended
                return
            self.ready = True
            self.watchdog.reset(engine.cycle)
            self._last_mode = engine.overall_mode()
            self._next_ping = self._next_status = now
            self.notifier.ready(self._status_text(self._last_mode))
            log.info("ready: the drives are live and %d cycles have run", engine.cycle)
            return
        ping = self.notifier.ping_period
        if ping is not None and now >= self._next_ping:
            self._next_ping = now + ping
            was_withheld = bool(self.watchdog.reason)
            if self.watchdog.earned(engine.cycle, engine.stats.consecutive_overruns, self.cycle.is_alive()):
                self.notifier.watchdog()
                if was_withheld:
                    log.info("systemd watchdog pings resumed: the cycle advances again")
            elif not was_withheld:  # one line per episode, not one per missed ping
                log.error("withholding the systemd watchdog ping: %s", self.watchdog.reason)
        if not self.notifier.enabled:  # not under systemd: no status line to build
            return
        mode = engine.overall_mode()
        if mode != self._last_mode or now >= self._next_status:
            self._last_mode = mode
            self._next_status = now + STATUS_PERIOD
            self.notifier.status(self._status_text(mode))

    def _status_text(self, mode: str) -> str:
        return status_line(mode, self.engine.update_rate, self.engine.stats.summary(STATUS_STATS_MAX_AGE))

    def _open_telemetry(self) -> None:
        if not self.loaded.config.telemetry.enabled:
            return
        from hild.telemetry import Telemetry, TelemetryError  # rerun lives in the telemetry room

        try:
            self.telemetry = Telemetry.from_config(self.loaded, self.engine.stats)
        except TelemetryError as exc:
            raise StartupError(f"telemetry: {exc}") from exc

    async def close_telemetry(self) -> None:
        """Flush and close the recording (bounded in time: an unreachable viewer never holds up the stop)."""
        telemetry, self.telemetry = self.telemetry, None
        if telemetry is None:
            return
        self.engine.tap = None
        await asyncio.to_thread(telemetry.close)
        if self._telemetry_task is not None:
            self._telemetry_task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await self._telemetry_task
            self._telemetry_task = None

    async def _shutdown(self) -> None:
        assert self.cycle is not None
        descent = self.engine.stop_descent
        words = f"a {descent:g} s damped descent" if descent else "holding every joint"
        self.notifier.stopping(f"stopping: {words}, then releasing the hardware")
        self.cycle.stop()
        timeout = CYCLE_JOIN_TIMEOUT + descent  # the cycle keeps its pace through the descent
        await asyncio.to_thread(self.cycle.join, timeout)
        stuck = self.cycle.is_alive()
        if stuck:
            log.error("the cycle thread did not stop within %g s", timeout)
        self._on_wake()
        await self.close_telemetry()
        if self.api is not None:
            await self.api.close()
        self.cpu_latency.release()
        self.notifier.status("stopped: the cycle thread did not stop" if stuck else "stopped: hardware released")
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
        asyncio.run(daemon.close_telemetry())
        for event in daemon.engine.events.drain():
            log_event(event)
        log.error("start-up failed; the hardware was released: %s", exc)
        daemon.notifier.status(f"start-up failed: {exc}")
        return 1
    finally:
        daemon.cpu_latency.release()
        daemon.notifier.close()
