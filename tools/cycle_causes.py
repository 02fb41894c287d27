#!/usr/bin/env python3
"""Why a cycle in the daemon takes longer than the same cycle in a loop: two measured causes, one command.

    python tools/cycle_causes.py [configs/arm6_twin.yaml] [--rate 1000] [--cycles 3000]

1. **Waking up cold.** The engine runs the standard trajectory in lockstep on the sim clock; each cycle is timed
   after the thread (a) ran the previous cycle straight away (hot), (b) slept 0.8 ms, (c) slept 0.6 ms then spun
   0.2 ms (the cycle thread's default ``spin_us``), (d) slept 0.4 ms then spun 0.4 ms, (e) spun 0.8 ms. On a VM
   the idle vCPU wakes slowly and comes back to cold caches: (b) and (c) are what the daemon's cycle pays.
2. **The GIL, given away.** MuJoCo's ``mj_step`` (like every socket call on a real CAN bus) releases the GIL.
   While one thread loops over ``mj_step`` for a second, another pure-Python thread counts; then the same with a
   pure-Python loop. With the switch interval at 1 s, the second count is zero: pure Python never lets go, a
   release always does, and the cycle thread then waits until the other thread gives the GIL back (up to
   ``realtime.switch_interval``).
3. **A busy neighbour: thread or process?** The cycle runs as in the daemon (sleep to 0.2 ms before the deadline,
   spin, step, at ``--rate``) while a neighbour does a servo sample's worth of API work (decode a JSON target and
   validate it, ~30 µs of Python) at 1 kHz: none, as a thread of this process (what the daemon's Zenoh callbacks
   are), or as a separate process (what an API process split off the daemon would be). Conditions are
   interleaved in short blocks so the machine's drift hits all alike. Thread ≫ process ≈ none: the GIL is the
   cost and a split removes it; thread ≈ process: the cost is two cores shared, and a split cannot help.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from hild.api.goals import GoalEndpoint
from hild.bench.measure import lockstep_engine
from hild.crossing.stats import percentiles
from hild.cycle.engine import Engine
from hild.cycle.pacing import wait_until
from hild.motion.reference import standard_trajectory

CONDITIONS = (  # label, sleep (s), spin (ns)
    ("hot (back to back)", 0.0, 0),
    ("sleep 0.8 ms", 0.0008, 0),
    ("sleep 0.6 + spin 0.2 ms", 0.0006, 200_000),
    ("sleep 0.4 + spin 0.4 ms", 0.0004, 400_000),
    ("spin 0.8 ms", 0.0, 800_000),
)


def wake_costs(engine: Engine, cycles: int) -> list[tuple[str, float, float]]:
    jtc = engine.manager.records["joint_trajectory"].instance
    home = engine.state.position.copy()
    rows = []
    for label, sleep, spin in CONDITIONS:
        reply = GoalEndpoint.of(jtc.action).submit(standard_trajectory(engine.joints, home))
        if not reply["ok"]:
            raise SystemExit(f"goal rejected: {reply['error']}")
        took = np.empty(cycles)
        for k in range(cycles):
            if sleep:
                time.sleep(sleep)
            end = time.perf_counter_ns() + spin
            while time.perf_counter_ns() < end:
                pass
            start = time.perf_counter_ns()
            engine.run_cycles(1)
            took[k] = (time.perf_counter_ns() - start) / 1e3
        figures = percentiles(took, "us")
        rows.append((label, figures["p50"], figures["p99"]))
    return rows


def gil_release(engine: Engine) -> dict[str, int]:
    from hild.bench.probes.mj_step import gil_release as measure

    twin = engine.hardware[0].component
    return measure(twin.model, twin.data)


NEIGHBOUR_RATE = 1000.0  # Hz: a 1 kHz servo stream
SAMPLE = json.dumps({"positions": [0.1, -0.2, 0.3], "velocities": [0.0, 0.0, 0.0]}).encode()


def api_work() -> None:
    """One servo sample's worth of the API side: decode, check every value, build the target."""
    payload = json.loads(SAMPLE)
    for _ in range(12):
        values = [float(v) for v in payload["positions"]]
        if not all(-10.0 < v < 10.0 for v in values) or len(payload["velocities"]) != len(values):
            raise ValueError("bad sample")


