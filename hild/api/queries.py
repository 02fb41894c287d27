"""Answering Zenoh queries, the same way for services and controller goal endpoints.

A query handler runs on a Zenoh thread: its :class:`QueryAdmission` refuses oversized payloads unread and admits the
query under an in-flight cap chosen by payload size (a flood is answered "busy" right there, before its payload is
copied or anything is queued for the loop, so memory stays bounded however fast queries arrive, and a flood of large
payloads never takes the places of small requests such as a cancel), then it copies the payload out and hops to the
asyncio loop. Every query gets exactly one JSON reply and is then dropped, so the querier never waits for a timeout; a
querier that went away costs a debug line, never an exception. Error texts are clipped: a reason that quotes a 1 MiB
request must not send it back, nor put it in the log.

Large payloads (over ``FAST_DECODE``) are decoded, and goals parsed, in the :class:`LargePayloadWorker`: one at a time,
in a worker thread. Python work in the client domain shares its GIL with Zenoh's threads and the loop, and in the
in-process case with the cycle thread; several threads chewing on megabytes at once starved that cycle into
consecutive overruns (measured: eight clients sending 1 MiB payloads faulted a 500 Hz daemon within seconds). One at a
time, every other thread gets the GIL back within a switch interval."""

from __future__ import annotations

import asyncio
import collections
import contextlib
import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar

import zenoh

from hild.api.codec import FAST_DECODE, MAX_PAYLOAD, encode

log = logging.getLogger("hild.api")

MAX_IN_FLIGHT = 32  # concurrent requests per endpoint group; more are refused with "busy"
MAX_LARGE_IN_FLIGHT = 4  # of those with a payload over FAST_DECODE, under their own cap
MAX_ERROR_CHARS = 500  # an error text longer than this is clipped
READ_BACKLOG = 1024  # read-only queries waiting per service for the loop's next batch; more are refused with "busy"
SHUTTING_DOWN = {"ok": False, "error": "the daemon is shutting down"}
BUSY = {"ok": False, "error": f"busy: {MAX_IN_FLIGHT} requests in flight; retry"}
BUSY_LARGE = {"ok": False, "error": f"busy: {MAX_LARGE_IN_FLIGHT} requests over {FAST_DECODE} bytes in flight; retry"}
BUSY_BACKLOG = {"ok": False, "error": f"busy: {READ_BACKLOG} queries wait for an answer; retry"}


class InFlight:
    """Requests admitted and not yet answered; admitted on Zenoh threads, released on the loop."""

    def __init__(self, capacity: int = MAX_IN_FLIGHT) -> None:
        self.capacity = capacity
        self.refused = 0  # queries answered "busy"
        self._count = 0
        self._lock = threading.Lock()  # Zenoh threads and the loop only; the cycle never takes it

    def admit(self) -> bool:
        with self._lock:
            if self._count >= self.capacity:
                self.refused += 1
                return False
            self._count += 1
            return True

    def release(self) -> None:
        with self._lock:
            self._count -= 1

    def __len__(self) -> int:
        return self._count


def clip(text: str, limit: int = MAX_ERROR_CHARS) -> str:
    """``text``, cut to ``limit`` characters with a note of how much was left out."""
    if len(text) <= limit:
        return text
    return f"{text[:limit]}… ({len(text) - limit} more characters)"


@dataclass(frozen=True, slots=True)
class Admitted:
    """A query the gate let in: its payload, and the cap to release once it is answered."""

    raw: bytes
    cap: InFlight

    def release(self) -> None:
        self.cap.release()


