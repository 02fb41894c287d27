"""The daemon: the client domain (one asyncio main thread) around the cycle (DESIGN.md §1, docs/architecture.md).

The cycle runs in a process of its own (``realtime.cycle_process``, :mod:`hild.cycle.process`), which the
daemon spawns, feeds through the shared region and watches; or as a thread of this process.

Start-up order matters for safety: the Zenoh session opens first and refuses to go on if another daemon of this
robot is on the network (it may drive this very arm: its bus must not even be opened); the engine configures the
hardware and reads it once, so hold starts where the arm is; the API declares its keys; the heap is frozen; the
drives are enabled last, right before the cycle thread starts.
Shutdown runs the other way: stop accepting commands, hold, release hardware, close.

Under systemd (``Type=notify``) the daemon says READY=1 only once the drives are live and the cycle has run a few
cycles with the supervisor holding, pings the watchdog only while the cycle earns it
(``hild.main.notify.WatchdogGate``), keeps ``STATUS=`` current and says STOPPING=1 when it starts to shut down.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import signal
import threading
import time
from typing import Any

from hild.config.loader import LoadedConfig
from hild.crossing.cells import Ask, ClientPhase, ClientVital, Phase, Vital
from hild.crossing.events import Event, log_event
from hild.cycle.engine import Engine
from hild.cycle.pacing import CycleThread
from hild.cycle.realtime import CpuLatencyRequest, apply_client_settings, apply_process_settings, freeze_heap
from hild.daemon.link import CycleLink
from hild.daemon.remote import Attachment, CycleProcessError, RemoteCycle
from hild.hardware import HardwareError
from hild.main.notify import ServiceReport, SystemdNotifier

log = logging.getLogger("hild.daemon")

CYCLE_JOIN_TIMEOUT = 5.0
READY_POLL = 0.005  # s: how often the asyncio side looks for those first cycles
SERVICE_TICK = 0.2  # s: the asyncio side's housekeeping tick once running (watchdog, status, cycle alive)
LOSS_ACK_TIMEOUT = 5.0  # s: a restarted client domain waits this long for the cycle to end its predecessor's goals


class StartupError(RuntimeError):
    pass


class Daemon:
    """The client domain around the cycle: Zenoh, the API, telemetry, and the cycle's lifecycle.

    Three layouts: the cycle as a thread of this process (``realtime.cycle_process: false``); the cycle process
    started by this very object (embedded use: tests, the bench); or, under ``hild run``, this object in the client
    process the main process started (``attachment``), which started the cycle process and speaks to systemd."""

    def __init__(
        self, loaded: LoadedConfig, listen: list[str] | None = None, attachment: Attachment | None = None
    ) -> None:
        self.loaded = loaded
        self.listen = listen
        self.attachment = attachment
        self._loop: asyncio.AbstractEventLoop | None = None
        self._wake_pending = False
        # One of the two: the engine in this process (a cycle thread), or the cycle process behind RemoteCycle.
        self.engine: Engine | None = None
        self.remote: RemoteCycle | None = None
        if loaded.config.realtime.cycle_process or attachment is not None:
            self.remote = RemoteCycle.attach(loaded, attachment) if attachment else RemoteCycle(loaded)
            self.link: CycleLink = self.remote
        else:
            self.engine = Engine(loaded, wake_client=self._wake_from_cycle)
            self.link = self.engine
        self._stopping = asyncio.Event()
        self._signals = 0
        self.api = None
        self.cycle: CycleThread | None = None
        self.telemetry: Any = None  # hild.telemetry.Telemetry when telemetry.enabled
        self._telemetry_task: asyncio.Task[None] | None = None
        self.notifier = SystemdNotifier()
        self.cpu_latency = CpuLatencyRequest()
        self.service = ServiceReport(self.notifier, loaded.config.safety.max_consecutive_overruns)
        self.client_report: dict[str, str] = {}  # the client domain's realtime settings, as applied

    @property
    def ready(self) -> bool:
        """The drives are live and the cycle has run its first cycles (READY=1 under systemd)."""
        return self.service.ready

    @property
    def watchdog(self) -> Any:
        return self.service.watchdog

    # ---- the cycle wakes the asyncio side --------------------------------------------------------------------------
    def _wake_from_cycle(self) -> None:
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
        if self.attachment is None:
            log.info("%s: holding every joint, then stopping", signal.Signals(signum).name)
        else:
            log.info("%s: the client domain stops", signal.Signals(signum).name)
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
        # Under the main process a terminal's Ctrl-C reaches every process: the main process stops this one.
        for sig in (signal.SIGTERM,) if self.attachment else (signal.SIGINT, signal.SIGTERM):
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
        if self.attachment is not None:
            self.remote.cells.client[ClientVital.PHASE] = ClientPhase.SERVING  # type: ignore[union-attr]
        log.info(
            "%s running at %g Hz on the %s clock%s; Zenoh %s",
            cfg.robot.name,
            cfg.update_rate,
            cfg.clock.source,
            f", the cycle in process {self.remote.cycle_pid}" if self.remote else "",
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
            await self._bring_up_remote(self.remote)
            return
        assert self.engine is not None
        self.engine.realtime_report.update(apply_process_settings(cfg.realtime))
        self.engine.realtime_report.update(self.client_report)
        self.engine.realtime_report["cpu_dma_latency"] = self.cpu_latency.hold(cfg.realtime.cpu_dma_latency_us)
        self.engine.bring_up()

    async def _bring_up_remote(self, remote: RemoteCycle) -> None:
        """Start the cycle process (or, under the main process, say that it may be started), and wait until it
        has brought the hardware up. A restarted client domain finds it live, and first waits until the cycle has
        ended what its predecessor ran (so no goal of the dead domain starts after this one answers)."""
        assert self._loop is not None
        cfg = self.loaded.config
        telemetry = None
        if self.telemetry is not None:
            from hild.cycle.process import TelemetryRing

            telemetry = TelemetryRing(*self.telemetry.ring_layout)
        if self.attachment is None:
            remote.spawn(telemetry)
        else:
            remote.cells.telemetry.put(telemetry)
            remote.cells.client[ClientVital.PID] = os.getpid()
            remote.cells.client[ClientVital.PHASE] = ClientPhase.OPEN  # the main process starts the cycle process
        self._loop.add_reader(remote.wakeup_fd, self._on_wake)
        if self.attachment is not None and self.attachment.restarted_after is not None:
            await self._after_restart(remote, self.attachment.restarted_after)
        else:
            try:
                await remote.brought_up()
            except CycleProcessError as exc:
                await asyncio.to_thread(remote.join, CYCLE_JOIN_TIMEOUT)
                self._on_wake()
                raise StartupError(f"the cycle process: {exc}") from None
        remote.realtime_report.update(self.client_report)
        remote.realtime_report["cpu_dma_latency"] = self.cpu_latency.hold(cfg.realtime.cpu_dma_latency_us)

    async def _after_restart(self, remote: RemoteCycle, reason: str) -> None:
        deadline = time.monotonic() + LOSS_ACK_TIMEOUT
        while remote.cells.vitals[Vital.CLIENT_LOST_SEEN] != remote.cells.asks[Ask.CLIENT_LOST]:
            if not remote.alive() or time.monotonic() > deadline:
                raise StartupError("the cycle process did not take over from the lost client domain")
            await asyncio.sleep(READY_POLL)
        remote.events.emit(
            "warning", "daemon", f"the client domain was restarted ({reason}); clients may reconnect and resend"
        )

    async def _go_live(self) -> None:
        """Enable the drives and start cycling at once: an enabled drive waits limp for its first command."""
        cfg = self.loaded.config
        if self.remote is not None:
            if self.remote.phase is not Phase.LIVE:  # a restarted client domain finds it running
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
            if self.attachment is None:  # under the main process, it stops the cycle process when we end
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
            if self.attachment is not None and os.getppid() != self.attachment.parent_pid:
                log.error("the daemon's main process is gone: stopping")
                return 1
            if not self._cycle_alive():
                self._on_wake()  # what it said last
                if self.attachment is not None and self.remote.cells.asks[Ask.STOP]:  # type: ignore[union-attr]
                    return 0  # the main process stopped it: ours is next
                log.error("%s", self._cycle_end())
                self.notifier.status(self._cycle_end())
                return 1
            if self.attachment is None:  # else the main process speaks to systemd
                self.service.tick(asyncio.get_running_loop().time(), self.link, self._cycle_alive())
        return 0

    def _open_telemetry(self) -> None:
        if not self.loaded.config.telemetry.enabled:
            return
        from hild.telemetry import Telemetry, TelemetryError  # rerun lives in the telemetry room

        try:
            restarted = self.attachment is not None and self.attachment.restarted_after is not None
            stats = self.engine.stats if self.engine else None
            self.telemetry = Telemetry.from_config(self.loaded, stats, keep_existing=restarted)
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
        stuck = False
        if self.attachment is not None:
            pass  # the main process stops the cycle process (it did already, unless this domain alone is stopped)
        elif self.remote is not None:
            self.remote.stop()
            await asyncio.to_thread(self.remote.join, timeout)
        elif self.cycle is not None:
            self.cycle.stop()
            await asyncio.to_thread(self.cycle.join, timeout)
        if self.attachment is None:
            stuck = self._cycle_alive()
        if stuck:
            log.error("the cycle did not stop within %g s", timeout)
            if self.remote is not None:
                self.remote.kill()  # the drives' own watchdogs take over, as on any crash
        self._on_wake()
        if self.remote is not None:
            assert self._loop is not None
            self._loop.remove_reader(self.remote.wakeup_fd)
            self.remote.abandon("the daemon stopped")
            if self.attachment is not None:
                self.remote.cells.client[ClientVital.PHASE] = ClientPhase.STOPPED
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
    if loaded.config.realtime.cycle_process:
        from hild.main.process import run_main_process

        return run_main_process(loaded, listen)
    try:
        daemon = Daemon(loaded, listen)
    except (HardwareError, ValueError) as exc:  # a driver or model that cannot be built from this config
        log.error("cannot build %s: %s", loaded.path, exc)
        return 1
    return serve(daemon)


def serve(daemon: Daemon) -> int:
    """Run ``daemon`` until it stops; returns the exit code. Start-up failures are reported, not raised."""
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
