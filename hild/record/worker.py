"""The recorder process: reads the cycle log and writes episodes and black boxes, off the cycle and off the loop.

Started by ``hild.record.recorder.Recorder`` with "spawn", at ``NICE`` and off the cycle's CPUs; it dies with the
client domain (``PR_SET_PDEATHSIG``, and a parent check each period), leaving an open episode ``recording`` on disk
for ``recover`` — after a last chunk: the cycle log outlives the client domain (it is in the shared region, and the
cycle runs on), so the rows up to the parent's death are still there to write, and a killed client domain costs
the episode nothing. It maps the cycle log (the memfd comes over the command socket) and, every
``recording.chunk_period``, takes the rows the cycle wrote since and writes those of the open episode as one MCAP
chunk, flushed (fsync'ed when ``recording.fsync``), with the episode's events in time order. The cycle never waits
for it: the log is a ring, and rows a late recorder finds overwritten are counted (``dropped``) and reported.

A full disk (``ENOSPC``/``EDQUOT`` while writing) or free space below ``recording.min_free_mb`` (checked every
chunk) stops the episode cleanly, with an event that says why; the recorder keeps running. At its start it recovers
the episodes a dead recorder left ``recording`` (those no live recorder holds: hild/record/locks.py). The messages
it exchanges with its handle are listed in hild/record/recorder.py.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import logging
import math
import os
import queue
import shutil
import signal
import threading
import time
from dataclasses import dataclass, replace
from multiprocessing.connection import Connection
from multiprocessing.reduction import recv_handle
from pathlib import Path
from typing import Any

import numpy as np

from hild.crossing.cyclelog import CycleLog, CycleRows
from hild.cycle.realtime import lower_priority
from hild.record import locks
from hild.record.events import EVENT
from hild.record.mcap_files import EpisodeWriter, recover, write_blackbox
from hild.record.model import EpisodeMeta, RecordedEvent
from hild.record.setup import CODES, RecorderSetup

log = logging.getLogger("hild.record")

NICE = 5  # below the cycle and the client domain (nice 0), above a busy machine's batch work: at 19 two busy
# processes on two cores starved it for more than 10 s (tests/record beside two busy loops); the ring holds seconds
EVENT_WAIT = 1.0  # s a stop waits for events the handle queued but the queue has not delivered yet
STOP_WAIT = 1.0  # s a stop waits for the cycle to write its stop tick's row (a stopped cycle never will)
RECENT_SECONDS = 2.0  # s of rows kept to place the cycle's events at their cycle's wall time
REPORT_EVERY = 5.0  # s between two warnings about lost rows or a slow recorder
DISK_FULL = (errno.ENOSPC, errno.EDQUOT)
PR_SET_PDEATHSIG = 1
LEFT_WAIT = 5.0  # s recovery at start waits for a dying recorder to let go of its episode


class _Leave(Exception):
    """SIGTERM: the client domain died (``PR_SET_PDEATHSIG``) or someone stops us; write a last chunk and go."""


def _leave(signum: int, frame: Any) -> None:
    raise _Leave


def die_with_parent(parent_pid: int) -> None:
    """SIGTERM when the client domain dies (Linux ``prctl``), raised as ``_Leave`` where the loop waits; without the
    prctl, the parent check each period and the command socket's end do it."""
    signal.signal(signal.SIGTERM, _leave)
    with contextlib.suppress(Exception):
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
    if os.getppid() != parent_pid:  # it died before the prctl took
        os._exit(0)


def free_mb(directory: Path) -> float:
    """MiB available to an unprivileged writer on ``directory``'s file system."""
    st = os.statvfs(directory)
    return st.f_bavail * st.f_frsize / 2**20


def placed(events: list[RecordedEvent], rows_t: np.ndarray, rows_wall: np.ndarray) -> list[RecordedEvent]:
    """The cycle's events moved to the wall time of the cycle that emitted them (their ``t`` is that cycle's clock)
    when ``rows`` cover it; others keep the time they were received. Sorted by wall time: the file's order."""
    out = []
    for event in events:
        if event.kind == EVENT and len(rows_t) and rows_t[0] <= event.t <= rows_t[-1]:
            i = int(np.searchsorted(rows_t, event.t, side="right")) - 1
            event = replace(event, wall=float(rows_wall[i] + (event.t - rows_t[i])))
        out.append(event)
    out.sort(key=lambda e: e.wall)
    return out


