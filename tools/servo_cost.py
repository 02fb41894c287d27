#!/usr/bin/env python3
"""Where a streamed servo target's time goes in the cycle: the arm6 twin in lockstep, a servo on 3 or 6 joints
fed a slow sine (the bench's interference stream: 0.05 rad at 0.5 Hz, positions only) at 1 kHz (a new target
every cycle) or 100 Hz, or not at all.

    python tools/servo_cost.py                  # 3 and 6 joints, 1 kHz / 100 Hz / none, hot and cold caches
    python tools/servo_cost.py --cycles 4000 --joints 3

Per cycle, median µs (less the timer's own cost), split into:

- *take*: taking the target through the crossing — a ``TargetRecord`` over the shared region, as in the cycle
  process (the API side's validation and put are not the cycle's work and are not counted);
- *ruckig new* / *ruckig same*: ruckig's ``update`` on a cycle that took a new target (a re-plan) and on one that
  did not (stepping the plan); *replans* is how many cycles in 100 re-planned;
- *servo rest*: the servo's ``update`` less the two above (list round trips, phase logic, writing the command);
- *servo*: the servo's whole ``update``; *supervisor*: its check and command; *step*: the whole engine step
  (twin physics included).

*hot*: cycles back to back, so code and data stay in the caches (a lower bound). *cold*: 16 MiB are read between
cycles (outside the timed spans), which evicts the caches the way the daemon's 1 ms of sleep beside other
processes does — closer to what the paced cycle pays; its figures move more from run to run. Compare two
checkouts on the same machine with ``PYTHONPATH=<checkout>``; the servo's internals this tool instruments
(``_slot``, ``_otg``, ``update``) are the same in both.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

sys.path.append(str(Path(__file__).resolve().parent.parent))  # PYTHONPATH=<checkout> comes first

from hild.bench.daemon import CONFIGS
from hild.bench.measure import lockstep_engine
from hild.controllers.servo import ServoController, TargetRecord
from hild.crossing.mailboxes import Shared
from hild.crossing.region import Region

AMPLITUDE, FREQUENCY = 0.05, 0.5  # rad, Hz: hild.bench.load's servo stream
EVICT = np.ones(16 << 20, dtype=np.uint8)
SPANS = ("take", "ruckig new", "ruckig same", "servo", "supervisor", "step")
clock = time.perf_counter_ns


class Spans:
    """Nanoseconds per span name for the cycle being measured; ``close`` files them under the cycle's kind."""

    def __init__(self) -> None:
        self.now: dict[str, int] = {}
        self.cycles: list[tuple[bool, dict[str, int]]] = []

    def add(self, name: str, ns: int) -> None:
        self.now[name] = self.now.get(name, 0) + ns

    def close(self, new_target: bool) -> None:
        self.cycles.append((new_target, self.now))
        self.now = {}


def timed(spans: Spans, name: str, fn: Callable[..., Any]) -> Callable[..., Any]:
    def call(*args: Any) -> Any:
        t0 = clock()
        result = fn(*args)
        spans.add(name, clock() - t0)
        return result

    return call


class TimedRuckig:
    """Stands in for the servo's ``Ruckig``: times each ``update``, filed as a re-plan when a target was taken."""

    def __init__(self, otg: Any, spans: Spans) -> None:
        self._otg, self._spans = otg, spans
        self.new_target = False

    @property
    def delta_time(self) -> float:
        return float(self._otg.delta_time)

    @delta_time.setter
    def delta_time(self, value: float) -> None:
        self._otg.delta_time = value

    def update(self, inp: Any, out: Any) -> Any:
        t0 = clock()
        result = self._otg.update(inp, out)
        self._spans.add("ruckig new" if self.new_target else "ruckig same", clock() - t0)
        return result

    def reset(self) -> None:
        self._otg.reset()


def timer_cost() -> float:
    spans = [clock() - clock() for _ in range(20_000)]
    return float(-np.median(spans))


