"""The client domain's side of a cycle that runs in a process of its own.

:class:`RemoteCycle` meets :class:`hild.daemon.link.CycleLink` for the API and the daemon: requests go into the
shared region's queue (a full queue refuses at once, as the engine's own does), e-stops through their own counter
(never queued behind anything), and replies, events and snapshots come back when the cycle wakes this process and
the loop calls :meth:`RemoteCycle.take`. The controllers' API halves are built here first: building them carves
their doors in the region the cycle process then finds.

Who started the cycle process is the one thing that differs, and each case is a class of its own, so the daemon
never asks: :class:`AttachedCycle` under ``hild run`` (the main process started it and speaks for the unit), and
:class:`SpawnedCycle` when this process started it itself (embedding, ``hild bench``, tests).
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import itertools
import os
import signal
import subprocess
import threading
import time
from collections.abc import Callable
from typing import Any

from hild.config.loader import LoadedConfig
from hild.crossing.attach import Attachment, Crossing
from hild.crossing.cells import REQUESTS, Ask, ClientPhase, ClientVital, Phase, Vital
from hild.crossing.cyclelog import CycleLogPlace, capacity_of
from hild.crossing.events import Event, EventLog
from hild.crossing.requests import Estop, Load, Refused, Request, SetParams, Unload
from hild.crossing.snapshot import Snapshot
from hild.crossing.status import loop_status, render_status
from hild.crossing.telemetry import TelemetryRing
from hild.cycle.process import spawn
from hild.daemon.halves import ApiHalves, configured_loads
from hild.main.notify import ServiceReport, SilentReport, SystemdNotifier

PHASE_POLL = 0.005  # s
STOP_JOIN_TIMEOUT = 5.0  # s: a cycle process told to stop before it went live releases the hardware by then
LOSS_ACK_TIMEOUT = 5.0  # s: a restarted client domain waits this long for the cycle to end its predecessor's goals
SNAPSHOT_TRIES = 1000  # copies of a snapshot the cycle overtook, taken again at once (it writes one in µs)


def _refused(reason: str) -> concurrent.futures.Future[Any]:
    future: concurrent.futures.Future[Any] = concurrent.futures.Future()
    future.set_exception(Refused(reason))
    return future


class CycleProcessError(RuntimeError):
    """The cycle process failed to start, or ended."""


class RemoteCycle:
    """The cycle process as the client domain (or the main process, which only reads it) reaches it."""

    inputs_on_arrival = True  # nothing for the cycle to take: inputs are validated and handed over as they arrive
    restarted_after: str | None = None

    def __init__(self, loaded: LoadedConfig, crossing: Crossing, loads: list[Load] | None = None) -> None:
        """``loads``: the controllers whose API halves to build (default: the config's; a restarted client domain
        passes the cycle's, which include those loaded while the robot ran)."""
        cfg = loaded.config
        self.loaded = loaded
        self.robot = cfg.robot.name
        self.joints: tuple[str, ...] = tuple(cfg.joints)
        self.update_rate = cfg.update_rate
        self.stop_descent = cfg.safety.stop_descent
        self.max_consecutive_overruns = cfg.safety.max_consecutive_overruns
        self.take_inputs = None
        self.crossing = crossing
        self.events = EventLog()  # the client domain's own (the API halves' refused goals …), on the cycle clock
        self.events.now = lambda: self.t
        self.region = crossing.region
        self.halves = ApiHalves(
            loaded, configured_loads(loaded) if loads is None else loads, crossing.doors, self.events.emit
        )
        self.cells = crossing.cells
        self.stats = self.cells.stats
        self.wakeup_fd = self.crossing.wakeup_fd
        self.process: subprocess.Popen[bytes] | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._lock = threading.Lock()  # request ids, futures, the snapshot cache: several client threads
        # Ids unique across client domains: replies to a dead one's requests may still be in the queue.
        self._ids = itertools.count((os.getpid() << 32) + 1)
        self._pending: dict[int, concurrent.futures.Future[Any]] = {}
        self._estops: list[tuple[int, concurrent.futures.Future[Any]]] = []
        self._snapshot: Snapshot | None = None
        self._estop_reply: dict[str, Any] = {"deactivated": []}
        self.realtime_report: dict[str, str] = {}  # what the client domain set up (its CPUs, the DMA latency hold)
        self._events_lost = int(self.cells.vitals[Vital.EVENTS_LOST])  # as last reported (by a predecessor too)

    @property
    def cycle_pid(self) -> int:
        return int(self.cells.vitals[Vital.PID])

    # ---- the process --------------------------------------------------------------------------------------
    @property
    def phase(self) -> Phase:
        return Phase(int(self.cells.vitals[Vital.PHASE]))

    async def brought_up(self) -> None:
        """Wait until the cycle process has configured and read the hardware (drives still disabled); raise
        :class:`CycleProcessError` with its reason if it could not."""
        while self.phase is Phase.STARTING:
            if not self.alive():
                break
            await asyncio.sleep(PHASE_POLL)
        if self.phase is not Phase.BROUGHT_UP:
            raise CycleProcessError(self.failure())

    async def live(self) -> None:
        """Tell the cycle process to enable the drives and run; wait until it does."""
        self.cells.asks[Ask.GO] = 1
        while self.phase is Phase.BROUGHT_UP and self.alive():
            await asyncio.sleep(PHASE_POLL)
        if self.phase is not Phase.LIVE:
            raise CycleProcessError(self.failure())

    def failure(self) -> str:
        text = self.cells.failure.take()
        if text is not None:
            return str(text)
        code = None if self.process is None else self.process.poll()
        return f"the cycle process ended (exit code {code})" if code is not None else "the cycle process is stuck"

    def ask_stop(self) -> None:
        """Ask the cycle to stop (it descends if configured, holds, releases the hardware, exits)."""
        self.cells.asks[Ask.STOP] = 1

    def join(self, timeout: float) -> bool:
        """Wait for the process to end (any thread but the loop's); True if it did."""
        if self.process is None:
            return True
        try:
            self.process.wait(timeout)
        except subprocess.TimeoutExpired:
            return False
        return True

    def kill(self) -> None:
        if self.process is not None and self.process.poll() is None:
            self.process.kill()
            self.process.wait()

    def alive(self) -> bool:
        """Started by this process: whether it runs. Started by another (which ends this one when the cycle
        process dies): whether it has not failed or stopped."""
        if self.process is not None:
            return self.process.poll() is None
        return self.phase not in (Phase.FAILED, Phase.STOPPED)

    @property
    def exit_code(self) -> int | None:
        return None if self.process is None else self.process.poll()

    # ---- reading back -------------------------------------------------------------------------------------------
    @property
    def cycle(self) -> int:
        return int(self.cells.vitals[Vital.CYCLE])

    @property
    def t(self) -> float:
        return float(self.cells.clock[0])

    @property
    def change_seq(self) -> int:
        """The cycle's, plus this side's own changes: a controller's API half comes and goes with its reply."""
        return int(self.cells.vitals[Vital.CHANGE_SEQ]) + self.halves.seq

    @property
    def started(self) -> bool:
        return bool(self.cells.vitals[Vital.STARTED])

    @property
    def python_threads(self) -> int:
        return int(self.cells.vitals[Vital.PYTHON_THREADS])

    def snapshot(self) -> Snapshot:
        """The newest snapshot: at least as new as ``change_seq`` said (a copy the cycle overtook is taken again),
        so a reply cached under a ``change_seq`` is never built from an older one."""
        wanted = self.change_seq
        with self._lock:
            for _ in range(SNAPSHOT_TRIES):
                fresh = self.cells.snapshot.take()
                if fresh is not None:
                    self._snapshot = fresh  # type: ignore[assignment]
                if self._snapshot is not None and self._snapshot.change_seq >= wanted:
                    break
            if self._snapshot is None:
                raise CycleProcessError("the cycle process has not reported yet")
            return self._snapshot

    def overall_mode(self) -> str:
        return self.snapshot().mode

    def status(self) -> dict[str, Any]:
        loop = loop_status(self.update_rate, self.loaded.config.clock.source, self.stats)
        status = render_status(self.robot, self.snapshot(), self.t, self.cells.clock[1:].tolist(), loop)
        status["realtime"].update(self.realtime_report)
        pid = self.cycle_pid
        if pid:
            status["realtime"]["cycle_process"] = f"pid {pid}, {self.python_threads} Python thread(s)"
        status["realtime"].update(self._process_report())
        return status

    def _process_report(self) -> dict[str, str]:
        return {}

    def controllers(self) -> dict[str, Any]:
        return self.halves.current()

    def cycle_log(self) -> tuple[int, CycleLogPlace] | None:
        """The region's fd and where the cycle log is in it (None: recording is off, the cycle writes none)."""
        place = self.cells.cycle_log_place
        return None if place is None else (self.region.fd, place)

    # ---- requests -----------------------------------------------------------------------------------------------
    def request(self, request: Request) -> concurrent.futures.Future[Any]:
        """Into the request queue; a load's API half is built first (its cells carved), an unload's dropped after."""
        match request:
            case Estop():
                return self.request_estop()
            case Load():
                try:
                    load, half = self.halves.prepare(request)
                except Exception as exc:
                    return _refused(f"{request.name}: building a {request.type} failed: {type(exc).__name__}: {exc}")
                future = self._queue(load)
                future.add_done_callback(lambda f: self.halves.loaded_one(load, half, f))
                return future
            case Unload(name):
                future = self._queue(request)
                future.add_done_callback(lambda f: self.halves.unloaded(name, f))
                return future
            case SetParams(name, params):
                future = self._queue(request)
                future.add_done_callback(lambda f: self.halves.params_set(name, params, f))
                return future
        return self._queue(request)

    def _queue(self, request: Request) -> concurrent.futures.Future[Any]:
        future: concurrent.futures.Future[Any] = concurrent.futures.Future()
        with self._lock:
            ident = next(self._ids)
            if len(self._pending) >= REQUESTS or not self.cells.requests.offer((ident, request)):
                future.set_exception(Refused("too many pending requests; try again"))
                return future
            self._pending[ident] = future
            future.set_running_or_notify_cancel()  # in the queue: it will be applied, it cannot be withdrawn
        return future

    def request_estop(self) -> concurrent.futures.Future[Any]:
        """Never refused, never queued: the cycle compares a counter at the start of every cycle."""
        future: concurrent.futures.Future[Any] = concurrent.futures.Future()
        with self._lock:
            counter = int(self.cells.asks[Ask.ESTOP]) + 1
            self._estops.append((counter, future))
            self.cells.asks[Ask.ESTOP] = counter
        return future

    def take(self) -> list[Event]:
        """What the cycle rang for: answer replies and e-stops, and return its events (the loop's thread)."""
        with contextlib.suppress(BlockingIOError):
            os.eventfd_read(self.wakeup_fd)
        while (record := self.cells.replies.poll()) is not None:
            ident, ok, value = record  # type: ignore[misc]
            with self._lock:
                future = self._pending.pop(ident, None)
            if future is None:
                continue
            if ok:
                future.set_result(value)
            else:
                kind, text, details = value
                error = Refused(text, **details) if kind == "Refused" else RuntimeError(f"{kind}: {text}")
                future.set_exception(error)
        self._answer_estops()
        events = []
        while (item := self.cells.events.poll()) is not None:
            events.append(Event(*item))  # type: ignore[misc]
        events.extend(self.events.drain())
        lost = int(self.cells.vitals[Vital.EVENTS_LOST])
        if lost != self._events_lost:
            text = f"{lost - self._events_lost} events of the cycle were lost: this process did not drain them in time"
            events.append(Event(self.t, "warning", "cycle", text))
            self._events_lost = lost
        return events

    def _answer_estops(self) -> None:
        done = int(self.cells.vitals[Vital.ESTOP_DONE])
        with self._lock:
            if not self._estops or self._estops[0][0] > done:
                return
            reply = self.cells.estop_reply.take()
            if reply is not None:
                self._estop_reply = reply[1]  # type: ignore[index]
            answered = [f for n, f in self._estops if n <= done]
            self._estops = [(n, f) for n, f in self._estops if n > done]
        for future in answered:
            future.set_result(self._estop_reply)

    def abandon(self, reason: str) -> None:
        """The cycle process is gone: every request still waiting gets ``reason``."""
        with self._lock:
            waiting = [*self._pending.values(), *(f for _, f in self._estops)]
            self._pending.clear()
            self._estops.clear()
        for future in waiting:
            if not future.done():
                future.set_exception(Refused(reason))

    # ---- the daemon's lifecycle (hild.daemon.link.CycleHost) -------------------------------------------------
    def watch(self, loop: asyncio.AbstractEventLoop, on_events: Callable[[list[Event]], None]) -> None:
        """Whenever the cycle rings (its eventfd): answer its replies, hand its events to ``on_events``."""
        self._loop = loop
        loop.add_reader(self.wakeup_fd, lambda: on_events(self.take()))

    def close(self) -> None:
        """The daemon stops: no more wake-ups, and whatever still waits for a reply is answered."""
        if self._loop is not None:
            self._loop.remove_reader(self.wakeup_fd)
            self._loop = None
        self.abandon("the daemon stopped")

    @property
    def telemetry_stats(self) -> None:
        return None  # the cycle process records its loop statistics into the ring itself

    def describe(self) -> str:
        return f", the cycle in process {self.cycle_pid}"

    def serving(self) -> None:
        """The API is up (nothing to tell when nobody else watches this process)."""


class SpawnedCycle(RemoteCycle):
    """A cycle process this process carves the region for, starts, stops and speaks for (embedding, the bench,
    tests): the daemon is the unit's top process."""

    signals = (signal.SIGINT, signal.SIGTERM)
    signal_meaning = "holding every joint, then stopping"
    releases_hardware = True

    def __init__(self, loaded: LoadedConfig) -> None:
        super().__init__(loaded, Crossing.carve(len(loaded.config.joints), capacity_of(loaded.config)))
        self.main_pid = os.getpid()  # the unit's top process
        self._wakeup_closed = False

    def service_report(self, notifier: SystemdNotifier) -> ServiceReport:
        return ServiceReport(notifier, self.max_consecutive_overruns)

    async def bring_up(self, telemetry: Any) -> None:
        """Start the cycle process, and wait until it has configured and read the hardware (drives disabled)."""
        self.process = spawn(self.loaded, self.crossing, TelemetryRing(*telemetry.ring_layout) if telemetry else None)
        try:
            await self.brought_up()
        except CycleProcessError:
            await asyncio.to_thread(self.join, STOP_JOIN_TIMEOUT)
            raise

    async def go_live(self) -> None:
        await self.live()

    def gone(self) -> tuple[int, str | None] | None:
        if self.alive():
            return None
        return 1, f"the cycle process ended unexpectedly (exit code {self.exit_code})"

    def stopping(self) -> bool:
        return False  # a stop begins here (a signal, request_stop)

    async def stop(self, timeout: float) -> bool:
        """Ask the cycle to stop (descent, hold, release) and wait; a cycle that does not is killed (the drives'
        own watchdogs take over, as on any crash). True if it stopped in time."""
        self.ask_stop()
        stopped = await asyncio.to_thread(self.join, timeout)
        if not stopped:
            self.kill()
        return stopped

    def refused(self) -> None:
        """The API did not come up: brought up or not, the cycle process releases the hardware and exits."""
        self.ask_stop()
        self.join(STOP_JOIN_TIMEOUT)

    def start_failed(self) -> None:
        """Nobody else to tell: this process is the unit's top process."""

    def close(self) -> None:
        super().close()
        if not self._wakeup_closed:  # once: the number may belong to another file afterwards
            self._wakeup_closed = True
            os.close(self.wakeup_fd)  # carved here: nobody else holds it once the cycle process has ended


def _cycle_loads(crossing: Crossing) -> list[Load] | None:
    """The controllers the cycle has loaded, as it handed them over (None if it never did: the config's then)."""
    cell = crossing.cells.loads
    for _ in range(SNAPSHOT_TRIES):  # a copy the cycle overtook is taken again at once
        loads = cell.take()
        if loads is not None:
            return list(loads)  # type: ignore[call-overload]
    return None


class AttachedCycle(RemoteCycle):
    """Under ``hild run``: the cycle process the daemon's main process started, reached through the crossing it
    carved. The main process speaks for the unit to systemd, takes SIGINT (a terminal's Ctrl-C reaches every
    process) and stops the cycle; this client domain only serves, and may be one restarted after another."""

    signals = (signal.SIGTERM,)
    signal_meaning = "the client domain stops"
    releases_hardware = False  # the main process stops the cycle process

    def __init__(self, loaded: LoadedConfig, at: Attachment) -> None:
        crossing = Crossing.attach(len(loaded.config.joints), at, capacity_of(loaded.config))
        super().__init__(loaded, crossing, None if at.restarted_after is None else _cycle_loads(crossing))
        self.parent_pid = self.main_pid = at.parent_pid  # stopping this process only makes the main one start another
        self.restarted_after = at.restarted_after

    def service_report(self, notifier: SystemdNotifier) -> SilentReport:
        return SilentReport()

    async def bring_up(self, telemetry: Any) -> None:
        """Say that the cycle process may be started (the main process does it), and wait until it has brought the
        hardware up. A restarted client domain finds it live, and first waits until the cycle has ended what its
        predecessor ran (so no goal of the dead domain starts after this one answers)."""
        self.cells.telemetry.put(TelemetryRing(*telemetry.ring_layout) if telemetry else None)
        self.cells.client[ClientVital.PID] = os.getpid()
        self.cells.client[ClientVital.PHASE] = ClientPhase.OPEN
        if self.restarted_after is None:
            await self.brought_up()
            return
        deadline = time.monotonic() + LOSS_ACK_TIMEOUT
        while self.cells.vitals[Vital.CLIENT_LOST_SEEN] != self.cells.asks[Ask.CLIENT_LOST]:
            if not self.alive() or time.monotonic() > deadline:
                raise CycleProcessError("it did not take over from the lost client domain")
            await asyncio.sleep(PHASE_POLL)
        self.events.emit(
            "warning",
            "daemon",
            f"the client domain was restarted ({self.restarted_after}); clients may reconnect and resend",
        )

    async def go_live(self) -> None:
        if self.phase is not Phase.LIVE:  # a restarted client domain finds it running
            await self.live()

    def serving(self) -> None:
        self.cells.client[ClientVital.PHASE] = ClientPhase.SERVING

    def gone(self) -> tuple[int, str | None] | None:
        if os.getppid() != self.parent_pid:
            return 1, "the daemon's main process is gone: stopping"
        if self.alive():
            return None
        if self.cells.asks[Ask.STOP]:
            return 0, None  # the main process stopped it: ours is next
        return 1, f"the cycle process ended unexpectedly (phase {self.phase.name.lower()})"

    def stopping(self) -> bool:
        return bool(self.cells.asks[Ask.STOP])  # the main process has asked the cycle to stop: descent, release

    async def stop(self, timeout: float) -> bool:
        return True  # the main process stops the cycle process (it did already, unless this domain alone stops)

    def refused(self) -> None:
        """Nothing to release here: the main process stops the cycle process when this domain ends."""

    def start_failed(self) -> None:
        """Logged here, with the reason only this domain knows: the main process adds only what became of the
        hardware."""
        self.cells.client[ClientVital.PHASE] = ClientPhase.FAILED

    def close(self) -> None:
        super().close()
        self.cells.client[ClientVital.PHASE] = ClientPhase.STOPPED

    def _process_report(self) -> dict[str, str]:
        restarts = int(self.cells.asks[Ask.CLIENT_LOST])
        return {"client_process": f"pid {os.getpid()}, {restarts} restart(s)"}