@contextlib.contextmanager
def _deferred_leave() -> Any:
    """Hold a SIGTERM until the block is done, then raise ``_Leave`` (the recorder process's main thread; a worker
    served on another thread, in tests, has no signals to hold)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pending: list[int] = []
    previous = signal.signal(signal.SIGTERM, lambda signum, frame: pending.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
    if pending:
        raise _Leave


class EpisodeFile:
    """The open episode: its writer, its reader of the cycle log, and what it has written."""

    def __init__(self, no: int, meta: EpisodeMeta, directory: Path, cycle_log: CycleLog, setup: RecorderSetup) -> None:
        self.no = no
        self.meta = meta
        self.directory = directory
        self.lock = locks.hold(directory)  # before the first file: recovery never takes a live episode
        try:
            self.writer = EpisodeWriter(directory, meta, fsync=setup.fsync)
        except BaseException:
            locks.release(self.lock)
            raise
        self.reader = cycle_log.reader(start_tick=meta.start_tick)
        self.codes: dict[int, str] = dict(meta.controller_codes)  # owner code → controller, as the cycle names them
        self.stop_tick: int | None = None
        self.pending: list[RecordedEvent] = []  # events waiting for the rows of their cycle
        self.received = 0  # events taken off the queue for this episode
        self.cycles = 0
        self.first: tuple[float, float] | None = None  # (t, wall) of the first row written
        self.last_tick = meta.start_tick - 1
        self.last_t = -math.inf
        self.last_wall = meta.started_wall
        self.recent_rows = max(2, math.ceil(setup.update_rate * max(RECENT_SECONDS, 4 * setup.chunk_period)))
        self._recent_t = np.zeros(0)
        self._recent_wall = np.zeros(0)
        self.events_written = 0
        self.chunks, self.chunk_seconds, self.chunk_max = 0, 0.0, 0.0

    @property
    def dropped(self) -> int:
        return int(self.reader.lost)

    @property
    def duration(self) -> float:
        return 0.0 if self.first is None else self.last_t - self.first[0]

    def take(self) -> CycleRows:
        """The rows of this episode written by the cycle since the last take (none past the stop tick)."""
        rows = self.reader.take()
        if not len(rows):
            return rows
        keep = rows.tick >= self.meta.start_tick
        if self.stop_tick is not None:
            keep &= rows.tick <= self.stop_tick
        return rows if keep.all() else rows.select(keep)

    def write(self, rows: CycleRows, events: list[RecordedEvent], final: bool = False) -> None:
        """One chunk: the rows, then the events whose cycle's row is written (all of them when ``final``)."""
        if len(rows):
            self.writer.write_rows(rows, self.codes)
            if self.first is None:
                self.first = (float(rows.t[0]), float(rows.wall[0]))
            self.cycles += len(rows)
            self.last_tick = int(rows.tick[-1])
            self.last_t, self.last_wall = float(rows.t[-1]), float(rows.wall[-1])
            keep = self.recent_rows  # the newest rows: where the cycle's late-received events are placed
            self._recent_t = np.concatenate((self._recent_t, rows.t))[-keep:]
            self._recent_wall = np.concatenate((self._recent_wall, rows.wall))[-keep:]
        self.pending.extend(events)
        if final:
            ready, self.pending = self.pending, []
        else:  # a cycle's event waits for its row, so it lands at that cycle's time
            ready = [e for e in self.pending if not (e.kind == EVENT and e.t > self.last_t)]
            self.pending = [e for e in self.pending if e.kind == EVENT and e.t > self.last_t]
        for event in placed(ready, self._recent_t, self._recent_wall):
            self.writer.write_event(event)
        self.events_written += len(ready)
        self.writer.end_chunk()

    def figures(self) -> dict[str, Any]:
        return {
            "cycles": self.cycles,
            "duration": self.duration,
            "dropped": self.dropped,
            "last_tick": self.last_tick,
            "chunks": self.chunks,
            "chunk_ms_mean": 1e3 * self.chunk_seconds / self.chunks if self.chunks else 0.0,
            "chunk_ms_max": 1e3 * self.chunk_max,
        }

    def timed(self, seconds: float) -> None:
        """A chunk's time (take, write, flush, the free-space check), for the figures."""
        self.chunks += 1
        self.chunk_seconds += seconds
        self.chunk_max = max(self.chunk_max, seconds)

    def close(self, events_dropped: int | None, controller_codes: dict[int, str] | None, why: str | None) -> list[Path]:
        """Close the file (state ``complete``) with the final metadata; returns every file written."""
        meta = self.meta  # the writer's: close() writes it into episode.json
        if self.first is not None:
            meta.started_wall = self.first[1]
        if controller_codes:
            self.codes.update(controller_codes)
        meta.controller_codes = dict(self.codes)
        figures = self.figures()
        meta.extra = {
            **meta.extra,
            "events": self.events_written,
            "events_dropped": events_dropped,
            "chunks": self.chunks,
            "chunk_ms_mean": round(figures["chunk_ms_mean"], 3),  # the recorder's time per chunk: is it keeping up?
            "chunk_ms_max": round(figures["chunk_ms_max"], 3),
        }
        if why is not None:
            meta.extra["stopped_because"] = why
        try:
            return [Path(p).resolve() for p in self.writer.close("complete", dropped=self.dropped)]
        finally:
            locks.release(self.lock)

    def remove(self) -> None:
        """Discard: close what is open and delete the directory."""
        with contextlib.suppress(Exception):
            self.writer.abandon()
        locks.release(self.lock)
        shutil.rmtree(self.directory, ignore_errors=True)


