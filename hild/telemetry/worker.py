"""The recorder process: everything rerun does, in a child of the client domain, so it never holds a GIL the cycle
or the API needs.

Started by ``hild.telemetry.recorder.Telemetry`` with the "spawn" start method (a fresh interpreter that inherits
none of the daemon's threads), at a lower priority (``NICE``) and off the cycle thread's CPUs. It reads the
cycle's rows from the shared ring, and every ``flush_period`` sends one ``send_columns`` batch per entity to every
sink; 3D poses are computed here, decimated to ``pose_rate``; events arrive on a queue and go out as a text log.

Messages on the control pipe — daemon → recorder: ``("flush", seq, events_sent)``, ``("close", budget_s,
events_sent)``; recorder → daemon: ``("ready", info)`` or ``("error", message)`` once at start-up,
``("flushed", seq, rows, info)``, ``("closed", info)``, and ``("log", levelno, message)`` at any time.
``events_sent`` lets the recorder wait for events still in flight on the queue before it flushes.
"""

from __future__ import annotations

import contextlib
import logging
import os
import queue
import threading
import time
import uuid
from collections.abc import Iterable, Sequence
from multiprocessing.connection import Connection
from typing import Any

import numpy as np
import rerun as rr

from hild.config.model import FileSinkSpec
from hild.crossing.events import Event
from hild.crossing.telemetry import SharedRing, TelemetryRows, TelemetryTap
from hild.cycle.realtime import lower_priority
from hild.telemetry import columns, layout
from hild.telemetry.errors import TelemetryError
from hild.telemetry.outlets import FileOutlet, LiveOutlet, Outlet
from hild.telemetry.setup import TelemetrySetup

log = logging.getLogger("hild.telemetry")

NICE = 19  # the recorder yields the CPU to anything else, above all the cycle; a late flush only costs latency
EVENT_WAIT = 1.0  # s a flush waits for events the daemon has queued but the pipe has not delivered yet
_LEVELS = {"debug": "DEBUG", "info": "INFO", "warning": "WARN", "error": "ERROR", "critical": "CRITICAL"}