class QueryAdmission:
    """Admission of one endpoint group's queries where they are received, before anything is copied or queued."""

    def __init__(self, capacity: int = MAX_IN_FLIGHT, large_capacity: int = MAX_LARGE_IN_FLIGHT) -> None:
        self.small = InFlight(capacity)
        self.large = InFlight(large_capacity)

    def admit(self, query: zenoh.Query, limit: int = MAX_PAYLOAD) -> Admitted | dict[str, Any]:
        """The admitted query, or the reply that refuses it (larger than ``limit``, its key's size limit, or busy)."""
        payload = query.payload
        size = 0 if payload is None else len(payload)
        if size > limit:
            return too_large(size, limit)
        large = size > FAST_DECODE
        cap = self.large if large else self.small
        if not cap.admit():
            return BUSY_LARGE if large else BUSY
        return Admitted(b"" if payload is None else payload.to_bytes(), cap)

    def __len__(self) -> int:
        return len(self.small) + len(self.large)


T = TypeVar("T")


class LargePayloadWorker:
    """Work on large payloads (decoding, parsing a goal): one job at a time, in a worker thread."""

    def __init__(self) -> None:
        self._lane = asyncio.Semaphore(1)

    async def run(self, work: Callable[[], T]) -> T:
        async with self._lane:
            return await asyncio.to_thread(work)

    @staticmethod
    def needed(raw: bytes) -> bool:
        """Whether ``raw`` is large enough for this worker (else decode it where you are)."""
        return len(raw) > FAST_DECODE


def too_large(size: int, limit: int = MAX_PAYLOAD) -> dict[str, Any]:
    """The refusal of a payload of ``size`` bytes over ``limit``; over ``MAX_PAYLOAD``, the reply it always was."""
    shown = MAX_PAYLOAD if size > MAX_PAYLOAD else limit
    return {"ok": False, "error": f"payload of {size} bytes exceeds the {shown}-byte limit"}


class ReadBacklog:
    """Read-only queries of one service waiting for the loop's next batch (hild/api/server.py), at most ``capacity``.

    Called on the Zenoh thread a query arrives on: it only counts and appends, so a poll costs a few µs of Python
    and no loop wake-up; a query that does not fit is answered "busy" there and then. Before, Zenoh queued them
    in a ring that dropped its oldest when the loop came late (a starved process), and a query dropped there was
    finished without any reply. Appends and ``take`` may run on different threads (``deque`` is safe for that);
    Zenoh threads racing for the last place may overshoot ``capacity`` by one each, never more."""

    def __init__(self, key: str, capacity: int = READ_BACKLOG) -> None:
        self.key = key
        self.capacity = capacity
        self.refused = 0  # queries answered "busy" for lack of room
        self._waiting: collections.deque[zenoh.Query] = collections.deque()

    def __call__(self, query: zenoh.Query) -> None:
        if len(self._waiting) >= self.capacity:
            self.refused += 1
            reply_json(query, self.key, BUSY_BACKLOG)
            return
        self._waiting.append(query)

    def take(self) -> zenoh.Query | None:
        """The oldest waiting query, or None."""
        try:
            return self._waiting.popleft()
        except IndexError:
            return None

    def __len__(self) -> int:
        return len(self._waiting)


_BUSY = (BUSY, BUSY_LARGE, BUSY_BACKLOG)
_ENCODED = {id(reply): encode(reply) for reply in _BUSY}  # a flood is refused without re-encoding


def reply_json(query: zenoh.Query, key: str, message: dict[str, Any] | bytes) -> None:
    """Send the one reply (a message, or one already encoded), then drop the query."""
    payload = message if isinstance(message, bytes) else _ENCODED.get(id(message))
    if payload is None:
        assert isinstance(message, dict)
        error = message.get("error")
        if isinstance(error, str) and len(error) > MAX_ERROR_CHARS:
            message = {**message, "error": clip(error)}
        payload = encode(message)
    try:
        query.reply(key, payload, encoding=zenoh.Encoding.APPLICATION_JSON)
    except zenoh.ZError as exc:  # the session closed, or the querier went away
        log.debug("reply on %s failed: %s", key, exc)
    finally:
        drop(query)


def drop(query: zenoh.Query) -> None:
    with contextlib.suppress(zenoh.ZError):
        query.drop()
