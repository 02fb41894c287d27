"""A client thread that sends at a fixed rate, and a poller that keeps the daemon's peak RSS while it does."""

from __future__ import annotations

import json
import threading
import time
from collections import Counter
from collections.abc import Callable
from typing import Any

from tests.fuzz.daemon import FuzzDaemon

BATCH_PERIOD = 0.001  # s: the sender wakes every millisecond and sends what the rate owes by then


class Flood(threading.Thread):
    """Calls ``send()`` at ``rate`` Hz for ``seconds`` (in 1 ms batches: Python cannot sleep 100 µs reliably)."""

    def __init__(self, send: Callable[[], None], rate: float, seconds: float) -> None:
        super().__init__(name="flood", daemon=True)
        self.send, self.rate, self.seconds = send, rate, seconds
        self.sent = 0
        self.elapsed = 0.0

    def run(self) -> None:
        start = time.perf_counter()
        while (now := time.perf_counter() - start) < self.seconds:
            owed = int(now * self.rate) - self.sent
            for _ in range(owed):
                self.send()
            self.sent += max(owed, 0)
            time.sleep(BATCH_PERIOD)
        self.elapsed = time.perf_counter() - start

    @property
    def achieved(self) -> float:
        return self.sent / self.elapsed if self.elapsed else 0.0


class QueryFlood(Flood):
    """Queries one key at ``rate`` Hz; replies wait in Zenoh's channels (a Python callback per reply would cost the
    client ~0.5 ms each and cap it far below the rate) and are counted by :meth:`outcomes` afterwards."""

    def __init__(self, daemon: FuzzDaemon, suffix: str, raw: bytes, rate: float, seconds: float) -> None:
        querier = daemon.session.declare_querier(daemon.key(suffix), timeout=5.0)
        self.handlers: list[Any] = []
        super().__init__(lambda: self.handlers.append(querier.get(payload=raw)), rate, seconds)

    def outcomes(self) -> Counter[str]:
        """Replies by kind: "ok", the error's first word ("busy", "malformed JSON", …), or "no reply"."""
        kinds: Counter[str] = Counter()
        for handler in self.handlers:
            replies = list(handler)
            if not replies:
                kinds["no reply"] += 1
            for reply in replies:
                if reply.ok is None:
                    kinds["zenoh error"] += 1
                    continue
                body = json.loads(reply.ok.payload.to_bytes())
                kinds["ok" if body.get("ok") else str(body.get("error")).split(":")[0]] += 1
        return kinds


class PeakRss(threading.Thread):
    def __init__(self, daemon: FuzzDaemon, period: float = 0.01) -> None:
        super().__init__(name="rss", daemon=True)
        self.daemon_ = daemon
        self.period = period
        self.peak_kb = daemon.rss_kb()
        self.stopped = threading.Event()

    def run(self) -> None:
        while not self.stopped.is_set():
            self.peak_kb = max(self.peak_kb, self.daemon_.rss_kb())
            self.stopped.wait(self.period)

    def __enter__(self) -> PeakRss:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stopped.set()
        self.join()
