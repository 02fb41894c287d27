"""The cycle process: the engine alone, paced on its main thread, reached only through the shared region.

Started by the main process (embedded: by the client domain's :class:`hild.daemon.remote.SpawnedCycle`) as
``python -m hild.cycle.process``
with a pickled :class:`CycleSpec` on its standard input and two inherited file descriptors: the shared region and
the wake-up eventfd (the client domain's loop waits on it). It runs no Zenoh, no asyncio and, once live, no Python
thread but the cycle: nothing a client does can take its interpreter's lock.

Around each ``engine.step`` (:class:`CrossingCycle`): before, it takes what the client domain asked (stop, e-stop,
queued requests); after, it hands out what changed (vitals, the snapshot when ``change_seq`` moved, events,
replies) and wakes the client domain at most once. It stops when asked, on SIGTERM, or when its parent is gone (the
arm is then held and released as on any stop); SIGINT is left to the main process (embedded: the daemon), which
asks for the stop itself.
"""

from __future__ import annotations

import concurrent.futures
import gc
import logging
import mmap
import os
import pickle
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from typing import Any

from hild import plugins
from hild.config.loader import LoadedConfig
from hild.crossing.attach import Crossing
from hild.crossing.cells import Ask, EngineCells, Phase, Vital
from hild.crossing.cyclelog import capacity_of
from hild.crossing.events import EventLog, log_event
from hild.crossing.mailboxes import Shared
from hild.crossing.region import Region
from hild.crossing.telemetry import TelemetryRing
from hild.cycle.engine import Engine
from hild.cycle.pacing import CycleThread
from hild.cycle.realtime import apply_process_settings, freeze_heap, thaw_heap

log = logging.getLogger("hild.cycle")

PARENT_CHECK = 0.1  # s: how often the cycle looks whether the daemon that started it still exists
GO_POLL = 0.001  # s: while brought up, how often it looks for the client domain's go
VITALS_EVERY = 0.05  # s: each joint's longest silence and the thread count are copied out this often


@dataclass(frozen=True)
class CycleSpec:
    loaded: LoadedConfig
    region_fd: int
    region_size: int
    wakeup_fd: int
    parent_pid: int
    go_timeout: float
    telemetry: TelemetryRing | None = None


