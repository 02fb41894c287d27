"""The daemon: the client domain (one asyncio main thread) around the cycle (docs/architecture.md, "Three processes").

The daemon reaches the cycle only through a :class:`~hild.daemon.link.CycleHost` and never asks which one it has:
under ``hild run`` the cycle process the main process started (:class:`~hild.daemon.remote.AttachedCycle`);
embedded, one it starts itself (:class:`~hild.daemon.remote.SpawnedCycle`) or the engine on a thread of this
process (:class:`~hild.daemon.local.LocalCycle`, ``realtime.cycle_process: false``).

Start-up order matters for safety: the Zenoh session opens first and refuses to go on if another daemon of this
robot is on the network (it may drive this very arm: its bus must not even be opened); the engine configures the
hardware and reads it once, so hold starts where the arm is; the API declares its keys; the heap is frozen; the
drives are enabled last, right before the cycle starts.
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
from typing import Any

from hild.config.loader import LoadedConfig
from hild.crossing.events import Event, log_event
from hild.cycle.realtime import CpuLatencyRequest, apply_client_settings
from hild.daemon.link import CycleHost, StartRefused, StartupError
from hild.daemon.local import LocalCycle
from hild.daemon.remote import CycleProcessError, SpawnedCycle
from hild.hardware import HardwareError
from hild.main.notify import SystemdNotifier
from hild.record.events import cycle_event
from hild.record.model import RecordError
from hild.record.recorder import Recorder
from hild.record.triggers import STALL, BlackBoxTriggers

__all__ = ["Daemon", "StartupError", "cycle_host", "run_daemon", "serve"]

log = logging.getLogger("hild.daemon")

CYCLE_JOIN_TIMEOUT = 5.0
READY_POLL = 0.005  # s: how often the asyncio side looks for those first cycles
SERVICE_TICK = 0.2  # s: the asyncio side's housekeeping tick once running (watchdog, status, cycle alive)


def cycle_host(loaded: LoadedConfig) -> CycleHost:
    """The cycle for an embedded daemon, as the config asks: a process of its own (the default), or a thread here."""
    return SpawnedCycle(loaded) if loaded.config.realtime.cycle_process else LocalCycle(loaded)


class Daemon:
    """The client domain around the cycle: Zenoh, the API, telemetry, and the cycle's lifecycle through ``link``."""

    def __init__(self, loaded: LoadedConfig, listen: list[str] | None = None, link: CycleHost | None = None) -> None:
        self.loaded = loaded
        self.listen = listen
        self.link: CycleHost = link if link is not None else cycle_host(loaded)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stopping = asyncio.Event()
        self._signals = 0
        self.api = None
        self.telemetry: Any = None  # hild.telemetry.Telemetry when telemetry.enabled
        self._telemetry_task: asyncio.Task[None] | None = None
        self.recorder: Recorder | None = None  # episodes and the black box, when recording.enabled
        self.triggers: BlackBoxTriggers | None = None  # the black box's own triggers (recording.blackbox_on)
        self._triggers_task: asyncio.Task[None] | None = None
        self._link_closed = False
        self.notifier = SystemdNotifier()
        self.cpu_latency = CpuLatencyRequest()
        self.service = self.link.service_report(self.notifier)
        self.client_report: dict[str, str] = {}  # the client domain's realtime settings, as applied

    @property
    def ready(self) -> bool:
        """The drives are live and the cycle has run its first cycles (READY=1 under systemd)."""
        return self.service.ready

    @property
    def watchdog(self) -> Any:
        return self.service.watchdog

    # ---- the cycle wakes the asyncio side --------------------------------------------------------------------
    def _on_wake(self) -> None:
        """Drain what the cycle said (at start, at the end, once it is gone)."""
        self._publish(self._take_events())

    def _publish(self, events: list[Event]) -> None:
        """The cycle's events, whenever it rang: logged once, published, recorded."""
        for event in events:
            log_event(event)
        if self.api is not None:
            self.api.publish(events)
        if self.telemetry is not None and events:
            self.telemetry.log_events(events)
        if self.recorder is not None:
            for event in events:
                self.recorder.log(cycle_event(event))

    def _take_events(self) -> list[Event]:
        return self.link.take()  # replies to requests are answered on the way, by the link

    # ---- signals ---------------------------------------------------------------------------------------------
    def _on_signal(self, signum: int) -> None:
        self._signals += 1
        if self._signals > 1:
            log.error("second %s: forcing exit", signal.Signals(signum).name)
            os._exit(1)
        log.info("%s: %s", signal.Signals(signum).name, self.link.signal_meaning)
        self._stopping.set()

    # ---- run -------------------------------------------------------------------------------------------------
    async def run(self) -> int:
        from hild.api.server import ApiServer  # zenoh lives in the api room
        from hild.api.unique import RobotNameTaken

        cfg = self.loaded.config
        self._loop = asyncio.get_running_loop()
        self.client_report = apply_client_settings(cfg.realtime)  # before Zenoh's threads start: they inherit it
        self.notifier.status("bringing up the hardware")
        self._open_telemetry()  # before the hardware: a sink that cannot open is a start-up error, nothing enabled
        self.recorder = self._build_recorder()
        self.api = ApiServer(self.link, cfg.zenoh, self.listen, pid=self.link.main_pid, recorder=self.recorder)
        try:  # one robot name, one daemon: checked before the hardware is touched (the bus may be the other's)
            await self.api.open()
        except RobotNameTaken as exc:
            self._refused()
            raise StartRefused(str(exc)) from exc
        except Exception as exc:  # e.g. the listen port is taken
            self._refused()
            raise StartRefused(f"cannot open the Zenoh API ({self.listen or cfg.zenoh.listen}): {exc}") from exc
        try:
            await self._bring_up()  # drives configured and read, still disabled
        except BaseException:
            await self.api.close()
            self.api = None
            raise
        await self._open_recorder()  # the cycle log exists now; a recorder that cannot start is reported, not fatal
        try:
            await self._go_live()
        except BaseException:
            await self.close_recorder()
            raise
        self._start_triggers()
        if self.telemetry is not None:
            self._telemetry_task = self._loop.create_task(self.telemetry.run(), name="hild-telemetry")
        self.link.serving()
        log.info(
            "%s running at %g Hz on the %s clock%s; Zenoh %s",
            cfg.robot.name,
            cfg.update_rate,
            cfg.clock.source,
            self.link.describe(),
            self.listen or cfg.zenoh.listen,
        )
        self._on_wake()
        exit_code = await self._wait_for_stop()
        await self._shutdown()
        return exit_code

    async def _go_live(self) -> None:
        """Declare the API, then enable the drives and start cycling."""
        assert self.api is not None and self._loop is not None
        cfg = self.loaded.config
        try:
            await self.api.start()
        except Exception as exc:  # release the hardware we just configured
            self._refused()
            raise StartupError(f"cannot start the Zenoh API ({self.listen or cfg.zenoh.listen}): {exc}") from exc
        for sig in self.link.signals:
            self._loop.add_signal_handler(sig, self._on_signal, sig)
        try:
            await self.link.go_live()
        except (HardwareError, CycleProcessError) as exc:
            await self.api.close()
            self.api = None
            if isinstance(exc, CycleProcessError):
                raise StartupError(f"the cycle process: {exc}") from None
            raise

    async def _bring_up(self) -> None:
        """Configure and read the hardware, drives disabled (wherever the cycle runs, it reports how it went)."""
        assert self._loop is not None
        realtime = self.loaded.config.realtime
        self.link.realtime_report.update(self.client_report)
        self.link.realtime_report["cpu_dma_latency"] = self.cpu_latency.hold(realtime.cpu_dma_latency_us)
        self.link.watch(self._loop, self._publish)
        try:
            await self.link.bring_up(self.telemetry)
        except CycleProcessError as exc:
            self._on_wake()
            raise StartupError(f"the cycle process: {exc}") from None

    def _refused(self) -> None:
        """The API did not come up: release whatever hardware was configured (none if it failed to open)."""
        self.api = None
        self.link.refused()

    def request_stop(self) -> None:
        """Stop as on SIGTERM (tests and embedding code)."""
        self._stopping.set()

    async def _wait_for_stop(self) -> int:
        ping = self.notifier.ping_period
        tick = SERVICE_TICK if ping is None else min(SERVICE_TICK, ping)
        while not self._stopping.is_set():
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._stopping.wait(), timeout=tick if self.ready else READY_POLL)
            if self.api is not None and self.link.stopping():
                self.api.withdraw()  # the main process is stopping the cycle: clients see the robot go now
            ended = self.link.gone()
            if ended is not None:
                code, why = ended
                self._on_wake()  # what it said last
                if why:
                    log.error("%s", why)
                    self.notifier.status(why)
                    if self.triggers is not None:  # the cycle's last seconds are in the log: the black box keeps them
                        self.triggers.trigger(STALL, why)
                return code
            self.service.tick(asyncio.get_running_loop().time(), self.link, True)
        return 0

    def _open_telemetry(self) -> None:
        if not self.loaded.config.telemetry.enabled:
            return
        from hild.telemetry import Telemetry, TelemetryError  # rerun lives in the telemetry room

        try:
            restarted = self.link.restarted_after is not None
            self.telemetry = Telemetry.from_config(self.loaded, self.link.telemetry_stats, keep_existing=restarted)
        except TelemetryError as exc:
            raise StartupError(f"telemetry: {exc}") from exc

    async def close_telemetry(self) -> None:
        """Flush and close the recording (bounded in time: an unreachable viewer never holds up the stop)."""
        telemetry, self.telemetry = self.telemetry, None
        if telemetry is None:
            return
        await asyncio.to_thread(telemetry.close)
        if self._telemetry_task is not None:
            self._telemetry_task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await self._telemetry_task
            self._telemetry_task = None

    # ---- recording -----------------------------------------------------------------------------------------------
    def _build_recorder(self) -> Recorder | None:
        """The recorder (not started yet), when recording is enabled and the cycle writes a cycle log."""
        if not self.loaded.config.recording.enabled:
            return None
        if self.link.cycle_log() is None:
            log.warning("recording: this cycle writes no cycle log; recording is off")
            return None
        return Recorder.from_config(self.loaded, self.link, self._recorder_said)

    async def _open_recorder(self) -> None:
        if self.recorder is None:
            return
        try:
            await self.recorder.open()
        except RecordError as exc:  # the robot runs on; record start says why it cannot
            log.error("%s; the daemon runs without recording", exc)
            self.link.events.emit("error", "recorder", f"{exc}; the daemon runs without recording")

    def _recorder_said(self, level: str, text: str) -> None:
        """An event of the recorder's own (recording started, disk full …): on the daemon's event stream."""
        if self._link_closed:
            log.log(logging.ERROR if level == "error" else logging.INFO, "[recorder] %s", text)
            return
        self.link.events.emit(level, "recorder", text)
        if self._loop is not None:
            self._loop.call_soon(self._drain_if_open)  # a cycle elsewhere rings only for its own events

    def _drain_if_open(self) -> None:
        if not self._link_closed:
            self._on_wake()

    def _start_triggers(self) -> None:
        """The black box's triggers, once the cycle is live (a stall means something only then)."""
        sec = self.loaded.config.recording
        recorder = self.recorder
        if recorder is None or not recorder.alive or sec.blackbox_seconds <= 0 or not sec.blackbox_on:
            return
        assert self._loop is not None
        self.triggers = BlackBoxTriggers(
            self.link,
            lambda reason: recorder.blackbox(reason),
            sec.blackbox_on,
            sec.stall_after,
            live=lambda: not self.link.stopping(),
        )
        self._triggers_task = self._loop.create_task(self.triggers.run(), name="hild-blackbox-triggers")

    async def _stop_triggers(self) -> None:
        """No more triggers (the stop itself stalls the cycle); a burst still waiting is written now."""
        task, self._triggers_task = self._triggers_task, None
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        if self.triggers is not None:
            await self.triggers.flush()

    async def close_recorder(self) -> None:
        """Stop the open episode (closed, complete) and the recorder process; bounded in time."""
        await self._stop_triggers()
        recorder, self.recorder = self.recorder, None
        if recorder is None:
            return
        await recorder.close()
        if not self._link_closed:
            self._on_wake()  # its last words

    async def _shutdown(self) -> None:
        await self._stop_triggers()
        if self.api is not None:
            self.api.withdraw()  # first: clients see the robot go while it descends and releases
        descent = self.loaded.config.safety.stop_descent
        words = f"a {descent:g} s damped descent" if descent else "holding every joint"
        self.notifier.stopping(f"stopping: {words}, then releasing the hardware")
        timeout = CYCLE_JOIN_TIMEOUT + descent  # the cycle keeps its pace through the descent
        stopped = await self.link.stop(timeout)
        if not stopped:
            log.error("the cycle did not stop within %g s", timeout)
        self._on_wake()
        await self.close_recorder()  # after the cycle stopped: the episode ends with the stop (descent, release)
        self.link.close()
        self._link_closed = True
        await self.close_telemetry()
        if self.api is not None:
            await self.api.close()
        self.cpu_latency.release()
        self.notifier.status("stopped: hardware released" if stopped else "stopped: the cycle did not stop")
        log.info("stopped")


def run_daemon(loaded: LoadedConfig, listen: list[str] | None = None) -> int:
    """``hild run``: until a signal; returns the process exit code. Start-up failures are reported, not raised.

    The default is the three processes (:mod:`hild.main.process`); ``realtime.cycle_process: false`` is one process,
    the daemon with the cycle on a thread of its own."""
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
        if isinstance(exc, StartRefused):
            log.error("start-up failed; nothing was opened: %s", exc)
        elif daemon.link.releases_hardware:
            log.error("start-up failed; the hardware was released: %s", exc)
        else:  # the main process stops the cycle process, and says what became of the hardware
            log.error("start-up failed: %s", exc)
        daemon.notifier.status(f"start-up failed: {exc}")
        daemon.link.start_failed()
        return 1
    finally:
        daemon.cpu_latency.release()
        daemon.notifier.close()
