"""The Zenoh floor for ``hild bench``: raw Zenoh on loopback between two processes, with no hild code in the path.

The echo side runs in a child process (``python -m hild.bench.probes.zenoh_loopback ENDPOINT``) as the daemon does:
a peer session listening on a loopback port, multicast scouting off. This process connects as a client, like
``HildClient``, and publishes as a client command does (express, INTERACTIVE_HIGH, congestion control DROP).
Measured:

* **ping-pong**: publish on ``ping``; the echo's subscriber republishes the bytes on ``pong`` from its callback;
  round trip = pong arrival − ping publish, and one-way = RTT / 2.
* **put → subscriber**: each sample carries its ``perf_counter_ns`` stamp; the echo's callback subtracts it from
  its own clock on arrival (CLOCK_MONOTONIC is system-wide, so stamps of two processes compare directly).

Everything is µs, p50/p99/p99.9/max.

The **decoy** (``python -m hild.bench.probes.zenoh_loopback decoy ENDPOINT ROBOT REPLIES.json``) stands in for a
daemon in the interference windows: a peer that answers the same service keys with replies captured from the real
daemon and decodes the same input samples, in its own process. Clients aimed at it load the machine as they would
load the daemon, but nothing reaches the daemon: the cycle's p99 rise against the decoy is what the machine (two
cores shared with the clients and Zenoh) costs, the rest is what serving the requests costs inside hild.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from hild.api.keys import Keys
from hild.api.session import client_config, declare_json_publisher, open_session, server_config
from hild.bench.children import end_child, free_endpoint
from hild.config.model import ZenohSection
from hild.crossing.stats import percentiles

PING, PONG, ONE_WAY, RESULTS = "hild_probe/ping", "hild_probe/pong", "hild_probe/oneway", "hild_probe/results"
PAYLOAD_PAD = bytes(56)  # a stamp plus padding: the size of a small JSON command
REPLY_TIMEOUT = 1.0  # s for one pong
START_TIMEOUT = 20.0  # s for the echo process to come up


def _publisher(session: zenoh.Session, key: str) -> zenoh.Publisher:
    return declare_json_publisher(session, key, priority=zenoh.Priority.INTERACTIVE_HIGH, express=True)


# ---- the echo process -------------------------------------------------------------------------------------------
def serve_echo(endpoint: str) -> int:
    """Echo pings and time one-way samples until stdin closes (the measuring process ends it that way)."""
    session = open_session(server_config(ZenohSection(listen=[endpoint])))
    pong = _publisher(session, PONG)
    arrivals: list[int] = []

    def on_ping(sample: zenoh.Sample) -> None:
        pong.put(sample.payload.to_bytes())

    def on_one_way(sample: zenoh.Sample) -> None:
        now = time.perf_counter_ns()
        arrivals.append(now - int.from_bytes(sample.payload.to_bytes()[:8], "little"))

    def on_results(query: zenoh.Query) -> None:
        query.reply(RESULTS, json.dumps(arrivals))

    entities = [
        session.declare_subscriber(PING, on_ping),
        session.declare_subscriber(ONE_WAY, on_one_way),
        session.declare_queryable(RESULTS, on_results),
    ]
    sys.stdin.read()  # until the parent closes the pipe
    for entity in entities:
        entity.undeclare()
    session.close()
    return 0


# ---- the decoy process ------------------------------------------------------------------------------------------
def serve_decoy(endpoint: str, robot: str, replies_path: str) -> int:
    """Answer ``{service: reply}`` queries and decode samples on the given input keys until stdin closes."""
    spec = json.loads(Path(replies_path).read_text(encoding="utf-8"))
    keys = Keys(robot)
    session = open_session(server_config(ZenohSection(listen=[endpoint])))
    decoded = [0]

    def answer(key: str, reply: bytes) -> Callable[[zenoh.Query], None]:
        def on_query(query: zenoh.Query) -> None:
            query.reply(key, reply, encoding=zenoh.Encoding.APPLICATION_JSON)

        return on_query

    def on_input(sample: zenoh.Sample) -> None:
        json.loads(sample.payload.to_bytes())
        decoded[0] += 1

    entities: list[Any] = [
        session.declare_queryable(keys.service(name), answer(keys.service(name), reply.encode()), complete=True)
        for name, reply in spec["replies"].items()
    ]
    entities += [session.declare_subscriber(keys.input(c, i), on_input) for c, i in spec["inputs"]]
    sys.stdout.write("ready\n")
    sys.stdout.flush()
    sys.stdin.read()  # until the parent closes the pipe
    for entity in entities:
        entity.undeclare()
    session.close()
    return 0


class Decoy:
    """A decoy daemon in a child process (see the module); a context manager, ``endpoint`` to connect to."""

    def __init__(self, robot: str, replies: dict[str, str], inputs: list[tuple[str, str]], spec_path: str) -> None:
        Path(spec_path).write_text(json.dumps({"replies": replies, "inputs": inputs}), encoding="utf-8")
        self.endpoint = free_endpoint()
        self._process = subprocess.Popen(
            [sys.executable, "-m", "hild.bench.probes.zenoh_loopback", "decoy", self.endpoint, robot, spec_path],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        assert self._process.stdout is not None
        if self._process.stdout.readline().strip() != "ready":
            self.close()
            raise RuntimeError(f"the decoy process did not come up (exit {self._process.poll()})")

    def close(self) -> None:
        end_child(self._process)

    def __enter__(self) -> Decoy:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# ---- the measuring side -----------------------------------------------------------------------------------------
class _Pongs:
    def __init__(self) -> None:
        self.arrived = threading.Event()
        self.stamp = 0
        self.seq = -1

    def __call__(self, sample: zenoh.Sample) -> None:
        self.stamp = time.perf_counter_ns()
        self.seq = int.from_bytes(sample.payload.to_bytes()[:8], "little")
        self.arrived.set()


def zenoh_round_trip(
    count: int = 2000, puts: int = 2000, put_rate: float = 1000.0, gap: float = 0.0005
) -> dict[str, Any]:
    """Ping-pong ``count`` times (``gap`` s apart) and ``puts`` stamped samples at ``put_rate`` Hz; see the module."""
    endpoint = free_endpoint()
    echo = subprocess.Popen([sys.executable, "-m", "hild.bench.probes.zenoh_loopback", endpoint], stdin=subprocess.PIPE)
    session = None
    try:
        deadline = time.monotonic() + START_TIMEOUT
        while session is None:
            try:
                session = open_session(client_config([endpoint]))
            except ConnectionError:
                if echo.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(f"the Zenoh echo process did not come up (exit {echo.poll()})") from None
                time.sleep(0.05)
        pongs = _Pongs()
        subscriber = session.declare_subscriber(PONG, pongs)
        ping = _publisher(session, PING)
        while True:  # until the echo's subscriber is declared and routed
            pongs.arrived.clear()
            ping.put((-1).to_bytes(8, "little", signed=True) + PAYLOAD_PAD)
            if pongs.arrived.wait(0.1):
                break
            if time.monotonic() > deadline:
                raise RuntimeError("the Zenoh echo process never answered a ping")
        rtt = np.zeros(count, dtype=np.int64)
        lost = 0
        for k in range(count):
            pongs.arrived.clear()
            start = time.perf_counter_ns()
            ping.put(k.to_bytes(8, "little") + PAYLOAD_PAD)
            if pongs.arrived.wait(REPLY_TIMEOUT) and pongs.seq == k:
                rtt[k] = pongs.stamp - start
            else:
                lost += 1
                rtt[k] = -1
            time.sleep(gap)
        rtt = rtt[rtt >= 0]
        one_way = _Publisher(session, ONE_WAY)
        period = 1.0 / put_rate
        next_put = time.perf_counter()
        for _ in range(puts):
            next_put += period
            delay = next_put - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
            one_way.put()
        time.sleep(0.1)  # let the last samples land
        arrivals: list[int] = []
        for reply in session.get(RESULTS, timeout=5.0):
            if reply.ok is not None:
                arrivals = json.loads(reply.ok.payload.to_bytes())
        subscriber.undeclare()
        ping.undeclare()
        one_way.undeclare()
        return {
            "endpoint": "tcp loopback, client → peer (as HildClient → daemon)",
            "pings": count,
            "lost": lost,
            "round_trip_us": percentiles(rtt, "ns"),
            "one_way_us": percentiles(rtt / 2, "ns"),
            "puts": puts,
            "put_rate_hz": put_rate,
            "received": len(arrivals),
            "put_to_subscriber_us": percentiles(arrivals, "ns"),
        }
    finally:
        if session is not None:
            session.close()
        end_child(echo)


class _Publisher:
    """Puts ``perf_counter_ns`` stamps (little-endian, padded) on one key."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        self._publisher = _publisher(session, key)

    def put(self) -> None:
        self._publisher.put(time.perf_counter_ns().to_bytes(8, "little") + PAYLOAD_PAD)

    def undeclare(self) -> None:
        self._publisher.undeclare()


if __name__ == "__main__":
    if sys.argv[1] == "decoy":
        sys.exit(serve_decoy(*sys.argv[2:5]))
    sys.exit(serve_echo(sys.argv[1]))