class ClientWakeup:
    """Wakes the client domain's loop: ``mark`` when there is something for it, ``send`` once per cycle (one
    eventfd write when marked, never blocking: a full counter would need 2⁶⁴ wake-ups)."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self.marked = False

    def mark(self) -> None:
        self.marked = True

    def send(self) -> None:
        if self.marked:
            self.marked = False
            try:  # noqa: SIM105 — no context manager object per cycle on the cycle thread
                os.eventfd_write(self.fd, 1)
            except BlockingIOError:  # the counter is full: the loop has plenty to read already
                pass


class Outbox:
    """What the cycle hands to the client domain: events, replies, the snapshot and vitals."""

    def __init__(self, cells: EngineCells, wakeup: ClientWakeup) -> None:
        self.cells = cells
        self.wakeup = wakeup
        self.orphaned = False  # the daemon is gone: nobody drains the queue, so events go to this process's log
        self._lost = 0

    def events(self, log_: EventLog) -> None:
        for event in log_.drain():
            if self.orphaned:
                log_event(event)
                continue
            record = (event.stamp, event.level, event.source, event.message)
            if self.cells.events.offer(record):
                continue
            self._lost += 1  # the client domain is not draining: count, never wait
            self.cells.vitals[Vital.EVENTS_LOST] = self._lost
        self.wakeup.mark()

    def reply(self, ident: int, future: concurrent.futures.Future[Any]) -> None:
        error = future.exception()
        if error is None:
            record: tuple[Any, ...] = (ident, True, future.result())
        else:
            record = (ident, False, (type(error).__name__, str(error), getattr(error, "details", {})))
        if not self.cells.replies.offer(record):  # cannot happen while the client keeps REQUESTS in flight
            log.error("reply %d lost: the replies queue is full", ident)
        self.wakeup.mark()

    def failure(self, text: str, log_: EventLog) -> None:
        self.cells.failure.put(text)
        self.events(log_)
        self.cells.vitals[Vital.PHASE] = Phase.FAILED
        self.wakeup.send()


class CrossingCycle(CycleThread):
    """The cycle thread's pacing, run on the process's main thread, with the shared region around each step."""

    def __init__(self, engine: Engine, cells: EngineCells, outbox: Outbox, parent_pid: int) -> None:
        cfg = engine.loaded.config
        super().__init__(engine, cfg.clock.source, cfg.clock.real_time_factor, cfg.realtime)
        self.cells = cells
        self.outbox = outbox
        self.parent_pid = parent_pid
        self.terminated = False  # SIGTERM
        self._estop_seen = int(cells.asks[Ask.ESTOP])
        self._client_lost_seen = int(cells.asks[Ask.CLIENT_LOST])
        self._next_ident = 0
        self._last_change = -1
        self._loads_seen = engine.loads_seq
        self._parent_every = max(1, round(PARENT_CHECK * engine.update_rate))
        self._vitals_every = max(1, round(VITALS_EVERY * engine.update_rate))

    def step(self, t: float, dt: float) -> None:
        engine, cells = self.engine, self.cells
        self._take_asks()
        engine.step(t, dt)
        vitals = cells.vitals
        cells.clock[0] = engine.t
        vitals[Vital.CYCLE] = engine.cycle
        if engine.change_seq != self._last_change:
            self._last_change = engine.change_seq
            cells.snapshot.put(engine.snapshot())
            vitals[Vital.CHANGE_SEQ] = self._last_change  # after the snapshot: whoever sees it finds the snapshot
            self.outbox.wakeup.mark()
        if engine.loads_seq != self._loads_seen:  # a controller loaded or unloaded: rare, after the write
            self._loads_seen = engine.loads_seq
            hand_over_loads(engine, cells)
        if engine.cycle % self._vitals_every == 0:
            cells.clock[1:] = engine.supervisor.longest_silence
            vitals[Vital.PYTHON_THREADS] = threading.active_count()
        if self.outbox.wakeup.marked:
            self.outbox.events(engine.events)
            self.outbox.wakeup.send()

    def _take_asks(self) -> None:
        asks, engine = self.cells.asks, self.engine
        if asks[Ask.STOP] or self.terminated:
            self.stop()
        if engine.cycle % self._parent_every == 0:
            if not self.outbox.orphaned and os.getppid() != self.parent_pid:  # said once: a descent takes a while
                self.outbox.orphaned = True
                engine.events.emit("error", "cycle", "the daemon that started the cycle process is gone: stopping")
                self.stop()
            ring = self.cells.telemetry.take()
            if ring is not None:  # a restarted client domain records from a ring of its own: once per restart
                engine.tap = _attach_telemetry(ring, engine)  # type: ignore[arg-type]
        lost = int(asks[Ask.CLIENT_LOST])
        if lost != self._client_lost_seen:  # before this cycle's requests: none of the old domain's goals starts
            self._client_lost_seen = lost
            engine.client_domain_lost("the client domain ended")
            self.cells.vitals[Vital.CLIENT_LOST_SEEN] = lost
        estop = int(asks[Ask.ESTOP])
        if estop != self._estop_seen:  # applied in this very cycle, whatever the request queue holds
            self._estop_seen = estop
            engine.request_estop().add_done_callback(lambda f, n=estop: self._estop_done(n, f))
        while (record := self.cells.requests.poll()) is not None:
            ident, request = record  # type: ignore[misc]
            engine.request(request).add_done_callback(lambda f, i=ident: self.outbox.reply(i, f))

    def _estop_done(self, counter: int, future: concurrent.futures.Future[Any]) -> None:
        self.cells.estop_reply.put((counter, future.result()))
        self.cells.vitals[Vital.ESTOP_DONE] = counter
        self.outbox.wakeup.mark()


def hand_over_loads(engine: Engine, cells: EngineCells) -> None:
    """How each loaded controller was loaded, for a client domain started later to build their API halves."""
    try:
        cells.loads.put(tuple(engine.loads.values()))
    except ValueError as exc:  # more params than the cell holds: the client domain refuses loads before that
        engine.events.emit("error", "cycle", f"the loaded controllers cannot be handed over: {exc}")


def import_controller_types(engine: Engine) -> None:
    """Import every installed controller type now, at start-up, so that loading one while the robot runs costs the
    cycle its constructor, never a module import. One that cannot be imported is reported and stays unloadable."""
    for name in plugins.available(plugins.CONTROLLERS):
        try:
            plugins.load(plugins.CONTROLLERS, name)
        except Exception as exc:
            engine.events.emit("warning", "cycle", f"controller type {name!r} cannot be imported: {exc}")


def _attach_telemetry(ring: TelemetryRing, engine: Engine) -> Any:
    """Record into the recorder's ring: mapped by its name, without multiprocessing's resource tracker (the daemon
    owns the name and unlinks it)."""
    from hild.crossing.telemetry import TelemetryTap, ring_bytes

    fd = os.open(f"/dev/shm/{ring.name}", os.O_RDWR)
    try:
        mapping = mmap.mmap(fd, ring_bytes(ring.joints, ring.capacity))
    finally:
        os.close(fd)
    return TelemetryTap(ring.joints, ring.capacity, ring.every, engine.stats, memoryview(mapping))


def _wait_for_go(cells: EngineCells, spec: CycleSpec, cycle_terminated: list[bool]) -> bool:
    deadline = time.monotonic() + spec.go_timeout
    while not cells.asks[Ask.GO]:
        if cells.asks[Ask.STOP] or cycle_terminated[0] or os.getppid() != spec.parent_pid:
            return False
        if time.monotonic() > deadline:
            return False
        time.sleep(GO_POLL)
    return True


def run(spec: CycleSpec) -> int:
    cfg = spec.loaded.config
    region = Region.attach(spec.region_fd, spec.region_size)
    cells = EngineCells(region, len(cfg.joints), create=False, cycle_log=capacity_of(cfg))
    outbox = Outbox(cells, ClientWakeup(spec.wakeup_fd))
    cells.vitals[Vital.PID] = os.getpid()
    terminated = [False]
    cycle: CrossingCycle | None = None

    def on_term(signum: int, frame: Any) -> None:
        terminated[0] = True
        if cycle is not None:
            cycle.terminated = True

    signal.signal(signal.SIGTERM, on_term)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches every process: the main process asks the stop
    scratch = EventLog()
    try:
        engine = Engine(
            spec.loaded,
            Shared(region, create=False),
            stats=cells.stats,
            wake_client=outbox.wakeup.mark,
            cycle_log=cells.cycle_log,  # written every cycle; the client domain's recorder maps it (None: off)
        )
    except Exception as exc:
        outbox.failure(f"cannot build {spec.loaded.path}: {exc}", scratch)
        return 1
    engine.realtime_report.update(apply_process_settings(cfg.realtime))
    import_controller_types(engine)
    try:
        engine.bring_up()
    except Exception as exc:
        outbox.failure(str(exc), engine.events)
        return 1
    cells.telemetry.clear()  # the ring in the spec: a newer one is a restarted client domain's
    if spec.telemetry is not None:
        engine.tap = _attach_telemetry(spec.telemetry, engine)
    cycle = CrossingCycle(engine, cells, outbox, spec.parent_pid)
    engine.realtime_report["gc"] = freeze_heap(cfg.realtime)
    cells.snapshot.put(engine.snapshot())
    hand_over_loads(engine, cells)
    cells.vitals[Vital.CHANGE_SEQ] = engine.change_seq
    cells.vitals[Vital.PHASE] = Phase.BROUGHT_UP
    outbox.events(engine.events)
    outbox.wakeup.send()
    if not _wait_for_go(cells, spec, terminated):
        engine.release()
        outbox.events(engine.events)
        cells.vitals[Vital.PHASE] = Phase.STOPPED
        outbox.wakeup.send()
        return 0
    try:
        engine.go_live()
    except Exception as exc:
        outbox.failure(str(exc), engine.events)
        return 1
    cells.vitals[Vital.STARTED] = 1
    cells.vitals[Vital.PHASE] = Phase.LIVE
    cycle.run()  # on this thread: the process's only one; returns once stopped and the hardware released
    cells.snapshot.put(engine.snapshot())
    cells.vitals[Vital.CHANGE_SEQ] = engine.change_seq
    outbox.events(engine.events)
    cells.vitals[Vital.PHASE] = Phase.STOPPED
    outbox.wakeup.send()
    return 1 if cycle.error is not None else 0


GO_TIMEOUT = 120.0  # s: a cycle process brought up but never told to go releases the hardware and exits


def spawn(loaded: LoadedConfig, crossing: Crossing, telemetry: TelemetryRing | None = None) -> subprocess.Popen[bytes]:
    """Start the cycle process as a child of this process (which it watches: it stops when this one is gone),
    reaching ``crossing``: the region and the wake-up eventfd are inherited, the rest is pickled on its stdin."""
    spec = CycleSpec(
        loaded, crossing.region.fd, crossing.region.size, crossing.wakeup_fd, os.getpid(), GO_TIMEOUT, telemetry
    )
    process = subprocess.Popen(
        [sys.executable, "-m", "hild.cycle.process"],
        stdin=subprocess.PIPE,
        pass_fds=(crossing.region.fd, crossing.wakeup_fd),
    )
    assert process.stdin is not None
    with process.stdin as stdin:
        stdin.write(pickle.dumps(spec, pickle.HIGHEST_PROTOCOL))
    return process


def main() -> int:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s hild-cycle: %(message)s")
    spec: CycleSpec = pickle.load(sys.stdin.buffer)
    sys.stdin.close()
    code = run(spec)
    thaw_heap()  # the engine is gone with run(): its extension objects are freed before the interpreter ends
    gc.collect()
    return code


if __name__ == "__main__":
    sys.exit(main())
