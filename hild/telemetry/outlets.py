"""Sinks as recording streams: rotating ``.rrd`` files, and one live stream (spawn / connect / serve).

A file sink has its own stream so it can rotate: rerun cannot reopen a ``FileSink`` in place, and replacing the
sinks of a shared stream would also shut down a served gRPC server. Every stream carries the same recording id,
so rotated files and the live view open as one recording. Each new stream gets the static content again (shapes,
series styles, blueprint) through ``on_open``, so every rotated file stands on its own.
"""

from __future__ import annotations

import datetime as dt
import logging
import os
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import rerun as rr
import rerun_bindings

from hild.config.model import ConnectSinkSpec, FileSinkSpec, ServeSinkSpec, SpawnSinkSpec
from hild.telemetry.errors import TelemetryError

log = logging.getLogger("hild.telemetry")

APPLICATION_ID = "hild"
ROTATION_FLUSH = 30.0  # s the rotation thread waits for a file's rows to be on disk; the rows' loop never waits

OnOpen = Callable[[rr.RecordingStream], None]

__all__ = ["FileOutlet", "LiveOutlet", "Outlet", "TelemetryError", "new_stream"]


def new_stream(recording_id: str, name: str) -> rr.RecordingStream:
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id)
    rec.set_log_time_enabled(False)  # every row carries tick and cycle_time; wall-clock log_time is noise
    rec.set_log_tick_enabled(False)
    rec.send_recording_name(name)
    return rec


class Outlet:
    """One recording stream and the sinks behind it."""

    def __init__(self, rec: rr.RecordingStream, description: str) -> None:
        self.rec = rec
        self.description = description

    def maintain(self) -> None:
        """Called after each flush (rotation)."""

    def close(self, timeout: float) -> None:
        try:
            self.rec.flush(timeout_sec=timeout)
        finally:
            self.rec.disconnect()