def neighbour(stop: threading.Event | None = None, seconds: float = 1e9) -> None:
    """``api_work`` at NEIGHBOUR_RATE on an absolute schedule, until ``stop`` or ``seconds``."""
    period = 1.0 / NEIGHBOUR_RATE
    start = next_call = time.perf_counter()
    while (stop is None or not stop.is_set()) and time.perf_counter() - start < seconds:
        api_work()
        next_call += period
        delay = next_call - time.perf_counter()
        if delay > 0:
            time.sleep(delay)


def paced_cycles(engine: Engine, count: int, rate: float) -> np.ndarray:
    """``count`` cycles paced as the daemon's cycle thread paces them; their durations in µs."""
    period = round(1e9 / rate)
    took = np.empty(count)
    deadline = time.perf_counter_ns()
    for k in range(count):
        deadline += period
        wait_until(deadline)  # the cycle thread's own sleep-then-spin, with its default spin
        start = time.perf_counter_ns()
        engine.run_cycles(1)
        took[k] = (time.perf_counter_ns() - start) / 1e3
    return took


def neighbour_costs(engine: Engine, rate: float, rounds: int, block: int) -> list[tuple[str, float, float, float]]:
    """Cycle p50/p99/p99.9 with no neighbour, a neighbour thread, a neighbour process (interleaved blocks)."""
    jtc = engine.manager.records["joint_trajectory"].instance
    home = engine.state.position.copy()
    took: dict[str, list[np.ndarray]] = {"none": [], "thread (same GIL)": [], "process (own GIL)": []}
    for _ in range(rounds):
        reply = GoalEndpoint.of(jtc.action).submit(standard_trajectory(engine.joints, home))
        if not reply["ok"]:
            raise SystemExit(f"goal rejected: {reply['error']}")
        engine.run_cycles(5)
        took["none"].append(paced_cycles(engine, block, rate))
        stop = threading.Event()
        thread = threading.Thread(target=neighbour, args=(stop,), daemon=True)
        thread.start()
        took["thread (same GIL)"].append(paced_cycles(engine, block, rate))
        stop.set()
        thread.join()
        process = subprocess.Popen([sys.executable, __file__, "--neighbour"], stdin=subprocess.PIPE)
        time.sleep(0.2)  # started and paced
        took["process (own GIL)"].append(paced_cycles(engine, block, rate))
        process.kill()
        process.wait()
    rows = []
    for label, blocks in took.items():
        figures = percentiles(np.concatenate(blocks), "us")
        rows.append((label, figures["p50"], figures["p99"], figures["p999"]))
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("config", nargs="?", default="configs/arm6_twin.yaml")
    parser.add_argument("--rate", type=float, default=1000.0)
    parser.add_argument("--cycles", type=int, default=3000)
    parser.add_argument("--rounds", type=int, default=10, help="part 3: interleaved rounds of each condition")
    parser.add_argument("--neighbour", action="store_true", help=argparse.SUPPRESS)  # part 3's neighbour process
    args = parser.parse_args()
    if args.neighbour:
        neighbour()
        return 0
    engine = lockstep_engine(Path(args.config), args.rate)
    if not engine.switch(["joint_trajectory"], []).ok:
        raise SystemExit("cannot activate joint_trajectory")
    engine.run_cycles(50)
    print(f"1. one cycle of {Path(args.config).name} at {args.rate:g} Hz, trajectory running (µs)")
    print(f"   {'before the cycle':26s} {'p50':>7} {'p99':>7}")
    for label, p50, p99 in wake_costs(engine, args.cycles):
        print(f"   {label:26s} {p50:7.1f} {p99:7.1f}")
    print("2. increments a pure-Python thread made while another thread looped for 1 s over")
    for label, count in gil_release(engine).items():
        print(f"   {label:12s} {count:>12,}")
    block = max(100, args.cycles // args.rounds)
    print(f"3. one paced cycle at {args.rate:g} Hz, a 1 kHz neighbour doing API work ({args.rounds} × {block} cycles)")
    print(f"   {'neighbour':26s} {'p50':>7} {'p99':>7} {'p99.9':>7}")
    for label, p50, p99, p999 in neighbour_costs(engine, args.rate, args.rounds, block):
        print(f"   {label:26s} {p50:7.1f} {p99:7.1f} {p999:7.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
