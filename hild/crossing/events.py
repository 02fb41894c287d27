"""Events: mode changes, faults, switches — one record each, never one per cycle.

The cycle appends to a bounded deque (atomic under the GIL) and wakes the client domain (``on_emit``). In the
cycle process its outbox moves them into the shared region's events queue, where a full queue counts them lost; in
the in-process case the asyncio loop drains the deque itself. The client domain logs each event once and publishes
it. If nobody drains, the oldest events are dropped, never the cycle.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

log = logging.getLogger("hild.events")

_LOG_LEVEL = {"debug": logging.DEBUG, "info": logging.INFO, "warning": logging.WARNING, "error": logging.ERROR}


@dataclass(frozen=True, slots=True)
class Event:
    stamp: float  # cycle clock time (s)
    level: str
    source: str
    message: str

    def as_dict(self) -> dict[str, object]:
        return {"stamp": self.stamp, "level": self.level, "source": self.source, "message": self.message}


class EventLog:
    def __init__(self, capacity: int = 4096) -> None:
        self._events: deque[Event] = deque(maxlen=capacity)
        self.now: Callable[[], float] = lambda: 0.0  # cycle clock, set by the engine
        self.on_emit: Callable[[], None] = lambda: None  # the engine's: wake the client domain

    def emit(self, level: str, source: str, message: str) -> None:
        self._events.append(Event(self.now(), level, source, message))
        self.on_emit()

    def drain(self) -> list[Event]:
        out: list[Event] = []
        while True:
            try:
                out.append(self._events.popleft())
            except IndexError:
                return out


def log_event(event: Event) -> None:
    log.log(_LOG_LEVEL.get(event.level, logging.INFO), "[%s] %s", event.source, event.message)
