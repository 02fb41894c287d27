"""The client domain's side of a cycle that runs in a process of its own.

:class:`RemoteCycle` meets :class:`hild.daemon.link.CycleLink` for the API and the daemon: requests go into the
shared region's queue (a full queue refuses at once, as the engine's own does), e-stops through their own counter
(never queued behind anything), and replies, events and snapshots come back when the cycle wakes this process and
the loop calls :meth:`RemoteCycle.take`. The controllers' API halves are built here first: building them carves
the region the cycle process then finds.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import itertools
import os
import pickle
import subprocess
import sys
import threading
from dataclasses import dataclass
from typing import Any

from hild.config.loader import LoadedConfig
from hild.crossing.cells import REGION_BYTES, REQUESTS, Ask, EngineCells, Phase, Vital
from hild.crossing.events import Event, EventLog
from hild.crossing.mailboxes import Shared
from hild.crossing.region import Region
from hild.crossing.requests import Estop, Refused, Request
from hild.crossing.snapshot import Snapshot
from hild.crossing.status import loop_status, render_status
from hild.cycle.process import CycleSpec, TelemetryRing

GO_TIMEOUT = 120.0  # s: a cycle process brought up but never told to go releases the hardware and exits
PHASE_POLL = 0.005  # s
SNAPSHOT_TRIES = 1000  # copies of a snapshot the cycle overtook, taken again at once (it writes one in µs)


class CycleProcessError(RuntimeError):
    """The cycle process failed to start, or ended."""


@dataclass(frozen=True)
class Attachment:
    """How a client domain started by the daemon's main process finds the crossing it carved."""

    region_fd: int
    region_size: int
    wakeup_fd: int
    parent_pid: int  # the main process: when it is gone, so is the unit
    restarted_after: str | None = None  # why the previous client domain ended; None for the first


class Crossing:
    """The shared region with the engine's cells and the controllers' API halves, and the wake-up eventfd: all a client
    domain needs to reach a cycle process. Carved once (:meth:`carve`: building the halves lays the region out);
    a client domain started later finds the same cells (:meth:`attach`)."""

    def __init__(self, loaded: LoadedConfig, region: Region, wakeup_fd: int, *, create: bool) -> None:
        from hild.daemon.halves import api_halves  # builds every controller plugin: only when the cycle is elsewhere

        self.region = region
        self.wakeup_fd = wakeup_fd
        self.events = EventLog()  # the API halves' events (refused goals …): the client domain's own
        self.halves = api_halves(loaded, Shared(region, create=create), self.events.emit)
        self.cells = EngineCells(region, len(loaded.config.joints), create=create)

    @classmethod
    def carve(cls, loaded: LoadedConfig) -> Crossing:
        wakeup = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
        return cls(loaded, Region(REGION_BYTES), wakeup, create=True)

    @classmethod
    def attach(cls, loaded: LoadedConfig, at: Attachment) -> Crossing:
        return cls(loaded, Region.attach(at.region_fd, at.region_size), at.wakeup_fd, create=False)

    def attachment(self, parent_pid: int, restarted_after: str | None = None) -> Attachment:
        return Attachment(self.region.fd, self.region.size, self.wakeup_fd, parent_pid, restarted_after)

    def spawn_cycle(self, loaded: LoadedConfig, telemetry: TelemetryRing | None = None) -> subprocess.Popen[bytes]:
        """Start the cycle process as a child of this process (which it watches: it stops when this one is
        gone)."""
        spec = CycleSpec(loaded, self.region.fd, self.region.size, self.wakeup_fd, os.getpid(), GO_TIMEOUT, telemetry)
        process = subprocess.Popen(
            [sys.executable, "-m", "hild.cycle.process"],
            stdin=subprocess.PIPE,
            pass_fds=(self.region.fd, self.wakeup_fd),
        )
        assert process.stdin is not None
        with process.stdin as stdin:
            stdin.write(pickle.dumps(spec, pickle.HIGHEST_PROTOCOL))
        return process


