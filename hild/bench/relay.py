"""A joint_states relay that delays and drops: the network between a leader and its follower, made bad on purpose.

It subscribes to ``hild/<source>/joint_states`` through one Zenoh session and republishes each message unchanged
(its ``seq`` and ``stamp`` too, so the follower sees the gaps) as ``hild/<target>/joint_states`` through another,
after ``delay`` ± ``jitter`` seconds, dropping each with probability ``loss``. Two client sessions, one per side,
so the two daemons need not reach each other: on loopback, with explicit endpoints and no scouting, nothing else
is found. Messages leave in order (a jittered release is never before the previous one's), as a TCP link would
deliver them.

Run it as a process of its own (``python -m hild.bench.relay --help``), from tests and ``hild bench --only
teleop``, or from a shell beside two daemons (README, "Teleoperate one arm with another"). On SIGTERM or SIGINT
it prints one JSON line of counts (received, dropped, sent) and exits 0.
"""

from __future__ import annotations

import argparse
import json
import random
import signal
import sys
import threading
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import zenoh

from hild.api.session import client_config, open_session

READY = "relay ready"  # printed once both sessions are open and the subscriber is declared


@dataclass
class RelayCounts:
    received: int = 0
    dropped: int = 0
    sent: int = 0


class Relay:
    """Delays and drops one key's samples into another key (thread-safe: Zenoh's thread in, one sender out)."""

    def __init__(
        self,
        source: zenoh.Session,
        target: zenoh.Session,
        source_key: str,
        target_key: str,
        delay: float,
        jitter: float = 0.0,
        loss: float = 0.0,
        seed: int | None = None,
    ) -> None:
        if delay < 0.0 or jitter < 0.0 or jitter > delay or not 0.0 <= loss < 1.0:
            raise ValueError("need delay ≥ jitter ≥ 0 and 0 ≤ loss < 1")
        self.delay, self.jitter, self.loss = delay, jitter, loss
        self.counts = RelayCounts()
        self._random = random.Random(seed)
        self._queue: deque[tuple[float, bytes]] = deque()
        self._wake = threading.Condition()
        self._last_release = 0.0
        self._stopping = False
        self._publisher = target.declare_publisher(target_key, express=True)
        self._subscriber = source.declare_subscriber(source_key, self._arrived)
        self._sender = threading.Thread(target=self._send, name="relay-sender", daemon=True)
        self._sender.start()

    def _arrived(self, sample: zenoh.Sample) -> None:
        now = time.monotonic()
        with self._wake:
            self.counts.received += 1
            if self._random.random() < self.loss:
                self.counts.dropped += 1
                return
            release = now + self.delay + self._random.uniform(-self.jitter, self.jitter)
            self._last_release = release = max(release, self._last_release)
            self._queue.append((release, sample.payload.to_bytes()))
            self._wake.notify()

    def _send(self) -> None:
        while True:
            with self._wake:
                while not self._queue and not self._stopping:
                    self._wake.wait()
                if self._stopping:
                    return
                release, payload = self._queue[0]
                wait = release - time.monotonic()
                if wait > 0.0:
                    self._wake.wait(wait)  # a new arrival wakes us early: its release is never sooner
                    continue
                self._queue.popleft()
            self._publisher.put(payload)
            self.counts.sent += 1

    def close(self) -> None:
        with self._wake:
            self._stopping = True
            self._wake.notify()
        self._sender.join(timeout=2.0)
        self._subscriber.undeclare()
        self._publisher.undeclare()


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m hild.bench.relay", description=__doc__.split("\n\n")[0])
    parser.add_argument("--from", dest="source", required=True, help="robot whose joint_states are relayed")
    parser.add_argument("--to", dest="target", required=True, help="robot name they are republished as")
    parser.add_argument("--source-connect", required=True, help="Zenoh endpoint of the source robot's daemon")
    parser.add_argument("--target-connect", required=True, help="Zenoh endpoint of the follower's daemon")
    parser.add_argument("--delay", type=float, default=0.05, help="s, one way (default 0.05)")
    parser.add_argument("--jitter", type=float, default=0.0, help="s, uniform ± around the delay (default 0)")
    parser.add_argument("--loss", type=float, default=0.0, help="probability a message is dropped (default 0)")
    parser.add_argument("--seed", type=int, default=None, help="for a reproducible loss and jitter")
    args = parser.parse_args(argv)
    source = open_session(client_config([args.source_connect]))
    target = open_session(client_config([args.target_connect]))
    relay = Relay(
        source,
        target,
        f"hild/{args.source}/joint_states",
        f"hild/{args.target}/joint_states",
        args.delay,
        args.jitter,
        args.loss,
        args.seed,
    )
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    print(READY, flush=True)
    while not stop.wait(0.2):  # a timeout, so the signal handler runs promptly
        pass
    relay.close()
    print(json.dumps(asdict(relay.counts)), flush=True)
    source.close()
    target.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
