"""What every bad-input test asserts about the daemon afterwards, and about each refusal."""

from __future__ import annotations

import contextlib
import re
from collections.abc import Iterator

from tests.fuzz import tally
from tests.fuzz.daemon import FuzzDaemon

MAX_ERROR_REPLY = 4096  # bytes: an error reply never echoes a large request back
RSS_GROWTH_KB = 64 * 1024
BUG = re.compile(r"^(internal error|[A-Z]\w*(Error|Exception)\b)")  # how an unexpected exception reads in a reply


@contextlib.contextmanager
def unharmed(daemon: FuzzDaemon, rss_growth_kb: int = RSS_GROWTH_KB) -> Iterator[None]:
    """Whatever runs inside: the daemon lives, cycles, keeps its modes, moves nothing, and keeps its memory."""
    before = daemon.quiesce()
    daemon.settle()  # the baseline is a sample taken after the last controller let go, not one from just before
    daemon.motion.arm()
    yield
    assert daemon.alive(), daemon.log.read_text()[-4000:]
    assert "Traceback" not in daemon.log.read_text()  # no handler logged an unexpected exception
    daemon.settle()
    after = daemon.snapshot()
    assert after.cycles > before.cycles
    assert (after.mode, after.joint_modes) == (before.mode, before.joint_modes)
    assert after.faults == (None,) * len(after.faults)
    assert daemon.motion.max_deviation == 0.0
    assert after.rss_kb - before.rss_kb < rss_growth_kb


def refused(endpoint: str, daemon: FuzzDaemon, raw: bytes) -> dict[str, object]:
    """Query ``endpoint`` with ``raw``: one reply, ok false, a short reason that is not a leaked exception."""
    tally.count(endpoint)
    reply, size = daemon.query(endpoint, raw)
    if not daemon.alive():
        tally.CRASHES[endpoint] += 1
    assert reply["ok"] is False, f"{endpoint} accepted {raw[:200]!r}: {reply}"
    assert isinstance(reply["error"], str) and reply["error"], reply
    assert not BUG.match(reply["error"]), f"{endpoint}: {raw[:200]!r} hit a code path that raised: {reply['error']}"
    assert size < MAX_ERROR_REPLY, f"{size}-byte error reply"
    return reply
