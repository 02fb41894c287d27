"""Answering Zenoh queries, the same way for services and controller goal endpoints.

A query handler runs on a Zenoh thread: it only copies the payload out (refusing oversized ones unread) and hops
to the asyncio loop. Every query gets exactly one JSON reply and is then dropped, so the querier never waits for
a timeout; a querier that went away costs a debug line, never an exception.
"""

from __future__ import annotations

import contextlib
import logging
from typing import Any

import zenoh

from hild.api.codec import MAX_PAYLOAD, encode

log = logging.getLogger("hild.api")

MAX_IN_FLIGHT = 32  # concurrent requests per endpoint group; more are refused with "busy"
SHUTTING_DOWN = {"ok": False, "error": "the daemon is shutting down"}
BUSY = {"ok": False, "error": f"busy: {MAX_IN_FLIGHT} requests in flight; retry"}


def read_payload(query: zenoh.Query) -> tuple[bytes | None, int]:
    """The query's payload (``b""`` when it has none) and its size; None for the bytes when over the limit."""
    payload = query.payload
    if payload is None:
        return b"", 0
    size = len(payload)
    return (payload.to_bytes() if size <= MAX_PAYLOAD else None), size


def too_large(size: int) -> dict[str, Any]:
    return {"ok": False, "error": f"payload of {size} bytes exceeds the {MAX_PAYLOAD}-byte limit"}


def reply_json(query: zenoh.Query, key: str, message: dict[str, Any]) -> None:
    """Send the one reply, then drop the query."""
    try:
        query.reply(key, encode(message), encoding=zenoh.Encoding.APPLICATION_JSON)
    except zenoh.ZError as exc:  # the session closed, or the querier went away
        log.debug("reply on %s failed: %s", key, exc)
    finally:
        drop(query)


def drop(query: zenoh.Query) -> None:
    with contextlib.suppress(zenoh.ZError):
        query.drop()