@dataclass
class _Early:
    """Events of an episode whose start has not arrived yet (the queue overtook the command pipe)."""

    no: int
    event: RecordedEvent


class Worker:
    """The recorder process's loop: chunks every period, commands from the handle, events from its queue."""

    def __init__(
        self,
        setup: RecorderSetup,
        cycle_log: CycleLog,
        commands: Connection,
        outbox: Outbox,
        events: Any,
        parent_pid: int,
    ) -> None:
        self.setup = setup
        self.cycle_log = cycle_log
        self.commands = commands
        self.send = outbox.send
        self.events = events
        self.parent_pid = parent_pid
        self.episode: EpisodeFile | None = None
        self._early: list[_Early] = []
        self._reported = (-math.inf, 0)  # (monotonic, dropped) of the last warning about lost rows
        self._slow_reported = -math.inf
        self._last_no = 0  # the newest episode number seen (older events are discarded)

    def event(self, level: str, text: str) -> None:
        self.send(("event", level, text))

    # ---- the loop ----------------------------------------------------------------------------------------------
    def serve(self) -> None:
        """Chunks every period and commands between them, until told to close; a parent that dies (its socket's
        end, SIGTERM, or found orphaned) gets the open episode's last chunk written first (``last_chunk``)."""
        try:
            self._serve()
        except _Leave:
            if threading.current_thread() is threading.main_thread():
                signal.signal(signal.SIGTERM, signal.SIG_DFL)  # a second SIGTERM ends us, last chunk or not
            self.last_chunk()

    def _serve(self) -> None:
        period = self.setup.chunk_period
        next_chunk = time.monotonic() + period
        while True:
            wait = next_chunk - time.monotonic()
            if wait > 0 and self.commands.poll(wait):
                try:
                    message = self.commands.recv()
                except (EOFError, OSError):  # the client domain is gone: the episode stays for recover
                    raise _Leave from None
                with _deferred_leave():  # a command runs whole: its reply and its files stay consistent
                    if not self.command(message):
                        return
                continue
            with _deferred_leave():  # a chunk is written whole, never cut by the SIGTERM a dead parent sends
                try:
                    self.chunk()
                except Exception as exc:  # e.g. the episode's directory removed under it: the recorder runs on
                    log.exception("recording: a chunk failed")
                    self.end(f"recording failed: {type(exc).__name__}: {exc}")
            next_chunk = max(next_chunk + period, time.monotonic())
            if os.getppid() != self.parent_pid:  # orphaned
                raise _Leave

    def last_chunk(self) -> None:
        """The client domain is gone: write the open episode's rows up to now (the cycle log lives on in the shared
        region) as one more chunk, and leave the episode ``recording`` for the next recorder's recovery."""
        episode = self.episode
        if episode is None:
            return
        with contextlib.suppress(Exception):
            self._write(episode, episode.take(), self.take_events(), final=True)

    def command(self, message: tuple[Any, ...]) -> bool:
        """Handle one command and acknowledge it; False once told to close."""
        kind, seq, *args = message
        try:
            if kind == "close":
                self.send(("reply", seq, True, None))
                return False
            handler = {"start": self.start, "stop": self.stop, "discard": self.discard, "blackbox": self.blackbox}
            reply = handler[kind](*args)
        except _Refusal as exc:
            self.send(("reply", seq, False, str(exc)))
        except Exception as exc:
            log.exception("recording: %s failed", kind)
            self.send(("reply", seq, False, f"{kind} failed: {type(exc).__name__}: {exc}"))
        else:
            self.send(("reply", seq, True, reply))
        return True

    def take_events(self, wait_for: int | None = None) -> list[RecordedEvent]:
        """The open episode's events off the queue; with ``wait_for``, until it has received that many (bounded)."""
        episode = self.episode
        out: list[RecordedEvent] = []
        deadline = time.monotonic() + EVENT_WAIT
        while True:
            try:
                if episode is not None and wait_for is not None and episode.received < wait_for:
                    item = self.events.get(timeout=max(0.0, deadline - time.monotonic()))
                else:
                    item = self.events.get_nowait()
            except (queue.Empty, OSError, EOFError, ValueError):
                return out
            no, wall, t, kind, data = item
            self._last_no = max(self._last_no, no)
            event = RecordedEvent(wall, t, kind, data)
            if episode is not None and no == episode.no:
                episode.received += 1
                if kind == CODES:
                    episode.codes.update(data)
                else:
                    out.append(event)
            elif episode is None or no > episode.no:
                self._early.append(_Early(no, event))

    def chunk(self) -> None:
        episode = self.episode
        events = self.take_events()
        if episode is None:
            self._early = [e for e in self._early if e.no >= self._last_no]
            return
        started = time.monotonic()
        if not self._write(episode, episode.take(), events):
            return
        left = free_mb(episode.directory)
        if left < self.setup.min_free_mb:
            self.end(f"free space below recording.min_free_mb ({left:.0f} MiB left, {self.setup.min_free_mb:g} asked)")
            return
        spent = time.monotonic() - started
        episode.timed(spent)
        self._report(episode, spent)
        self.send(("progress", episode.no, episode.figures()))

    def _write(self, episode: EpisodeFile, rows: CycleRows, events: list[RecordedEvent], final: bool = False) -> bool:
        """Write a chunk; a full disk or a failing write ends the episode (True: it is still open)."""
        try:
            episode.write(rows, events, final)
        except OSError as exc:
            full = exc.errno in DISK_FULL
            self.end(f"disk full ({exc})" if full else f"writing failed: {exc}")
            return False
        except Exception as exc:
            log.exception("recording: writing episode %s failed", episode.meta.id)
            self.end(f"writing failed: {type(exc).__name__}: {exc}")
            return False
        return True

    def _report(self, episode: EpisodeFile, spent: float) -> None:
        """Rows lost, and a recorder slower than the cycle, are told (at most every ``REPORT_EVERY`` s)."""
        now = time.monotonic()
        last_time, last_dropped = self._reported
        if episode.dropped > last_dropped and now - last_time >= REPORT_EVERY:
            self.event(
                "warning",
                f"recording: {episode.dropped - last_dropped} cycles lost in episode {episode.meta.id}: "
                "the recorder fell behind the cycle log",
            )
            self._reported = (now, episode.dropped)
        if spent > self.setup.chunk_period and now - self._slow_reported >= REPORT_EVERY:
            self.event(
                "warning",
                f"recording: a chunk took {1e3 * spent:.0f} ms to write, longer than recording.chunk_period "
                f"({1e3 * self.setup.chunk_period:.0f} ms): the recorder is falling behind",
            )
            self._slow_reported = now

    def end(self, why: str) -> None:
        """Stop the open episode on the recorder's own account (disk full): closed if it can be, and told."""
        episode, self.episode = self.episode, None
        if episode is None:
            return
        try:
            files = episode.close(None, None, why)  # events dropped on the way here: the handle's count
        except Exception as exc:
            files = []
            why = f"{why}; closing it failed too ({exc}): hild record recover closes it once there is room"
        self.send(("ended", episode.no, self._reply(episode, files), why))

    @staticmethod
    def _reply(episode: EpisodeFile, files: list[Path]) -> dict[str, Any]:
        return {
            "id": episode.meta.id,
            "directory": str(episode.directory.resolve()),
            "files": [str(p) for p in files],
            "cycles": episode.cycles,
            "duration": episode.duration,
            "dropped": episode.dropped,
            "start_tick": episode.meta.start_tick,
            "stop_tick": episode.meta.stop_tick,
        }

    # ---- commands ----------------------------------------------------------------------------------------------
    def start(self, no: int, meta: EpisodeMeta, directory: str, markers: list[RecordedEvent]) -> dict[str, Any]:
        path = Path(directory)
        if self.episode is not None:
            shutil.rmtree(path, ignore_errors=True)
            raise _Refusal(f"episode {self.episode.meta.id} is being recorded")
        left = free_mb(path)
        if left < self.setup.min_free_mb:
            shutil.rmtree(path, ignore_errors=True)
            raise _Refusal(
                f"only {left:.0f} MiB free in {self.setup.directory}, below recording.min_free_mb "
                f"({self.setup.min_free_mb:g} MiB)"
            )
        try:
            episode = EpisodeFile(no, meta, path, self.cycle_log, self.setup)
        except Exception as exc:
            shutil.rmtree(path, ignore_errors=True)
            raise _Refusal(f"cannot write {path}: {exc}") from None
        episode.pending.extend(markers)
        early = [e.event for e in self._early if e.no == no]
        episode.received += len(early)
        for event in early:
            if event.kind == CODES:
                episode.codes.update(event.data)
            else:
                episode.pending.append(event)
        self._early = [e for e in self._early if e.no > no]
        self._last_no = max(self._last_no, no)
        self.episode = episode
        self._reported = (-math.inf, 0)
        return {"id": meta.id}

    def stop(
        self,
        no: int,
        stop_tick: int,
        events_sent: int,
        markers: list[RecordedEvent],
        controller_codes: dict[int, str],
        events_dropped: int,
    ) -> dict[str, Any]:
        episode = self.episode
        if episode is None or episode.no != no:
            raise _Refusal("no episode is being recorded (the recorder stopped it: see its events)")
        episode.stop_tick = stop_tick
        events = self.take_events(wait_for=events_sent)
        deadline = time.monotonic() + max(STOP_WAIT, 2 * self.setup.chunk_period)
        while True:  # every row up to the stop tick: the cycle may still be writing it
            rows = episode.take()
            if len(rows) and not self._write(episode, rows, events):
                raise _Refusal("the recorder stopped the episode itself: see its events")
            events = []
            if episode.last_tick >= stop_tick or time.monotonic() > deadline:
                break
            time.sleep(min(0.005, self.setup.chunk_period))
        if episode.last_tick < stop_tick:
            log.warning(
                "recording: episode %s ends at cycle %d: the cycle did not reach the stop tick %d in time",
                episode.meta.id,
                episode.last_tick,
                stop_tick,
            )
        if not self._write(episode, CycleRows.empty(len(self.setup.joints)), [*events, *markers], final=True):
            raise _Refusal("the recorder stopped the episode itself: see its events")
        self.episode = None
        files = episode.close(events_dropped, controller_codes, None)
        return {**self._reply(episode, files), "events_dropped": events_dropped}

    def discard(self, no: int) -> dict[str, Any]:
        episode = self.episode
        if episode is None or episode.no != no:
            raise _Refusal("no episode is being recorded")
        self.episode = None
        episode.remove()
        return {"id": episode.meta.id}

    def blackbox(self, name: str, count: int, events: list[RecordedEvent], info: dict[str, Any]) -> dict[str, Any]:
        """The cycle log's newest ``count`` rows and the events of their time, as one file under ``blackbox/``."""
        rows = self.cycle_log.last(count)
        if not len(rows):
            raise _Refusal("the cycle log holds no rows yet")
        folder = self.setup.blackbox_directory
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / f"{name}.mcap"
        n = 1
        while path.exists() or path.with_suffix(".json").exists():
            n += 1
            path = folder / f"{name}-{n}.mcap"
        first, last = float(rows.t[0]), float(rows.t[-1])
        chosen = [e for e in events if not (e.kind == EVENT and e.t > last)]
        try:
            write_blackbox(path, rows, placed(chosen, rows.t, rows.wall), info)
        except OSError as exc:
            with contextlib.suppress(OSError):
                path.unlink()
            raise _Refusal(f"cannot write {path}: {exc}") from None
        return {"file": str(path.resolve()), "cycles": len(rows), "seconds": last - first + float(rows.period[-1])}

    # ---- recovery ----------------------------------------------------------------------------------------------
    def recover_left(self, directories: list[Path]) -> None:
        """Close the episodes a dead recorder left ``recording`` (a thread at start: episodes start meanwhile)."""
        for directory in directories:
            if _still_held(directory):
                log.info("recording: %s is being written by a live recorder; left alone", directory)
                continue
            try:
                report = recover(directory)
            except Exception as exc:
                log.error("recording: recovering %s failed: %s", directory, exc)
                continue
            summary = report if isinstance(report, dict) else {"report": str(report)}
            self.send(("recovered", {"directory": str(directory), **summary}))
            self.event("warning", f"recording: recovered episode {directory.name}, left open by a recorder that died")