class Recorder:
    """Sends a tap's rows and the daemon's events to every sink (rerun), in the recorder process."""

    def __init__(self, setup: TelemetrySetup, tap: TelemetryTap) -> None:
        sec = setup.section
        self.setup = setup
        self.joints = setup.joints
        self.tap = tap
        self.pose_rate = sec.pose_rate
        self._last_pose_bin = -1
        self._anchor = (0.0, 0)  # (cycle_time, tick) of the newest row sent: events get their tick from it
        self._events: list[Event] = []
        self.flushes, self.flush_seconds, self.flush_max = 0, 0.0, 0.0
        self.scene = None
        if setup.model is not None:
            from hild.dynamics.kinematics import Kinematics  # mujoco stays behind hild.dynamics
            from hild.telemetry.arm3d import ArmScene

            self.scene = ArmScene(Kinematics(setup.model, self.joints))
        self.blueprint = layout.default_blueprint(self.joints, self.scene is not None)
        self.recording_id = str(uuid.uuid4())
        self.outlets: list[Outlet] = []
        try:
            live = [s for s in sec.sinks if not isinstance(s, FileSinkSpec)]
            for spec in sec.sinks:
                if isinstance(spec, FileSinkSpec):
                    self.outlets.append(
                        FileOutlet(
                            spec, setup.directory, self.recording_id, setup.robot, self._on_open, setup.keep_existing
                        )
                    )
            if live:
                self.outlets.append(LiveOutlet(live, self.recording_id, setup.robot, self._on_open))
        except Exception:
            self.close(1.0)
            raise

    def info(self) -> dict[str, Any]:
        """What the daemon side shows: sinks, files written so far, drops and flush timing."""
        return {
            "description": "; ".join(o.description for o in self.outlets),
            "files": [str(p) for o in self.outlets if isinstance(o, FileOutlet) for p in o.files],
            "dropped": self.tap.dropped,
            "flushes": self.flushes,
            "flush_mean_ms": 1e3 * self.flush_seconds / self.flushes if self.flushes else 0.0,
            "flush_max_ms": 1e3 * self.flush_max,
        }

    # ---- static content (every new stream) ------------------------------------------------------------------
    def _on_open(self, rec: rr.RecordingStream) -> None:
        columns.log_series_styles(rec, self.joints)
        if self.scene is not None:
            self.scene.log_static(rec)
        rec.send_blueprint(self.blueprint)

    # ---- batches ------------------------------------------------------------------------------------------------
    def add_events(self, events: Iterable[Event]) -> None:
        self._events.extend(events)

    def flush(self) -> int:
        """Send every row the tap holds and the queued events; returns the number of cycle rows sent."""
        start = time.perf_counter()
        rows = self.tap.take()
        if len(rows):
            self._send_rows(rows)
        if self._events:
            events, self._events = self._events, []
            self._send_events(events)
        for outlet in self.outlets:
            outlet.maintain()
        spent = time.perf_counter() - start
        self.flushes += 1
        self.flush_seconds += spent
        self.flush_max = max(self.flush_max, spent)
        return len(rows)

    def _send(self, path: str, indexes: Sequence[rr.TimeColumn], columns: Any) -> None:
        for outlet in self.outlets:
            outlet.rec.send_columns(path, indexes=indexes, columns=columns)

    def _send_rows(self, rows: TelemetryRows) -> None:
        index = columns.time_index(rows.tick, rows.t)
        for path, batch in columns.row_columns(rows):
            self._send(path, index, batch)
        self._anchor = (float(rows.t[-1]), int(rows.tick[-1]))
        if self.scene is not None:
            pick = self.pose_rows(rows.t)
            if pick.size:
                pose_index = columns.time_index(rows.tick[pick], rows.t[pick])
                for path, poses in self.scene.pose_columns(rows.measured_position[pick]):
                    self._send(path, pose_index, poses)

    def pose_rows(self, t: np.ndarray) -> np.ndarray:
        """Indices of the rows that start a new 1/pose_rate slot of the cycle clock (decimation without drift)."""
        bins = np.floor(t * self.pose_rate + 1e-9).astype(np.int64)
        previous = np.concatenate(([self._last_pose_bin], bins[:-1]))
        pick = np.flatnonzero(bins > previous)
        if len(bins):
            self._last_pose_bin = max(self._last_pose_bin, int(bins[-1]))
        return pick

    def _send_events(self, events: list[Event]) -> None:
        t0, tick0 = self._anchor
        rate = self.setup.update_rate
        stamps = np.array([e.stamp for e in events])
        ticks = np.maximum(0, tick0 + np.round((stamps - t0) * rate)).astype(np.int64)
        index = [rr.TimeColumn(layout.TICK, sequence=ticks), rr.TimeColumn(layout.CYCLE_TIME, duration=stamps)]
        self._send(
            layout.EVENTS,
            index,
            rr.TextLog.columns(
                text=[f"[{e.source}] {e.message}" for e in events],
                level=[_LEVELS.get(e.level, e.level.upper()) for e in events],
            ),
        )

    # ---- shutdown -----------------------------------------------------------------------------------------------
    def close(self, budget: float) -> bool:
        """Flush and disconnect every sink, files first (an unreachable viewer must not cost the file its tail).
        Gives up after ``budget`` s; returns whether every sink closed."""
        done = threading.Event()
        outlets = sorted(self.outlets, key=lambda o: not isinstance(o, FileOutlet))
        deadline = time.monotonic() + budget

        def finish() -> None:
            for outlet in outlets:  # each may take what those before it left of the budget: files come first
                try:
                    outlet.close(max(0.0, deadline - time.monotonic()))
                except TimeoutError:
                    log.warning("telemetry: closing %s did not finish within %g s", outlet.description, budget)
                except Exception as exc:
                    log.warning("telemetry: closing %s failed: %s", outlet.description, exc)
            done.set()

        threading.Thread(target=finish, name="hild-telemetry-close", daemon=True).start()
        if done.wait(budget + 0.1):
            return True
        log.warning("telemetry: sinks did not close within %g s; some data may be lost", budget)
        return False


