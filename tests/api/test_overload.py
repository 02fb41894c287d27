"""An overloaded service says "busy" (issue [layout], item 7.2): every query gets exactly one reply.

Beside busy processes a 10 kHz flood of status queries left 105 of 19 991 queries without any reply: read-only
queries waited in a Zenoh ring of ``READ_BACKLOG`` per service for the asyncio loop to answer them in a batch, and
when the loop came late the ring made room by dropping its oldest, which Zenoh then finished without a reply. The
test holds the loop (blocked in a call, as a starved process's loop is) while more queries than the backlog arrive:
each must still get one reply, "ok" or "busy", and the ones beyond the backlog at once.
"""

from __future__ import annotations

import json
import threading
from collections import Counter

import zenoh

from hild.api.client import HildClient
from hild.api.queries import READ_BACKLOG
from tests.api.conftest import WAIT, Daemon
from tests.helpers import wait_for

EXTRA = 200  # queries beyond the backlog


class Outcomes:
    """Replies and ends of many queries, counted from Zenoh's threads."""

    def __init__(self, count: int) -> None:
        self.replies: list[list[str]] = [[] for _ in range(count)]
        self.ended = 0
        self._lock = threading.Lock()

    def handler(self, k: int) -> zenoh.handlers.Callback[zenoh.Reply]:
        def reply(answer: zenoh.Reply) -> None:
            body = json.loads(answer.ok.payload.to_bytes()) if answer.ok is not None else {"error": "zenoh error"}
            with self._lock:
                self.replies[k].append("ok" if body.get("ok") else str(body.get("error")).split(":")[0])

        def end() -> None:
            with self._lock:
                self.ended += 1

        return zenoh.handlers.Callback(reply, end)

    def kinds(self) -> Counter[str]:
        with self._lock:
            return Counter(r[0] if len(r) == 1 else f"{len(r)} replies" for r in self.replies)


def test_queries_beyond_the_backlog_are_answered_busy_at_once_while_the_loop_is_held(
    daemon: Daemon, client: HildClient
) -> None:
    count = READ_BACKLOG + EXTRA
    outcomes = Outcomes(count)
    querier = client.session.declare_querier(f"hild/{daemon.engine.robot}/srv/status", timeout=WAIT)
    held = threading.Event()
    release = threading.Event()
    daemon.loop.call_soon_threadsafe(lambda: (held.set(), release.wait(WAIT)))
    try:
        assert held.wait(WAIT)
        for k in range(count):
            querier.get(handler=outcomes.handler(k))
        wait_for(lambda: outcomes.ended >= EXTRA, timeout=WAIT, what=f"{EXTRA} queries answered while held")
    finally:
        release.set()
    wait_for(lambda: outcomes.ended == count, timeout=WAIT, what="every query answered")
    kinds = outcomes.kinds()
    assert set(kinds) <= {"ok", "busy"} and kinds["busy"] >= EXTRA, kinds  # one reply each, never silence
    querier.undeclare()