def measure(joints: int, every: int, cold: bool, cycles: int) -> dict[str, float]:
    """Median µs per span over ``cycles`` (a new target every ``every`` cycles; 0: none), and the re-plan share."""
    engine = lockstep_engine(CONFIGS / "arm6_twin.yaml")
    try:
        names = list(engine.joints)[-joints:]
        engine.load_controller("servo_cost", "servo", {"joints": names, "command_timeout": 0.25})
        assert engine.switch(["servo_cost"], []).ok
        servo = engine.manager.records["servo_cost"].instance
        assert isinstance(servo, ServoController)
        region = Region(1 << 22)
        api = TargetRecord(Shared(region, create=True).latest_numbers("target", TargetRecord.width(joints)), joints)
        cycle_side = Shared(Region.attach(region.fd, 1 << 22), create=False)
        take = TargetRecord(cycle_side.latest_numbers("target", TargetRecord.width(joints)), joints)
        spans = Spans()
        otg = TimedRuckig(servo._otg, spans)
        servo._otg = otg  # type: ignore[assignment]
        servo._slot = take
        take.take = timed(spans, "take", take.take)  # type: ignore[method-assign]
        servo.update = timed(spans, "servo", servo.update)  # type: ignore[method-assign]
        sup = engine.supervisor
        sup.check = timed(spans, "supervisor", sup.check)  # type: ignore[method-assign]
        sup.command = timed(spans, "supervisor", sup.command)  # type: ignore[method-assign]
        home = engine.state.position[-joints:].tolist()

        def send() -> None:
            phase = AMPLITUDE * math.sin(2 * math.pi * FREQUENCY * engine.t)
            servo._slot = api
            try:
                servo.accept({"positions": [p + phase for p in home]})
            finally:
                servo._slot = take

        warmup = 500
        for k in range(warmup + cycles):
            new = every > 0 and k % every == 0
            if new:
                send()
            if cold:
                EVICT.sum()
            otg.new_target = new
            t0 = clock()
            engine.run_cycles(1)
            spans.add("step", clock() - t0)
            spans.close(new)
    finally:
        engine.stop()
    measured = spans.cycles[warmup:]
    overhead = timer_cost()
    out: dict[str, float] = {}
    for name in SPANS:
        values = [c[name] for _, c in measured if name in c]
        out[name] = max(0.0, float(np.median(values)) - overhead) / 1e3 if values else math.nan
    replans = [c for new, c in measured if new and "ruckig new" in c]
    out["replans %"] = 100.0 * len(replans) / len(measured)
    rest = [c["servo"] - c.get("take", 0) - c.get("ruckig new", 0) - c.get("ruckig same", 0) for _, c in measured]
    out["servo rest"] = max(0.0, float(np.median(rest)) - 4 * overhead) / 1e3
    return out


STREAMS = {"1 kHz": 1, "100 Hz": 10, "none": 0}
COLUMNS = ("take", "ruckig new", "ruckig same", "servo rest", "servo", "supervisor", "step", "replans %")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--joints", type=int, nargs="+", default=[3, 6], choices=range(1, 7), metavar="N")
    parser.add_argument("--cycles", type=int, default=3000)
    parser.add_argument("--hot-only", action="store_true", help="skip the cold-cache runs")
    args = parser.parse_args()
    print(f"servo on the arm6 twin, lockstep, median µs per cycle of {args.cycles}")
    head = f"{'cache':<5} {'joints':>6} {'stream':>7} " + " ".join(f"{c:>11}" for c in COLUMNS)
    print(head)
    for cold in (False,) if args.hot_only else (False, True):
        for joints in args.joints:
            for stream, every in STREAMS.items():
                row = measure(joints, every, cold, args.cycles)
                cells = " ".join("—".rjust(11) if math.isnan(row[c]) else f"{row[c]:11.2f}" for c in COLUMNS)
                print(f"{'cold' if cold else 'hot':<5} {joints:>6} {stream:>7} {cells}")


if __name__ == "__main__":
    main()
