"""The daemon: the client domain (one asyncio main thread) around the cycle (DESIGN.md §1, docs/architecture.md).

The cycle runs in a process of its own (``realtime.cycle_process``, :mod:`hild.domains.cycle_process`), which the
daemon spawns, feeds through the shared region and watches; or as a thread of this process.

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

from hild.api.status import STATS_MAX_AGE
from hild.config.loader import LoadedConfig
from hild.cycle import CycleThread
from hild.domains.link import CycleLink
from hild.domains.remote import CycleProcessError, RemoteCycle
from hild.engine import Engine
from hild.events import Event, log_event
from hild.hardware import HardwareError
from hild.notify import SystemdNotifier, WatchdogGate, status_line
from hild.realtime import CpuLatencyRequest, apply_client_settings, apply_process_settings, freeze_heap

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
        self._loop: asyncio.AbstractEventLoop | None = None
        self._wake_pending = False
        # One of the two: the engine in this process (a cycle thread), or the cycle process behind RemoteCycle.
        self.engine: Engine | None = None
        self.remote: RemoteCycle | None = None
        if loaded.config.realtime.cycle_process:
            self.remote = RemoteCycle(loaded)
            self.link: CycleLink = self.remote
        else:
            self.engine = Engine(loaded, doorbell=self._doorbell)
            self.link = self.engine
        self._stopping = asyncio.Event()
        self._signals = 0
        self.api = None
        self.cycle: CycleThread | None = None
        self.telemetry: Any = None  # hild.telemetry.Telemetry when telemetry.enabled
        self._telemetry_task: asyncio.Task[None] | None = None
        self.notifier = SystemdNotifier()
        self.cpu_latency = CpuLatencyRequest()
        self.watchdog = WatchdogGate(loaded.config.safety.max_consecutive_overruns)
        self.ready = False
        self.client_report: dict[str, str] = {}  # the client domain's realtime settings, as applied
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
        events = self._take_events()
        for event in events:
            log_event(event)
        if self.api is not None:
            self.api.publish(events)
        if self.telemetry is not None and events:
            self.telemetry.log_events(events)

    def _take_events(self) -> list[Event]:
        if self.remote is not None:
            return self.remote.take()  # and answers the replies the cycle process rang for
        return self.link.events.drain()

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
        self.client_report = apply_client_settings(cfg.realtime)  # before Zenoh's threads start: they inherit it
        self.notifier.status("bringing up the hardware")
        self._open_telemetry()  # before the hardware: a sink that cannot open is a start-up error, nothing enabled
        self.api = ApiServer(self.link, cfg.zenoh, self.listen)
        try:  # one robot name, one daemon: checked before the hardware is touched (the bus may be the other's)
            await self.api.open()
        except RobotNameTaken as exc:
            self._refused()
            raise StartupError(str(exc)) from exc
        except Exception as exc:  # e.g. the listen port is taken
            self._refused()
            raise StartupError(f"cannot open the Zenoh API ({self.listen or cfg.zenoh.listen}): {exc}") from exc
        try:
            await self._bring_up()  # drives configured and read, still disabled
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
        try:
            await self._go_live()
        except (HardwareError, CycleProcessError) as exc:
            await self.api.close()
            self.api = None
            if isinstance(exc, CycleProcessError):
                raise StartupError(f"the cycle process: {exc}") from None
            raise
        if self.telemetry is not None:
            self._telemetry_task = self._loop.create_task(self.telemetry.run(), name="hild-telemetry")
        log.info(
            "%s running at %g Hz on the %s clock%s; Zenoh %s",
            cfg.robot.name,
            cfg.update_rate,
            cfg.clock.source,
            f", the cycle in process {self.remote.process.pid}" if self.remote and self.remote.process else "",
            self.listen or cfg.zenoh.listen,
        )
        self._on_wake()
        exit_code = await self._wait_for_stop()
        await self._shutdown()
        return exit_code

    async def _bring_up(self) -> None:
        """Configure and read the hardware, drives disabled: in the cycle process (it reports how it went), or
        here."""
        cfg = self.loaded.config
        if self.remote is not None:
            assert self._loop is not None
            telemetry = None
            if self.telemetry is not None:
                from hild.domains.cycle_process import TelemetryRing

                telemetry = TelemetryRing(*self.telemetry.ring_layout)
            self.remote.spawn(telemetry)
            self._loop.add_reader(self.remote.doorbell_fd, self._on_wake)
            try:
                await self.remote.brought_up()
            except CycleProcessError as exc:
                await asyncio.to_thread(self.remote.join, CYCLE_JOIN_TIMEOUT)
                self._on_wake()
                raise StartupError(f"the cycle process: {exc}") from None
            self.remote.realtime_report.update(self.client_report)
            self.remote.realtime_report["cpu_dma_latency"] = self.cpu_latency.hold(cfg.realtime.cpu_dma_latency_us)
            return
        assert self.engine is not None
        self.engine.realtime_report.update(apply_process_settings(cfg.realtime))
        self.engine.realtime_report.update(self.client_report)
        self.engine.realtime_report["cpu_dma_latency"] = self.cpu_latency.hold(cfg.realtime.cpu_dma_latency_us)
        self.engine.bring_up()

    async def _go_live(self) -> None:
        """Enable the drives and start cycling at once: an enabled drive waits limp for its first command."""
        cfg = self.loaded.config
        if self.remote is not None:
            await self.remote.live()
            return
        assert self.engine is not None
        self.engine.realtime_report["gc"] = freeze_heap(cfg.realtime)
        self.cycle = CycleThread(self.engine, cfg.clock.source, cfg.clock.real_time_factor, cfg.realtime)
        # Enable the drives only now: the first cycle follows within a thread start, so no drive waits limp
        # (or trips its CAN watchdog) while Zenoh opens and the heap is frozen.
        self.engine.go_live()
        if self.telemetry is not None:
            self.engine.tap = self.telemetry.tap
        self.cycle.start()

    def _refused(self) -> None:
        """The API did not come up: release whatever hardware was configured (none if it failed to open)."""
        self.api = None
        if self.remote is not None:
            self.remote.stop()  # brought up or not: it releases the hardware and exits
            self.remote.join(CYCLE_JOIN_TIMEOUT)
        elif self.engine is not None:
            self.engine.release()

    def request_stop(self) -> None:
        """Stop as on SIGTERM (tests and embedding code)."""
        self._stopping.set()

    def _cycle_alive(self) -> bool:
        if self.remote is not None:
            return self.remote.alive()
        return self.cycle is not None and self.cycle.is_alive()

    def _cycle_end(self) -> str:
        if self.remote is not None:
            return f"the cycle process ended unexpectedly (exit code {self.remote.exit_code})"
        return f"the cycle thread ended unexpectedly: {self.cycle.error if self.cycle else None}"

    async def _wait_for_stop(self) -> int:
        ping = self.notifier.ping_period
        tick = SERVICE_TICK if ping is None else min(SERVICE_TICK, ping)
        while not self._stopping.is_set():
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._stopping.wait(), timeout=tick if self.ready else READY_POLL)
            if not self._cycle_alive():
                self._on_wake()  # what it said last
                log.error("%s", self._cycle_end())
                self.notifier.status(self._cycle_end())
                return 1
            self._service_tick(asyncio.get_running_loop().time())
        return 0

    # ---- systemd: READY, WATCHDOG, STATUS ------------------------------------------------------------------
    def _service_tick(self, now: float) -> None:
        """READY=1 once the live cycle has run; then earned watchdog pings and a current STATUS=."""
        engine = self.link
        if not self.ready:
            if engine.cycle <= READY_AFTER_CYCLES:  # the counter counts cycles begun: this many have ended
                return
            self.ready = True
            self.watchdog.reset(engine.cycle)
            self._last_mode = self._mode()
            self._next_ping = self._next_status = now
            self.notifier.ready(self._status_text(self._last_mode))
            log.info("ready: the drives are live and %d cycles have run", engine.cycle)
            return
        ping = self.notifier.ping_period
        if ping is not None and now >= self._next_ping:
            self._next_ping = now + ping
            was_withheld = bool(self.watchdog.reason)
            if self.watchdog.earned(engine.cycle, engine.stats.consecutive_overruns, self._cycle_alive()):
                self.notifier.watchdog()
                if was_withheld:
                    log.info("systemd watchdog pings resumed: the cycle advances again")
            elif not was_withheld:  # one line per episode, not one per missed ping
                log.error("withholding the systemd watchdog ping: %s", self.watchdog.reason)
        if not self.notifier.enabled:  # not under systemd: no status line to build
            return
        mode = self._mode()
        if mode != self._last_mode or now >= self._next_status:
            self._last_mode = mode
            self._next_status = now + STATUS_PERIOD
            self.notifier.status(self._status_text(mode))

    def _mode(self) -> str:
        return self.link.overall_mode()

    def _status_text(self, mode: str) -> str:
        return status_line(mode, self.link.update_rate, self.link.stats.summary(STATS_MAX_AGE))

    def _open_telemetry(self) -> None:
        if not self.loaded.config.telemetry.enabled:
            return
        from hild.telemetry import Telemetry, TelemetryError  # rerun lives in the telemetry room

        try:
            self.telemetry = Telemetry.from_config(self.loaded, self.engine.stats if self.engine else None)
        except TelemetryError as exc:
            raise StartupError(f"telemetry: {exc}") from exc

    async def close_telemetry(self) -> None:
        """Flush and close the recording (bounded in time: an unreachable viewer never holds up the stop)."""
        telemetry, self.telemetry = self.telemetry, None
        if telemetry is None:
            return
        if self.engine is not None:
            self.engine.tap = None
        await asyncio.to_thread(telemetry.close)
        if self._telemetry_task is not None:
            self._telemetry_task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await self._telemetry_task
            self._telemetry_task = None

    async def _shutdown(self) -> None:
        descent = self.loaded.config.safety.stop_descent
        words = f"a {descent:g} s damped descent" if descent else "holding every joint"
        self.notifier.stopping(f"stopping: {words}, then releasing the hardware")
        timeout = CYCLE_JOIN_TIMEOUT + descent  # the cycle keeps its pace through the descent
        if self.remote is not None:
            self.remote.stop()
            await asyncio.to_thread(self.remote.join, timeout)
        elif self.cycle is not None:
            self.cycle.stop()
            await asyncio.to_thread(self.cycle.join, timeout)
        stuck = self._cycle_alive()
        if stuck:
            log.error("the cycle did not stop within %g s", timeout)
            if self.remote is not None:
                self.remote.kill()  # the drives' own watchdogs take over, as on any crash
        self._on_wake()
        if self.remote is not None:
            assert self._loop is not None
            self._loop.remove_reader(self.remote.doorbell_fd)
            self.remote.abandon("the daemon stopped")
        await self.close_telemetry()
        if self.api is not None:
            await self.api.close()
        self.cpu_latency.release()
        self.notifier.status("stopped: the cycle did not stop" if stuck else "stopped: hardware released")
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
        for event in daemon._take_events():
            log_event(event)
        log.error("start-up failed; the hardware was released: %s", exc)
        daemon.notifier.status(f"start-up failed: {exc}")
        return 1
    finally:
        daemon.cpu_latency.release()
        daemon.notifier.close()