class _PipeLog(logging.Handler):
    """Forwards the recorder's log records to the daemon, which logs them as its own."""

    def __init__(self, send: Any) -> None:
        super().__init__(logging.INFO)
        self.send = send

    def emit(self, record: logging.LogRecord) -> None:
        with contextlib.suppress(Exception):
            self.send(("log", record.levelno, record.getMessage()))


class _Process:
    """The recorder process's main loop: periodic flushes, commands from the daemon, events from its queue."""

    def __init__(self, conn: Connection, events: Any, parent_pid: int) -> None:
        self.conn = conn
        self.events = events
        self.parent_pid = parent_pid
        self.received = 0  # events taken off the queue
        self._send_lock = threading.Lock()  # the sink-attach thread logs too

    def send(self, message: tuple[Any, ...]) -> None:
        with self._send_lock, contextlib.suppress(OSError):  # the daemon is gone: nothing to tell
            self.conn.send(message)

    def drain_events(self, recorder: Recorder, sent: int | None) -> None:
        """Take every queued event; with ``sent``, wait (bounded) for the ones still in flight."""
        batch: list[Event] = []
        deadline = time.monotonic() + EVENT_WAIT
        while True:
            try:
                if sent is not None and self.received < sent:
                    item = self.events.get(timeout=max(0.0, deadline - time.monotonic()))
                else:
                    item = self.events.get_nowait()
            except (queue.Empty, OSError, EOFError):
                break
            self.received += 1
            batch.append(Event(*item))
        recorder.add_events(batch)

    def serve(self, recorder: Recorder, period: float) -> None:
        next_flush = time.monotonic() + period
        while True:
            wait = next_flush - time.monotonic()
            if wait > 0 and self.conn.poll(wait):
                try:
                    message = self.conn.recv()
                except (EOFError, OSError):  # the daemon died: save what we have and go
                    message = ("close", 2.0, None)
                if message[0] == "flush":
                    _, seq, sent = message
                    self.drain_events(recorder, sent)
                    rows = recorder.flush()
                    self.send(("flushed", seq, rows, recorder.info()))
                elif message[0] == "close":
                    _, budget, sent = message
                    self.drain_events(recorder, sent)
                    with contextlib.suppress(Exception):
                        recorder.flush()
                    recorder.close(budget)
                    self.send(("closed", recorder.info()))
                    return
                continue
            self.drain_events(recorder, None)
            try:
                recorder.flush()
            except Exception:  # one bad batch must not end the recording
                log.exception("telemetry flush failed")
            next_flush = max(next_flush + period, time.monotonic())
            if os.getppid() != self.parent_pid:  # orphaned (the daemon was killed): finish like a close
                recorder.flush()
                recorder.close(2.0)
                return


def main(
    setup: TelemetrySetup, ring: tuple[str, int, int, int], conn: Connection, events: Any, parent_pid: int
) -> None:
    """Entry point of the recorder process (spawned by ``Telemetry``): start the sinks, report, then serve — at
    ``NICE`` only once ready: its start-up (the model, the sinks) is a one-off the daemon waits for, and at nice 19
    beside two busy processes on two cores it did not get done within the 30 s start timeout."""
    proc = _Process(conn, events, parent_pid)
    handler = _PipeLog(proc.send)
    logger = logging.getLogger("hild")
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    logger.propagate = False
    try:
        shared = SharedRing.attach(*ring)
        recorder = Recorder(setup, shared.tap)
    except TelemetryError as exc:
        proc.send(("error", str(exc)))
        os._exit(1)
    except Exception as exc:  # e.g. the model does not load
        proc.send(("error", f"telemetry: {type(exc).__name__}: {exc}"))
        os._exit(1)
    proc.send(("ready", recorder.info()))
    lower_priority(NICE, setup.avoid_cpus)
    proc.serve(recorder, setup.section.flush_period)
    # Everything is flushed and acknowledged: leave now, skipping rerun's at-exit flush (it would wait again for
    # an unreachable viewer). The daemon unlinks the shared memory; the mapping goes with the process.
    os._exit(0)