def _still_held(directory: Path) -> bool:
    """Whether a live recorder holds ``directory`` after ``LEFT_WAIT``: one whose client domain just died may be
    writing its last chunk (``Worker.last_chunk``) while the next client domain's recorder starts."""
    deadline = time.monotonic() + LEFT_WAIT
    while locks.in_use(directory):
        if time.monotonic() > deadline:
            return True
        time.sleep(0.05)
    return False


class _Refusal(Exception):
    """A command refused, with words for the client."""


def left_recording(directory: Path) -> list[Path]:
    """Episode directories whose ``episode.json`` still says ``recording``."""
    found = []
    if not directory.is_dir():
        return found
    for child in sorted(directory.iterdir()):
        try:
            if child.is_dir() and EpisodeMeta.read(child).state == "recording":
                found.append(child)
        except (OSError, ValueError, TypeError, KeyError):
            continue
    return found


class Outbox:
    """The messages pipe, shared by the loop, the recovery thread and the log handler."""

    def __init__(self, messages: Connection) -> None:
        self.messages = messages
        self._lock = threading.Lock()

    def send(self, message: tuple[Any, ...]) -> None:
        with self._lock, contextlib.suppress(OSError, ValueError):  # the handle is gone: nothing to tell
            self.messages.send(message)


class _PipeLog(logging.Handler):
    """Forwards the recorder's log records to the client domain, which logs them as its own."""

    def __init__(self, outbox: Outbox) -> None:
        super().__init__(logging.INFO)
        self.outbox = outbox

    def emit(self, record: logging.LogRecord) -> None:
        with contextlib.suppress(Exception):
            self.outbox.send(("log", record.levelno, record.getMessage()))


