"""Telemetry, client-domain side: a shared-memory ring for the cycle, and a recorder process that does all of rerun.

The cycle only calls ``tap.record`` (hild/crossing/telemetry.py), which writes plain numpy rows into a ring in
shared memory. Everything rerun does (building columns, ``send_columns``, 3D poses, file rotation) runs in a
child process (hild/telemetry/worker.py), started with "spawn" so it inherits none of the daemon's threads, at a
low priority. Why a process: a flush is 5–9 ms of Python-side work; inside the daemon (a task or a thread) it holds
the GIL that long, and the API, or a cycle thread of the same process, waits for it. Events go to the child on a
bounded queue (full → dropped and counted); flush/close are commands on a pipe, each acknowledged. This module does
not import rerun: the client domain never loads it.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import multiprocessing as mp
import os
import queue
import threading
import time
import weakref
from collections.abc import Callable, Iterable
from multiprocessing.connection import wait as wait_for_any
from pathlib import Path
from typing import Any

from hild.config.model import TelemetrySection
from hild.crossing.events import Event
from hild.crossing.stats import LoopStats
from hild.crossing.telemetry import SharedRing
from hild.telemetry.errors import TelemetryError
from hild.telemetry.setup import TelemetrySetup

log = logging.getLogger("hild.telemetry")

CLOSE_TIMEOUT = 2.0  # s: close() returns within this, whatever the recorder or a sink does
START_TIMEOUT = 30.0  # s for the recorder process to import rerun, load the model and open every sink
FLUSH_TIMEOUT = 5.0  # s flush() waits for the recorder's acknowledgement
WATCH_PERIOD = 0.25  # s between run()'s checks that the recorder is alive
EVENT_QUEUE = 1024  # events in flight to the recorder; more are dropped (and counted), never waited for
RING_SECONDS = 2.0  # the ring keeps at least this much, or 10 flush periods, whichever is longer


def _child_main(*args: Any) -> None:
    """Recorder process entry (imports rerun there only, so pickling this target does not load it here)."""
    from hild.telemetry.worker import main

    main(*args)


def _stop(process: Any, grace: float) -> None:
    """Join, then SIGTERM, then SIGKILL (a stopped or wedged process ignores the first two)."""
    for end in (process.terminate, process.kill):
        if not process.is_alive():
            return
        end()
        process.join(grace)


def _last_resort(process: Any, shared: SharedRing) -> None:
    """At interpreter exit without close(): stop the recorder and unlink the segment."""
    with contextlib.suppress(Exception):
        if process.is_alive():
            _stop(process, 0.2)
    with contextlib.suppress(Exception):
        shared.release()


class Telemetry:
    """The daemon's handle on telemetry: ``tap`` for the cycle, ``run`` (watchdog), ``log_events``, ``close``."""

    def __init__(self, setup: TelemetrySetup, stats: LoopStats | None = None) -> None:
        sec = setup.section
        self.setup = setup
        self.joints = setup.joints
        self.flush_period = sec.flush_period
        every = 1 if sec.scalar_rate <= 0 else max(1, round(setup.update_rate / sec.scalar_rate))
        rows_per_s = setup.update_rate / every
        capacity = max(256, math.ceil(rows_per_s * max(RING_SECONDS, 10 * sec.flush_period)))
        try:
            self._shared = SharedRing.create(len(self.joints), capacity, every, stats)
        except OSError as exc:
            raise TelemetryError(f"telemetry: cannot create the shared ring in /dev/shm: {exc}") from exc
        self.tap = self._shared.tap
        self.alive = False  # the recorder is up and answering (False after close() or its death)
        self.dropped_events = 0
        self.info: dict[str, Any] = {"files": [], "dropped": 0}
        self._closed = False
        self._events_sent = 0
        self._seq = 0
        self._lock = threading.RLock()  # close() may run on another thread (the daemon uses asyncio.to_thread)
        ctx = mp.get_context("spawn")  # a fork would copy the daemon's threads' locks in whatever state they are
        self._conn, child_conn = ctx.Pipe()
        self._events = ctx.Queue(EVENT_QUEUE)
        self._events.cancel_join_thread()  # never wait at exit for events a dead recorder will not read
        ring = (self._shared.name, len(self.joints), capacity, every)
        self.ring_layout = ring  # what another process needs to record into the ring (the cycle process)
        self._process = ctx.Process(
            target=_child_main,
            args=(setup, ring, child_conn, self._events, os.getpid()),
            name="hild-telemetry",
            daemon=True,
        )
        try:
            self._process.start()
            child_conn.close()
            reply = self._receive(lambda m: m[0] in ("ready", "error"), time.monotonic() + START_TIMEOUT)
        except BaseException:
            self._release(kill=True)
            raise
        if reply[0] != "ready":
            self._release(kill=True)
            if reply[0] == "error":
                raise TelemetryError(reply[1])
            raise TelemetryError(f"telemetry: the recorder process did not start ({self._describe_end(reply)})")
        self.alive = True
        self.info = reply[1]
        self._finalizer = weakref.finalize(self, _last_resort, self._process, self._shared)
        log.info("telemetry to %s (recorder process %d)", self.info["description"], self._process.pid)

    @classmethod
    def from_config(
        cls, loaded: Any, stats: LoopStats | None = None, *, keep_existing: bool = False
    ) -> Telemetry | None:
        """Telemetry for a loaded config, or None when disabled. Starts the recorder process and waits until every
        sink is open; raises ``TelemetryError`` if one cannot open."""
        cfg = loaded.config
        sec: TelemetrySection = cfg.telemetry
        if not sec.enabled:
            return None
        model = loaded.directory / cfg.robot.model if cfg.robot.model else None
        setup = TelemetrySetup(
            cfg.robot.name,
            tuple(cfg.joints),
            cfg.update_rate,
            sec,
            loaded.directory,
            model,
            tuple(cfg.realtime.cpu_affinity),
            keep_existing,
        )
        return cls(setup, stats)

    # ---- talking to the recorder ------------------------------------------------------------------------------
    @property
    def pid(self) -> int | None:
        return self._process.pid

    @property
    def shm_name(self) -> str:
        """The shared-memory segment (``/dev/shm/<name>``); unlinked by close() or when the recorder dies."""
        return self._shared.name

    @staticmethod
    def _describe_end(reply: tuple[Any, ...]) -> str:
        return f"it exited with code {reply[1]}" if reply[0] == "dead" else "no answer in time"

    def _receive(self, wanted: Callable[[tuple[Any, ...]], bool], deadline: float) -> tuple[Any, ...]:
        """The next message ``wanted`` accepts; logs forwarded on the way. ``("timeout",)`` or ``("dead", code)``
        when none comes."""
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return ("timeout",)
            ready = wait_for_any([self._conn, self._process.sentinel], remaining)
            if self._conn in ready:
                try:
                    message = self._conn.recv()
                except (EOFError, OSError):
                    self._process.join(max(0.0, min(0.5, deadline - time.monotonic())))
                    return ("dead", self._process.exitcode)
                if wanted(message):
                    return message
                self._handle(message)
            elif ready:
                return ("dead", self._process.exitcode)

    def _handle(self, message: tuple[Any, ...]) -> None:
        kind = message[0]
        if kind == "log":
            log.log(message[1], "%s", message[2])
        elif kind == "flushed":
            self.info = message[3]
        elif kind == "closed":
            self.info = message[1]

    def _drain(self) -> None:
        with contextlib.suppress(EOFError, OSError):
            while self._conn.poll(0):
                self._handle(self._conn.recv())

    # ---- the asyncio side -------------------------------------------------------------------------------------
    def log_events(self, events: Iterable[Event]) -> None:
        """Queue engine events for the recorder (the daemon drains ``engine.events`` on its loop). Never blocks:
        when the queue is full the events are dropped and counted in ``dropped_events``."""
        for e in events:
            if not self.alive:
                return
            try:
                self._events.put_nowait((e.stamp, e.level, e.source, e.message))
                self._events_sent += 1
            except (queue.Full, ValueError, OSError):  # full, or closed under us by close()
                self.dropped_events += 1

    async def run(self) -> None:
        """Watch the recorder until close() (an asyncio task on the daemon's loop). If it dies, log an error, turn
        telemetry off and return: the daemon keeps running (``tap.record`` keeps working, into private memory)."""
        while self.alive:
            await asyncio.sleep(WATCH_PERIOD)
            self.check()

    def check(self) -> bool:
        """Forward the recorder's log lines and notice its death; returns whether it is alive."""
        if not self._lock.acquire(blocking=False):  # close() or flush() is talking to it
            return self.alive
        try:
            if self.alive:
                self._drain()
                if not self._process.is_alive():
                    self._died(self._process.exitcode)
            return self.alive
        finally:
            self._lock.release()

    def _died(self, code: int | None) -> None:
        self.alive = False
        log.error(
            "telemetry: the recorder process died (exit code %s); telemetry is off, the daemon keeps running",
            code,
        )
        self._release(kill=True)

    def flush(self, timeout: float = FLUSH_TIMEOUT) -> int:
        """Ask the recorder to send everything now (tests, tools) and wait for it; returns the rows it sent.
        Raises ``TelemetryError`` if it does not answer within ``timeout``; 0 once telemetry is off."""
        with self._lock:
            if not self.alive:
                return 0
            self._seq += 1
            seq = self._seq
            with contextlib.suppress(OSError):  # it died: _receive says so
                self._conn.send(("flush", seq, self._events_sent))
            reply = self._receive(lambda m: m[0] == "flushed" and m[1] == seq, time.monotonic() + timeout)
            if reply[0] == "flushed":
                self.info = reply[3]
                return int(reply[2])
            if reply[0] == "dead":
                self._died(reply[1])
                return 0
            raise TelemetryError(f"telemetry: the recorder did not acknowledge a flush within {timeout:g} s")

    # ---- shutdown -----------------------------------------------------------------------------------------------
    def close(self, timeout: float = CLOSE_TIMEOUT) -> None:
        """Tell the recorder to flush, close its sinks and exit; returns within ``timeout`` s whatever it does
        (a recorder that does not finish is stopped: SIGTERM, then SIGKILL). Unlinks the shared memory."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            if not self.alive:
                self._release(kill=True)
                return
            self.alive = False
            start = time.monotonic()
            grace = min(0.25, timeout / 4)  # kept back to stop a recorder that does not answer
            try:
                # The recorder's own budget for its sinks leaves it time to answer before our deadline.
                with contextlib.suppress(OSError):
                    self._conn.send(("close", max(0.05, 0.6 * timeout - 0.1), self._events_sent))
                reply = self._receive(lambda m: m[0] == "closed", start + timeout - grace)
                if reply[0] == "closed":
                    self.info = reply[1]
                    self._process.join(max(0.0, start + timeout - grace - time.monotonic()))
                elif reply[0] == "timeout":
                    log.warning("telemetry: the recorder did not finish within %g s; stopped it", timeout)
            finally:
                self._release(kill=True, grace=grace / 2)

    def _release(self, kill: bool, grace: float = 0.1) -> None:
        """Stop the process if still there, unlink the shared memory, close the pipe and the queue."""
        if kill and self._process.is_alive():
            _stop(self._process, grace)
        self._shared.release()
        with contextlib.suppress(Exception):
            self._events.close()
        with contextlib.suppress(Exception):
            self._conn.close()
        finalizer = getattr(self, "_finalizer", None)
        if finalizer is not None:
            finalizer.detach()

    @property
    def files(self) -> list[Path]:
        """Every .rrd file written so far (rotation adds more), as of the recorder's last answer."""
        return [Path(p) for p in self.info["files"]]
