#!/usr/bin/env python3
"""What a streamed servo target costs the cycle to take from shared memory: the pickle it crossed as before, the
numeric record it crosses as now.

    python tools/input_crossing.py               # 6 joints, 20 000 takes each, median
    python tools/input_crossing.py --joints 7 --takes 50000

Each take follows a fresh put (as in a stream at the cycle's rate); only the take is timed, and the timer's own
cost (an empty timed span) is subtracted. *pickle*: a ``SharedLatest`` holding a ``ServoTarget`` as it was then
(lists and a note string), unpickled by the take. *numbers*: the servo's ``TargetRecord`` over a ``NumbersCell``;
*numbers + lists* adds the two ``tolist()`` calls the servo makes to hand positions and velocities to ruckig.
Wall clock on this machine, garbage collector on as in the cycle process.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from hild.controllers.servo import ServoTarget, TargetRecord
from hild.crossing.latest import LatestCell, latest_bytes
from hild.crossing.mailboxes import LATEST_BYTES, Shared, SharedLatest
from hild.crossing.region import Region
from hild.crossing.stats import percentiles


@dataclasses.dataclass(frozen=True, slots=True)
class PickledTarget:
    """``ServoTarget`` as it crossed before: what the cycle unpickled."""

    positions: list[float]
    velocities: list[float]
    moving: bool
    clamped: str


def median_take(put: Callable[[], None], take: Callable[[], object], takes: int) -> float:
    """Median of ``takes`` timed takes, each after a fresh put, in µs, less the timer's own cost."""
    clock = time.perf_counter_ns
    spans, empty = [], []
    for _ in range(takes):
        put()
        t0 = clock()
        got = take()
        t1 = clock()
        t2 = clock()
        empty.append(t2 - t1)
        spans.append(t1 - t0)
        assert got is not None
    return percentiles(spans, "ns", digits=3)["p50"] - percentiles(empty, "ns", digits=3)["p50"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--joints", type=int, default=6)
    parser.add_argument("--takes", type=int, default=20_000)
    args = parser.parse_args()
    n = args.joints
    region = Region(1 << 22)
    positions, velocities = [0.1 * k for k in range(n)], [0.0] * n

    cell = region.carve("pickled", latest_bytes(LATEST_BYTES))
    writer: SharedLatest[PickledTarget] = SharedLatest(LatestCell(cell, writer_lock=threading.Lock()))
    reader: SharedLatest[PickledTarget] = SharedLatest(LatestCell(cell))
    old = PickledTarget(positions, velocities, False, "")

    api = Shared(region, create=True)
    cycle = Shared(Region.attach(region.fd, 1 << 22), create=False)
    put_side = TargetRecord(api.latest_numbers("target", TargetRecord.width(n)), n)
    take_side = TargetRecord(cycle.latest_numbers("target", TargetRecord.width(n)), n)
    new = ServoTarget(positions, velocities, False)

    def numbers_and_lists() -> object:
        if not take_side.take():
            return None
        return take_side.positions.tolist(), take_side.velocities.tolist()

    rows = {
        "pickle": median_take(lambda: writer.put(old), reader.take, args.takes),
        "numbers": median_take(lambda: put_side.put(new), lambda: take_side.take() or None, args.takes),
        "numbers + lists": median_take(lambda: put_side.put(new), numbers_and_lists, args.takes),
    }
    print(f"{n} joints, median of {args.takes} takes")
    for name, us in rows.items():
        print(f"  {name:<16} {us:6.2f} µs")


if __name__ == "__main__":
    main()
