"""The client domain's handle on recording: episodes, the black box, and the recorder process that writes them.

The cycle writes every cycle into the cycle log (hild/crossing/cyclelog.py); the recorder process
(hild/record/worker.py) maps it and writes the files. This handle only decides: which cycle an episode starts and
stops at (the cycle count when the request is handled: the ring holds seconds, so a late recorder still starts
exactly there), what goes with it (metadata, markers, the events and requests the daemon hands to ``log``), and
when. It never waits on the recorder's disk: commands go down a pipe and are acknowledged; events go on a bounded
queue, and a full queue drops and counts them.

The recorder process is started with "spawn" (a fresh interpreter, none of this one's threads), from the thread that
opens the recorder: it dies with that thread's process (``PR_SET_PDEATHSIG``), so open it from the main thread.
This module does not import ``mcap`` or ``pyarrow``: the client domain never loads them.

Messages — handle → recorder (the ``commands`` socket pair; first the cycle log's memfd, ``send_handle``):
``("start", seq, episode_no, meta, directory, markers)``, ``("stop", seq, episode_no, stop_tick, events_sent,
markers, controller_codes, events_dropped)``, ``("discard", seq, episode_no)``, ``("blackbox", seq, name, count,
events, info)``, ``("close", seq)``; events on the bounded queue as ``(episode_no, wall, t, kind, data)``.
Recorder → handle (the ``messages`` pipe): ``("ready", info)`` or ``("error", text)`` once, ``("reply", seq, ok,
value)``, ``("progress", episode_no, figures)`` after each chunk, ``("ended", episode_no, reply, reason)`` (an
episode the recorder had to stop: disk full), ``("recovered", report)``, ``("event", level, text)`` and ``("log",
levelno, text)``.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
import math
import multiprocessing as mp
import os
import queue
import threading
import time
import weakref
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from multiprocessing.reduction import send_handle
from pathlib import Path
from typing import Any, Protocol

from hild.record.events import marker
from hild.record.model import EpisodeMeta, RecordedEvent, RecordError
from hild.record.setup import CODES, RecorderSetup

log = logging.getLogger("hild.record")

START_TIMEOUT = 30.0  # s for the recorder process to import its libraries, map the cycle log and answer
COMMAND_TIMEOUT = 10.0  # s: a stop writes its last rows, fsyncs and writes the metadata; a slow card takes seconds
CLOSE_TIMEOUT = 5.0  # s: close() returns within this (plus an open episode's stop), whatever the recorder does
EVENT_QUEUE = 4096  # events in flight to the recorder; more are dropped (and counted), never waited for
RECENT_EVENTS = 10_000  # at most this many recent events kept for the black box (by age: its seconds)
SOURCE = "recorder"  # the source of the events the recorder emits


class CycleSource(Protocol):
    """What the recorder reads of the cycle (a ``CycleLink``)."""

    @property
    def cycle(self) -> int: ...

    @property
    def t(self) -> float: ...

    @property
    def change_seq(self) -> int: ...

    def snapshot(self) -> Any: ...

    def cycle_log(self) -> Any: ...  # (memfd, CycleLogPlace) | None


class _NoAnswer(RecordError):
    """The recorder did not answer a command (in time, or at all): it may still carry it out."""


Emit = Callable[[str, str], None]  # (level, text): an event on the daemon's stream


@dataclass
class _Episode:
    """The open episode, as the client domain knows it."""

    no: int
    id: str
    directory: Path
    start_tick: int
    task: str | None
    fps: float
    started: float  # monotonic
    sent: int = 0  # events queued for the recorder
    events_dropped: int = 0  # events the full queue refused
    stopping: bool = False  # stop or discard sent: no more events for it
    figures: dict[str, Any] | None = None  # the recorder's last progress report


def _child_main(*args: Any) -> None:
    """Recorder process entry (imports mcap there only, so pickling this target does not load it here)."""
    from hild.record.worker import main

    main(*args)


def _stop_process(process: Any, grace: float) -> None:
    """Join, then SIGTERM, then SIGKILL."""
    for end in (process.terminate, process.kill):
        if not process.is_alive():
            return
        end()
        process.join(grace)


def episode_stamp(wall: float) -> str:
    """``YYYYmmdd-HHMMSS`` in UTC: episode ids and black box file names start with it."""
    return datetime.fromtimestamp(wall, UTC).strftime("%Y%m%d-%H%M%S")


class Recorder:
    """Episodes and the black box, written by the recorder process (what the API layer calls: hild/api/record.py)."""

    def __init__(self, setup: RecorderSetup, cycle: CycleSource, emit: Emit | None = None) -> None:
        self.setup = setup
        self.cycle = cycle
        self._emit = emit or (lambda level, text: None)
        self.alive = False  # the recorder process runs and answers
        self.failure: str | None = None  # why it is not running (did not start, died)
        self.recovered: list[dict[str, Any]] = []  # what the recorder recovered at its start
        self._episode: _Episode | None = None
        self._last: dict[str, Any] | None = None  # the last episode's stop reply
        self._last_blackbox: dict[str, Any] | None = None
        self._episodes = itertools.count(1)
        self._seqs = itertools.count(1)
        self._recent: deque[RecordedEvent] = deque(maxlen=RECENT_EVENTS)
        self._keep = max(setup.blackbox_seconds, 2.0) + 1.0  # s of events kept for the black box
        self._codes_seq = -1  # the change_seq the controllers' codes were last read at
        self._codes: dict[int, str] = {}  # as the open episode's recorder knows them
        self._waiting: dict[int, asyncio.Future[Any]] = {}
        self._ready: asyncio.Future[Any] | None = None
        self._episode_lock: asyncio.Lock | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._process: Any = None
        self._commands: Any = None
        self._messages: Any = None
        self._events: Any = None
        self._reader: threading.Thread | None = None
        self._closing = False

    @classmethod
    def from_config(cls, loaded: Any, cycle: CycleSource, emit: Emit | None = None) -> Recorder | None:
        """A recorder for ``loaded`` (not started: ``open``), or None when ``recording.enabled`` is false."""
        if not loaded.config.recording.enabled:
            return None
        return cls(RecorderSetup.from_config(loaded), cycle, emit)

    # ---- the process ------------------------------------------------------------------------------------------
    async def open(self, timeout: float = START_TIMEOUT) -> None:
        """Start the recorder process on the cycle log and wait until it answers; ``RecordError`` if it cannot
        (the daemon runs on without recording). Episodes left ``recording`` in ``recording.dir`` by a recorder
        that died are recovered by it in the background and reported."""
        self._loop = asyncio.get_running_loop()
        self._episode_lock = asyncio.Lock()
        shared = self.cycle.cycle_log()
        if shared is None:
            raise self._failed("this cycle has no cycle log")
        fd, place = shared
        ctx = mp.get_context("spawn")  # a fork would copy the daemon's threads' locks in whatever state they are
        self._commands, child_commands = ctx.Pipe()  # a socket pair: the memfd goes across it (SCM_RIGHTS)
        self._messages, child_messages = ctx.Pipe(duplex=False)
        self._events = ctx.Queue(EVENT_QUEUE)
        self._events.cancel_join_thread()  # never wait at exit for events a dead recorder will not read
        self._process = ctx.Process(
            target=_child_main,
            args=(self.setup, place, child_commands, child_messages, self._events, os.getpid()),
            name="hild-recorder",
            daemon=True,
        )
        self._ready = self._loop.create_future()
        try:
            self._process.start()
            child_commands.close()
            child_messages.close()
            send_handle(self._commands, fd, self._process.pid)
            self._reader = threading.Thread(target=self._read_messages, name="hild-recorder-pipe", daemon=True)
            self._reader.start()
            info = await asyncio.wait_for(asyncio.shield(self._ready), timeout)
        except TimeoutError:
            await self._release(kill=True)
            raise self._failed(f"the recorder process did not answer within {timeout:g} s") from None
        except RecordError as exc:
            await self._release(kill=True)
            raise self._failed(str(exc)) from None
        except BaseException:
            await self._release(kill=True)
            raise
        self.alive = True
        self.failure = None
        self._finalizer = weakref.finalize(self, _stop_process, self._process, 0.2)
        log.info(
            "recording into %s (recorder process %d, %s)", self.setup.directory, self._process.pid, info["cycle_log"]
        )

    def _failed(self, why: str) -> RecordError:
        self.failure = why
        return RecordError(f"recording: {why}")

    @property
    def pid(self) -> int | None:
        return None if self._process is None else self._process.pid

    def _read_messages(self) -> None:
        """The pipe reader (a thread: a blocked read must never be the loop's): each message hops to the loop."""
        loop, messages = self._loop, self._messages
        assert loop is not None
        while True:
            try:
                message = messages.recv()
            except (EOFError, OSError):
                with contextlib.suppress(RuntimeError):  # the loop is closed
                    loop.call_soon_threadsafe(self._gone)
                return
            try:
                loop.call_soon_threadsafe(self._on_message, message)
            except RuntimeError:
                return

    def _on_message(self, message: tuple[Any, ...]) -> None:
        kind = message[0]
        if kind == "reply":
            _, seq, ok, value = message
            future = self._waiting.pop(seq, None)
            if future is not None and not future.done():
                if ok:
                    future.set_result(value)
                else:
                    future.set_exception(RecordError(value))
        elif kind == "progress":
            _, no, figures = message
            if self._episode is not None and self._episode.no == no:
                self._episode.figures = figures
        elif kind == "ended":
            self._ended(*message[1:])
        elif kind == "event":
            self._emit(message[1], message[2])
        elif kind == "log":
            log.log(message[1], "%s", message[2])
        elif kind == "recovered":
            self.recovered.append(message[1])
        elif kind in ("ready", "error") and self._ready is not None and not self._ready.done():
            if kind == "ready":
                self._ready.set_result(message[1])
            else:
                self._ready.set_exception(RecordError(message[1]))

    def _gone(self) -> None:
        """The recorder's end of the pipe closed: it exited (asked to, or died)."""
        if self._ready is not None and not self._ready.done():
            code = self._process.exitcode if self._process is not None else None
            self._ready.set_exception(RecordError(f"the recorder process ended at start-up (exit code {code})"))
        for future in self._waiting.values():
            if not future.done():
                future.set_exception(RecordError("the recorder process ended"))
        self._waiting.clear()
        if self._closing or not self.alive:
            return
        self.alive = False
        code = None
        if self._process is not None:
            self._process.join(0.2)  # its pipe closed: it is exiting
            code = self._process.exitcode
        episode, self._episode = self._episode, None
        left = f"; episode {episode.id} stays on disk for hild record recover" if episode is not None else ""
        self.failure = f"the recorder process died (exit code {code})"
        self._emit("error", f"recording: {self.failure}: recording is off{left}")

    async def _ask(self, *command: Any, timeout: float | None = None) -> Any:
        """Send a command and wait for its acknowledgement (``COMMAND_TIMEOUT`` unless told); its refusal, or
        silence, as ``RecordError``."""
        timeout = COMMAND_TIMEOUT if timeout is None else timeout
        if not self.alive:
            raise RecordError(self._not_running())
        assert self._loop is not None
        seq = next(self._seqs)
        future = self._loop.create_future()
        self._waiting[seq] = future
        try:
            self._commands.send((command[0], seq, *command[1:]))
        except OSError:
            self._waiting.pop(seq, None)
            raise _NoAnswer("the recorder process is not answering (its pipe is closed)") from None
        try:
            return await asyncio.wait_for(future, timeout)
        except TimeoutError:
            raise _NoAnswer(f"the recorder did not answer within {timeout:g} s ({command[0]})") from None
        finally:
            self._waiting.pop(seq, None)

    def _tell(self, *command: Any) -> None:
        """Send a command without waiting for its answer (nobody waits for its reply)."""
        with contextlib.suppress(OSError, ValueError, AttributeError):
            self._commands.send((command[0], next(self._seqs), *command[1:]))

    def _not_running(self) -> str:
        why = self.failure or "it is not started"
        return f"the recorder is not running ({why})"

    async def close(self, timeout: float = CLOSE_TIMEOUT) -> None:
        """Stop an open episode (closed, complete), then end the recorder process; bounded in time."""
        if self._closing:
            return
        if self._episode is not None and self.alive:
            try:
                await self.stop()
            except RecordError as exc:
                log.error("recording: the open episode could not be stopped: %s", exc)
        self._closing = True
        if self.alive:
            try:
                await self._ask("close", timeout=timeout)
            except RecordError as exc:
                log.warning("recording: the recorder did not close cleanly: %s", exc)
        self.alive = False
        await self._release(kill=True)

    async def _release(self, kill: bool) -> None:
        process = self._process
        if process is not None and process.pid is not None:  # started
            await asyncio.to_thread(process.join, 1.0)
            if kill and process.is_alive():
                await asyncio.to_thread(_stop_process, process, 0.2)
        for end in (self._commands, self._messages):
            with contextlib.suppress(Exception):
                if end is not None:
                    end.close()
        events, self._events = self._events, None
        if events is not None:  # freed now: its semaphores leave the resource tracker before the client domain's
            with contextlib.suppress(Exception):  # os._exit (else the tracker reports them "leaked" at shutdown)
                events.close()
                feeder = getattr(events, "_thread", None)  # the queue's feeder thread holds two of them
                if feeder is not None:
                    await asyncio.to_thread(feeder.join, 1.0)
            del events
        finalizer = getattr(self, "_finalizer", None)
        if finalizer is not None:
            finalizer.detach()

    # ---- episodes ---------------------------------------------------------------------------------------------
    async def start(self, task: str | None, fps: float | None, note: str | None) -> dict[str, Any]:
        """Open an episode at the cycle this request is handled in; the reply's fields (docs/protocol.md)."""
        assert self._episode_lock is not None, "open() first"
        async with self._episode_lock:
            if not self.alive:
                raise RecordError(self._not_running())
            if self._episode is not None:
                raise RecordError(f"episode {self._episode.id} is being recorded: stop or discard it first")
            tick, t, wall = int(self.cycle.cycle), float(self.cycle.t), time.time()
            fps = float(fps) if fps is not None else self.setup.fps
            episode_id, directory = self._new_directory(wall)
            meta = EpisodeMeta(
                id=episode_id,
                robot=self.setup.robot,
                joints=list(self.setup.joints),
                state="recording",
                task=task,
                note=note,
                fps=fps,
                update_rate=self.setup.update_rate,
                config_path=self.setup.config_path,
                config_sha256=self.setup.config_sha256,
                versions=dict(self.setup.versions),
                started_wall=wall,
                start_tick=tick,
                controller_codes=self._controller_codes(),
            )
            markers = [marker("episode_start", t, wall, id=episode_id, tick=tick, task=task, fps=fps, note=note)]
            if task is not None:
                markers.append(marker("task", t, wall, task=task))
            self._codes, self._codes_seq = dict(meta.controller_codes), self.cycle.change_seq
            episode = _Episode(next(self._episodes), episode_id, directory, tick, task, fps, time.monotonic())
            self._episode = episode  # events from here on are the episode's
            try:
                await self._ask("start", episode.no, meta, str(directory), markers)
            except _NoAnswer:
                self._episode = None
                self._tell("discard", episode.no)  # should it start late after all: undone there, its directory too
                raise
            except RecordError:
                self._episode = None
                with contextlib.suppress(OSError):
                    directory.rmdir()  # refused: the recorder removed what it wrote; an empty directory is ours
                raise
            words = f"recording started: episode {episode_id} at cycle {tick}"
            self._emit("info", words + (f", task {task!r}" if task else ""))
            return {
                "id": episode_id,
                "directory": str(directory),
                "start_tick": tick,
                "task": task,
                "fps": fps,
            }

    async def stop(self) -> dict[str, Any]:
        """Close the open episode at the cycle this request is handled in (every row up to it is written)."""
        assert self._episode_lock is not None, "open() first"
        async with self._episode_lock:
            episode = self._open_episode()
            tick, t = int(self.cycle.cycle), float(self.cycle.t)
            episode.stopping = True
            stop = marker("episode_stop", t, id=episode.id, tick=tick)
            try:
                reply = await self._ask(
                    "stop", episode.no, tick, episode.sent, [stop], self._controller_codes(), episode.events_dropped
                )
            finally:
                if self._episode is episode:
                    self._episode = None
            self._last = dict(reply)
            lost = f", {reply['dropped']} cycles lost" if reply.get("dropped") else ""
            self._emit(
                "info",
                f"recording stopped: episode {episode.id}, {reply['cycles']} cycles, {reply['duration']:.3f} s{lost}",
            )
            return reply

    async def discard(self) -> dict[str, Any]:
        """Close the open episode and remove its directory."""
        assert self._episode_lock is not None, "open() first"
        async with self._episode_lock:
            episode = self._open_episode()
            episode.stopping = True
            try:
                await self._ask("discard", episode.no)
            finally:
                if self._episode is episode:
                    self._episode = None
            self._emit("info", f"recording discarded: episode {episode.id} removed")
            return {"id": episode.id, "discarded": True}

    def _open_episode(self) -> _Episode:
        if not self.alive:
            raise RecordError(self._not_running())
        if self._episode is None:
            raise RecordError("no episode is being recorded")
        return self._episode

    def _ended(self, no: int, reply: dict[str, Any], reason: str) -> None:
        """The recorder stopped an episode itself (disk full, a write failed): closed as far as it could be."""
        self._last = dict(reply)
        if self._episode is not None and self._episode.no == no:
            self._episode = None
        self._emit("error", f"recording stopped: {reason} (episode {reply.get('id')}, {reply.get('cycles')} cycles)")

    def _new_directory(self, wall: float) -> tuple[str, Path]:
        """``<YYYYmmdd-HHMMSS>-<robot>``, then ``-2``, ``-3`` … if taken; created here, so two are never one."""
        base = f"{episode_stamp(wall)}-{self.setup.robot}"
        try:
            self.setup.directory.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise RecordError(f"cannot create {self.setup.directory}: {exc}") from None
        for n in itertools.count(1):
            episode_id = base if n == 1 else f"{base}-{n}"
            directory = self.setup.directory / episode_id
            try:
                directory.mkdir()
            except FileExistsError:
                continue
            except OSError as exc:
                raise RecordError(f"cannot create {directory}: {exc}") from None
            return episode_id, directory
        raise AssertionError("unreachable")

    def _controller_codes(self) -> dict[int, str]:
        try:
            return dict(getattr(self.cycle.snapshot(), "controller_codes", {}) or {})
        except Exception:  # the cycle has not reported yet
            return {}

    def status(self) -> dict[str, Any]:
        """``record status``'s fields (docs/protocol.md) (and ``events_dropped``, ``recovered``, ``blackbox``)."""
        episode = self._episode
        figures = (episode.figures if episode is not None else None) or {}
        source = episode if episode is not None else None
        out: dict[str, Any] = {
            "recording": episode is not None,
            "dropped": int(figures.get("dropped", 0) if source else (self._last or {}).get("dropped", 0)),
            "events_dropped": episode.events_dropped if episode else (self._last or {}).get("events_dropped", 0),
            "dir": str(self.setup.directory),
            "recorder": "running" if self.alive else "stopped",
        }
        if episode is not None:
            out.update(
                id=episode.id,
                directory=str(episode.directory),
                start_tick=episode.start_tick,
                task=episode.task,
                fps=episode.fps,
                cycles=int(figures.get("cycles", 0)),
                duration=float(figures.get("duration", 0.0)),
                chunk_ms_max=float(figures.get("chunk_ms_max", 0.0)),  # the recorder's slowest chunk so far
            )
        if self._last is not None:
            out["last"] = dict(self._last)
        if self._last_blackbox is not None:
            out["blackbox"] = dict(self._last_blackbox)
        if self.failure and not self.alive:
            out["failure"] = self.failure
        if self.recovered:
            out["recovered"] = list(self.recovered)
        return out

    # ---- events ------------------------------------------------------------------------------------------------
    def log(self, event: RecordedEvent) -> None:
        """Keep ``event`` for the black box and, while an episode is open, queue it for the recorder. Never blocks:
        a full queue drops it and counts it (status, and the episode's metadata)."""
        recent = self._recent
        recent.append(event)
        oldest = event.wall - self._keep
        while recent and recent[0].wall < oldest:
            recent.popleft()
        episode = self._episode
        if episode is None or episode.stopping or not self.alive:
            return
        self._queue(episode, (episode.no, event.wall, event.t, event.kind, event.data))
        seq = self.cycle.change_seq  # a controller loaded: its code's name, for its commands topic
        if seq != self._codes_seq:
            self._codes_seq = seq
            codes = self._controller_codes()
            if codes != self._codes:
                self._codes = codes
                self._queue(episode, (episode.no, event.wall, event.t, CODES, codes))

    def _queue(self, episode: _Episode, item: tuple[Any, ...]) -> None:
        try:
            self._events.put_nowait(item)
            episode.sent += 1
        except (queue.Full, ValueError, OSError, AttributeError):  # full, or closed under us
            episode.events_dropped += 1

    # ---- the black box -------------------------------------------------------------------------------------------
    async def blackbox(self, reason: str, seconds: float | None = None) -> dict[str, Any]:
        """Write the cycle log's last ``seconds`` (default ``recording.blackbox_seconds``) and the events of that
        time to ``<dir>/blackbox/<YYYYmmdd-HHMMSS>-<reason>.mcap``; the reply's ``file``, ``cycles``, ``seconds``."""
        if not self.alive:
            raise RecordError(self._not_running())
        if seconds is None:
            seconds = self.setup.blackbox_seconds
            if seconds <= 0:
                raise RecordError("the black box is off (recording.blackbox_seconds: 0); ask for seconds")
        if not (math.isfinite(seconds) and seconds > 0):
            raise RecordError(f"seconds must be a finite number > 0, not {seconds!r}")
        count = max(1, math.ceil(seconds * self.setup.update_rate))
        wall = time.time()
        events = [e for e in self._recent if e.wall >= wall - seconds - 1.0]
        name = f"{episode_stamp(wall)}-{reason}"
        info = {
            "reason": reason,
            "robot": self.setup.robot,
            "joints": list(self.setup.joints),
            "update_rate": self.setup.update_rate,
            "config_path": self.setup.config_path,
            "config_sha256": self.setup.config_sha256,
            "versions": dict(self.setup.versions),
            "controller_codes": self._controller_codes(),
            "asked_seconds": seconds,
        }
        reply = await self._ask("blackbox", name, count, events, info)
        self._last_blackbox = {**reply, "reason": reason}
        self._emit(
            "info" if reason == "manual" else "warning",
            f"black box saved ({reason}): {reply['file']}, the last {reply['seconds']:.3f} s "
            f"({reply['cycles']} cycles)",
        )
        return reply