class FileOutlet(Outlet):
    """An ``.rrd`` file, rotated by size and/or age into ``<stem>-<UTC timestamp>.rrd`` files. ``keep_existing``:
    a file already at ``path`` is not overwritten either (the recording of a client domain that crashed).

    Rotation runs on a thread of its own. rerun's calls that wait — a flush (its timeout is not always held), and
    the drop of a stream, which ``send_blueprint`` does with its temporary blueprint stream — were seen to block
    for over a minute on a loaded machine. So the loop that sends rows only ever hands work to that thread and, at
    a later ``maintain``, adopts the stream it prepared: a stuck rerun can delay a rotation, never the rows.
    """

    def __init__(
        self,
        spec: FileSinkSpec,
        directory: Path,
        recording_id: str,
        name: str,
        on_open: OnOpen,
        keep_existing: bool = False,
    ) -> None:
        self.base = (directory / spec.path).resolve()
        self.keep_existing = keep_existing
        self.rotate_bytes = spec.rotate_mb * 1e6 if spec.rotate_mb else None
        self.rotate_seconds = spec.rotate_minutes * 60 if spec.rotate_minutes else None
        self.rotating = bool(self.rotate_bytes or self.rotate_seconds)
        self.recording_id, self.name, self.on_open = recording_id, name, on_open
        self.files: list[Path] = []
        try:
            self.base.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise TelemetryError(f"telemetry file sink: cannot create {self.base.parent}: {exc}") from exc
        rec, path = self._open()
        self._adopt(path)
        super().__init__(rec, f"file {self.base}")
        self._rotator = ThreadPoolExecutor(max_workers=1, thread_name_prefix="hild-telemetry-rotate")
        self._next: Future[tuple[rr.RecordingStream, Path] | None] | None = None
        self._retired: list[Future[None]] = []

    def _next_path(self) -> Path:
        if not self.rotating and not (self.keep_existing and self.base.exists()):
            return self.base
        stamp = dt.datetime.now(dt.UTC).strftime("%Y%m%dT%H%M%SZ")
        path = self.base.with_name(f"{self.base.stem}-{stamp}.rrd")
        n = 1
        while path.exists() or path in self.files:
            path = self.base.with_name(f"{self.base.stem}-{stamp}-{n}.rrd")
            n += 1
        return path

    def _open(self) -> tuple[rr.RecordingStream, Path]:
        path = self._next_path()
        rec = new_stream(self.recording_id, self.name)
        try:
            rec.set_sinks(rr.FileSink(path))
        except Exception as exc:
            raise TelemetryError(f"telemetry file sink: cannot write {path}: {exc}") from exc
        self.on_open(rec)
        return rec, path

    def _adopt(self, path: Path) -> None:
        self.files.append(path)
        self.opened = time.monotonic()

    def _rotate_if_due(self, rec: rr.RecordingStream, path: Path) -> tuple[rr.RecordingStream, Path] | None:
        """On the rotation thread: a new stream and file if ``path`` is old or big enough, else ``None``."""
        too_old = self.rotate_seconds is not None and time.monotonic() - self.opened >= self.rotate_seconds
        too_big = False
        if self.rotate_bytes is not None and not too_old:
            rec.flush(timeout_sec=ROTATION_FLUSH)  # so the size on disk is current
            try:
                too_big = os.path.getsize(path) >= self.rotate_bytes
            except OSError:
                too_big = False
        return self._open() if too_old or too_big else None

    @staticmethod
    def _finish(rec: rr.RecordingStream, timeout: float) -> None:
        try:
            rec.flush(timeout_sec=timeout)
        finally:
            rec.disconnect()

    def maintain(self) -> None:
        if not self.rotating:
            return
        if self._next is None:
            self._next = self._rotator.submit(self._rotate_if_due, self.rec, self.files[-1])
            return
        if not self._next.done():
            return  # still checking or opening: the rows keep going to the current file
        pending, self._next = self._next, None
        try:
            opened = pending.result()
        except Exception as exc:
            log.warning("telemetry: cannot rotate %s: %s; still writing %s", self.base, exc, self.files[-1])
            self.opened = time.monotonic()  # try again one rotation period on
            return
        if opened is not None:
            old, (self.rec, path) = self.rec, opened
            self._adopt(path)
            self._retired.append(self._rotator.submit(self._finish, old, ROTATION_FLUSH))
            del old  # the stream is dropped on the rotation thread: rerun's drop can wait too
            self._retired = [f for f in self._retired if not f.done()]
            log.info("telemetry: rotated to %s", path)

    def close(self, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        streams = [self.rec]
        if self._next is not None and not self._next.cancel():
            try:
                opened = self._next.result(timeout=max(0.0, deadline - time.monotonic()))
            except Exception as exc:
                log.warning("telemetry: a rotation of %s did not finish: %s", self.base, exc)
            else:
                if opened is not None:  # the new file exists on disk: close it as a file of the recording
                    streams.append(opened[0])
                    self._adopt(opened[1])
        self._next = None
        for rec in streams:
            self._retired.append(self._rotator.submit(self._finish, rec, max(0.0, deadline - time.monotonic())))
        del streams
        self._rotator.shutdown(wait=False)
        for retired in self._retired:
            retired.result(timeout=max(0.0, deadline - time.monotonic()))


class LiveOutlet(Outlet):
    """Viewers: a spawned native viewer, a remote viewer to connect to, and/or a served gRPC endpoint."""

    def __init__(
        self,
        specs: Sequence[SpawnSinkSpec | ConnectSinkSpec | ServeSinkSpec],
        recording_id: str,
        name: str,
        on_open: OnOpen,
    ) -> None:
        rec = new_stream(recording_id, name)
        sinks: list[rr.GrpcSink | rr.GrpcServerSink] = []
        what: list[str] = []
        self.serve_uri: str | None = None
        for spec in specs:
            try:
                if isinstance(spec, SpawnSinkSpec):
                    # rr.spawn cannot pass --bind, and the viewer's server would listen on every interface.
                    rerun_bindings.spawn(port=spec.port, hide_welcome_screen=True, extra_args=[f"--bind={spec.bind}"])
                    sinks.append(rr.GrpcSink(f"rerun+http://127.0.0.1:{spec.port}/proxy"))
                    what.append(f"spawned viewer on port {spec.port}")
                elif isinstance(spec, ConnectSinkSpec):
                    sinks.append(rr.GrpcSink(spec.url))
                    what.append(f"viewer at {spec.url}")
                else:
                    server = rr.GrpcServerSink(spec.bind, spec.port, server_memory_limit=spec.memory_limit)
                    self.serve_uri = server.uri
                    sinks.append(server)
                    what.append(f"serving {server.uri}")
            except Exception as exc:
                raise TelemetryError(f"telemetry {spec.kind} sink: {exc}") from exc
        on_open(rec)  # buffered in the stream until the sinks are attached
        if any(isinstance(s, rr.GrpcSink) for s in sinks):
            # set_sinks waits up to ~5 s for a gRPC client to connect: attach in the background so an absent
            # viewer never delays start-up; rows sent meanwhile are buffered and forwarded.
            threading.Thread(target=self._attach, args=(rec, sinks), name="hild-telemetry-connect", daemon=True).start()
        else:
            try:
                rec.set_sinks(*sinks)
            except Exception as exc:
                raise TelemetryError(f"telemetry sinks ({', '.join(what)}): {exc}") from exc
        super().__init__(rec, ", ".join(what))

    @staticmethod
    def _attach(rec: rr.RecordingStream, sinks: list[rr.GrpcSink | rr.GrpcServerSink]) -> None:
        try:
            rec.set_sinks(*sinks)
        except Exception as exc:
            log.warning("telemetry: cannot attach the live sinks: %s", exc)
