"""The ``record`` and ``blackbox`` services: episodes and the flight recorder on demand (docs/recording.md).

``record`` takes ``{"action": "start" | "stop" | "discard" | "status", "task"?, "fps"?, "note"?}`` (task, fps and
note go with start only); ``blackbox`` takes ``{"seconds"?}``. Both are thin: the request is checked here, the
work is the client domain's :class:`hild.record.recorder.Recorder`, and its :class:`RecordError` (one open
already, none open, disk full …) becomes the reply's ``error``. A daemon started with ``recording.enabled: false``
has no recorder: it refuses start, stop, discard and blackbox in words, and its status says
``"recorder": "disabled"``.

A recorder that does not answer within ``RECORDER_TIMEOUT`` costs the client one error reply, never the loop: the
call is shielded, so a stop still closes its file after the client was told it took too long.
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections.abc import Coroutine
from typing import Any, Protocol

from hild.api.fields import Reply, RequestError, Service, required
from hild.record.model import RecordError

ACTIONS = ("start", "stop", "discard", "status")
START_ONLY = ("task", "fps", "note")
MAX_TASK_CHARS = 1000  # one line: it becomes a LeRobot task string (meta/tasks.parquet)
MAX_NOTE_CHARS = 4000  # the operator's note, in episode.json; lines allowed
RECORDER_TIMEOUT = 15.0  # s: a stop writes its last chunk, fsyncs and writes metadata.yaml; a slow card takes seconds
BLACKBOX_REASON = "manual"  # the black box file's name says why: fault, estop, stall, or this
log = logging.getLogger("hild.api")

DISABLED = "recording is disabled on this daemon (recording.enabled: false in its config)"


class RecorderFace(Protocol):
    """What these services ask of the recorder (``hild.record.recorder.Recorder``; docs/recording.md)."""

    async def start(self, task: str | None, fps: float | None, note: str | None) -> dict[str, Any]: ...

    async def stop(self) -> dict[str, Any]: ...

    async def discard(self) -> dict[str, Any]: ...

    def status(self) -> dict[str, Any]: ...

    async def blackbox(self, reason: str, seconds: float | None = None) -> dict[str, Any]: ...


def action(field: str, value: Any) -> str:
    if value not in ACTIONS:
        raise RequestError(f"{field} must be one of {', '.join(ACTIONS)}, not {value!r}")
    return str(value)


def task_text(field: str, value: Any) -> str:
    """One printable line (the dataset's task: what the episode shows the robot doing)."""
    if not isinstance(value, str) or not value.strip():
        raise RequestError(f"{field} must be a non-empty string, not {_shown(value)}")
    if len(value) > MAX_TASK_CHARS:
        raise RequestError(f"{field} is {len(value)} characters long; at most {MAX_TASK_CHARS}")
    if not value.isprintable():
        raise RequestError(f"{field} must be one line of printable characters")
    return value


def note_text(field: str, value: Any) -> str:
    """Free text; lines and tabs allowed, other control characters not."""
    if not isinstance(value, str) or not value.strip():
        raise RequestError(f"{field} must be a non-empty string, not {_shown(value)}")
    if len(value) > MAX_NOTE_CHARS:
        raise RequestError(f"{field} is {len(value)} characters long; at most {MAX_NOTE_CHARS}")
    if not value.replace("\n", " ").replace("\t", " ").isprintable():
        raise RequestError(f"{field} must be printable text (newlines and tabs allowed)")
    return value


def positive(field: str, value: Any) -> float:
    """A finite number > 0 (JSON has no NaN or Infinity; a huge number overflows to inf and is refused here)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise RequestError(f"{field} must be a number, not {_shown(value)}")
    try:
        number = float(value)
    except OverflowError:  # an integer beyond float's range
        number = math.inf
    if not math.isfinite(number) or number <= 0:
        raise RequestError(f"{field} must be a finite number > 0, not {value!r}")
    return number


def _shown(value: Any) -> str:
    return repr(value) if isinstance(value, str) else type(value).__name__


class RecordServices:
    """``record`` and ``blackbox`` over a recorder (None: recording disabled)."""

    def __init__(self, recorder: RecorderFace | None, update_rate: float) -> None:
        self.recorder = recorder
        self.update_rate = update_rate

    def services(self) -> dict[str, Service]:
        return {
            "record": Service({"action": action, "task": task_text, "fps": positive, "note": note_text}, self._record),
            "blackbox": Service({"seconds": positive}, self._blackbox),
        }

    async def _record(self, request: dict[str, Any]) -> Reply:
        verb = required(request, "action")
        extra = [f for f in START_ONLY if f in request]
        if verb != "start" and extra:
            raise RequestError(f"{', '.join(extra)} go with start only, not with {verb}")
        if verb == "status":
            return self._status()
        recorder = self._recorder()
        if verb == "start":
            fps = request.get("fps")
            if fps is not None and fps > self.update_rate:
                raise RequestError(f"fps {fps:g} is above the robot's update rate ({self.update_rate:g} Hz)")
            return await self._ask(recorder.start(request.get("task"), fps, request.get("note")))
        return await self._ask(recorder.stop() if verb == "stop" else recorder.discard())

    async def _blackbox(self, request: dict[str, Any]) -> Reply:
        return await self._ask(self._recorder().blackbox(BLACKBOX_REASON, request.get("seconds")))

    def _status(self) -> Reply:
        if self.recorder is None:
            return {"recording": False, "recorder": "disabled", "dropped": 0, "dir": None}
        try:
            return dict(self.recorder.status())
        except RecordError as exc:
            raise RequestError(str(exc)) from None

    def _recorder(self) -> RecorderFace:
        if self.recorder is None:
            raise RequestError(DISABLED)
        return self.recorder

    @staticmethod
    async def _ask(call: Coroutine[Any, Any, dict[str, Any]]) -> Reply:
        """The recorder's reply; its refusal as the client's error; a recorder that hangs, an error in time."""
        task = asyncio.ensure_future(call)
        try:
            return dict(await asyncio.wait_for(asyncio.shield(task), RECORDER_TIMEOUT))
        except RecordError as exc:
            raise RequestError(str(exc)) from None
        except asyncio.CancelledError:  # the server is closing: the call goes on, its outcome is logged
            task.add_done_callback(_late)
            raise
        except TimeoutError:
            task.add_done_callback(_late)
            raise RequestError(
                f"the recorder did not answer within {RECORDER_TIMEOUT:g} s; it may still complete "
                "(hild ctl record status)"
            ) from None


def _late(task: asyncio.Future[dict[str, Any]]) -> None:
    """A recorder call's outcome nobody awaits any more (its client was answered already): logged, not lost."""
    if task.cancelled():
        return
    exc = task.exception()
    if isinstance(exc, RecordError):
        log.warning("a recorder call refused after its request was answered: %s", exc)
    elif exc is not None:
        log.error("a recorder call failed after its request was answered", exc_info=exc)
