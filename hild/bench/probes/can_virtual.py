"""The CAN floor for ``hild bench``: python-can's ``virtual`` bus alone, with no driver, codec or emulator.

Both directions run on one thread: send on bus A, ``recv(timeout=0)`` on bus B (the
virtual bus delivers synchronously, into B's queue, inside A's ``send``), then a reply back. What remains is the
cost python-can itself adds per frame, the part of the driver's read/write time no driver change can remove.
"""

from __future__ import annotations

import time
import uuid
from typing import Any

import numpy as np

from drivers.can.bus import BusSpec, CanLink, open_bus
from hild.crossing.stats import percentiles

WARMUP_FRAMES = 1000


def virtual_round_trip(count: int = 20_000, **_: Any) -> dict[str, Any]:
    """One-way (send on A → recv on B) and request → reply (A → B → A) on a private virtual channel, µs."""
    if count < 1:
        raise ValueError("count must be positive")
    spec = BusSpec(interface="virtual", channel=f"hild-probe-{uuid.uuid4().hex[:10]}")
    host, drive = open_bus(spec), open_bus(spec)
    link = CanLink(spec)
    request = link.make_message(0x001, bytes(8))
    reply = link.make_message(0x011, bytes(8))
    one_way = np.empty(count)
    round_trip = np.empty(count)
    clock = time.perf_counter
    try:
        for k in range(count + WARMUP_FRAMES):
            start = clock()
            host.send(request, timeout=0)
            got = drive.recv(timeout=0)
            middle = clock()
            drive.send(reply, timeout=0)
            back = host.recv(timeout=0)
            end = clock()
            if got is None or back is None:
                raise RuntimeError("the virtual bus did not deliver a frame synchronously")
            if k >= WARMUP_FRAMES:
                one_way[k - WARMUP_FRAMES] = middle - start
                round_trip[k - WARMUP_FRAMES] = end - start
    finally:
        host.shutdown()
        drive.shutdown()
    return {"frames": count, "one_way_us": percentiles(one_way, "s"), "round_trip_us": percentiles(round_trip, "s")}