def main(
    setup: RecorderSetup,
    place: Any,
    commands: Connection,
    messages: Connection,
    events: Any,
    parent_pid: int,
) -> None:
    """Entry point of the recorder process (spawned by ``Recorder.open``): map the log, report, recover, serve."""
    die_with_parent(parent_pid)
    lower_priority(NICE, setup.avoid_cpus)
    outbox = Outbox(messages)
    logger = logging.getLogger("hild")
    logger.addHandler(_PipeLog(outbox))
    logger.setLevel(logging.INFO)
    logger.propagate = False
    try:
        fd = recv_handle(commands)
        cycle_log = CycleLog.attach(fd, place)
        setup.directory.mkdir(parents=True, exist_ok=True)
        left = left_recording(setup.directory)  # before any episode of ours starts: only a dead one's
    except Exception as exc:
        outbox.send(("error", f"{type(exc).__name__}: {exc}"))
        os._exit(1)
    worker = Worker(setup, cycle_log, commands, outbox, events, parent_pid)
    worker.send(("ready", {"cycle_log": f"{place.capacity} rows"}))
    if left:
        threading.Thread(target=worker.recover_left, args=(left,), name="hild-recover", daemon=True).start()
    worker.serve()
    os._exit(0)  # everything written is closed; the episode a dead parent left open stays for recover