class RemoteCycle:
    inputs_on_arrival = True  # nothing for the cycle to take: inputs are validated and handed over as they arrive

    def __init__(self, loaded: LoadedConfig, crossing: Crossing | None = None) -> None:
        """With ``crossing`` None, this process carves the region and starts the cycle process itself
        (:meth:`spawn`); else the cycle process another process started is reached through it."""
        cfg = loaded.config
        self.loaded = loaded
        self.robot = cfg.robot.name
        self.joints: tuple[str, ...] = tuple(cfg.joints)
        self.update_rate = cfg.update_rate
        self.stop_descent = cfg.safety.stop_descent
        self.max_consecutive_overruns = cfg.safety.max_consecutive_overruns
        self.take_inputs = None
        self.crossing = crossing or Crossing.carve(loaded)
        self.events = self.crossing.events  # the client domain's own events, stamped with the cycle clock
        self.events.now = lambda: self.t
        self.owns_cycle = crossing is None
        self.region = self.crossing.region
        self._halves = self.crossing.halves
        self.cells = self.crossing.cells
        self.stats = self.cells.stats
        self.wakeup_fd = self.crossing.wakeup_fd
        self.process: subprocess.Popen[bytes] | None = None
        self._lock = threading.Lock()  # request ids, futures, the snapshot cache: several client threads
        # Ids unique across client domains: replies to a dead one's requests may still be in the queue.
        self._ids = itertools.count((os.getpid() << 32) + 1)
        self._pending: dict[int, concurrent.futures.Future[Any]] = {}
        self._estops: list[tuple[int, concurrent.futures.Future[Any]]] = []
        self._snapshot: Snapshot | None = None
        self._estop_reply: dict[str, Any] = {"deactivated": []}
        self.realtime_report: dict[str, str] = {}  # what the client domain set up (its CPUs, the DMA latency hold)
        self._events_lost = int(self.cells.vitals[Vital.EVENTS_LOST])  # as last reported (by a predecessor too)

    @classmethod
    def attach(cls, loaded: LoadedConfig, at: Attachment) -> RemoteCycle:
        """Reach the cycle process the daemon's main process started, through the crossing it carved."""
        return cls(loaded, Crossing.attach(loaded, at))

    @property
    def cycle_pid(self) -> int:
        return int(self.cells.vitals[Vital.PID])

    # ---- the process --------------------------------------------------------------------------------------
    def spawn(self, telemetry: TelemetryRing | None = None) -> None:
        self.process = self.crossing.spawn_cycle(self.loaded, telemetry)

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

    def stop(self) -> None:
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
        """Started by this process: whether it runs. Started by the main process (which ends this one when the
        cycle process dies): whether it has not failed or stopped."""
        if self.process is not None:
            return self.process.poll() is None
        return not self.owns_cycle and self.phase not in (Phase.FAILED, Phase.STOPPED)

    @property
    def exit_code(self) -> int | None:
        return None if self.process is None else self.process.poll()

    def close(self) -> None:
        os.close(self.wakeup_fd)

    # ---- reading back -------------------------------------------------------------------------------------------
    @property
    def cycle(self) -> int:
        return int(self.cells.vitals[Vital.CYCLE])

    @property
    def t(self) -> float:
        return float(self.cells.clock[0])

    @property
    def change_seq(self) -> int:
        return int(self.cells.vitals[Vital.CHANGE_SEQ])

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
        if not self.owns_cycle:  # this client domain was started by the main process, maybe after another
            restarts = int(self.cells.asks[Ask.CLIENT_LOST])
            status["realtime"]["client_process"] = f"pid {os.getpid()}, {restarts} restart(s)"
        return status

    def controllers(self) -> dict[str, Any]:
        return dict(self._halves)

    # ---- requests -----------------------------------------------------------------------------------------------
    def request(self, request: Request) -> concurrent.futures.Future[Any]:
        if isinstance(request, Estop):
            return self.request_estop()
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
