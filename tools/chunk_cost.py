"""The servo's ``update`` cost per cycle: at rest, with a streamed target every cycle, with a policy's chunks.

    python tools/chunk_cost.py [--cycles 2500] [--rounds 2]

configs/arm6_twin.yaml at 500 Hz in lockstep (hild.bench.chunks' twin and reference); a servo loaded for it; each
condition a fresh engine, the conditions interleaved round by round so a drift of the machine hits all alike. The
first 500 cycles of each run are left out (the arm catching up). Thread CPU time (CLOCK_THREAD_CPUTIME_ID), so a
busy machine's preemptions stay out of it, though not its caches; rerun on a quiet machine before quoting.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import numpy as np

from hild.bench.chunks import Reference, twin_engine

CONDITIONS = ("rest", "target", "chunk")
SKIP = 500


def measure(condition: str, cycles: int) -> np.ndarray:
    engine = twin_engine()
    try:
        joints = list(engine.manager.records["joint_trajectory"].instance.params.joints)
        engine.load_controller("policy", "servo", {"joints": joints, "command_timeout": 5.0})
        assert engine.switch(["policy"], []).ok
        servo = engine.manager.records["policy"].instance
        index = [engine.joints.index(j) for j in joints]
        lim = engine.limits
        home = engine.state.position[index].copy()
        ref = Reference(home, lim.velocity[index], lim.acceleration[index], lim.jerk[index])
        costs: list[int] = []
        update = servo.update

        def timed(*args: Any) -> None:
            start = time.thread_time_ns()
            update(*args)
            costs.append(time.thread_time_ns() - start)

        servo.update = timed
        for k in range(cycles):
            t = engine.t
            if condition == "chunk" and k % 50 == 0:  # 10 Hz at 500 Hz
                chunk = ref.at(t + 0.02 * np.arange(50))
                servo.accept_chunk({"stamp": t, "dt": 0.02, "positions": chunk.tolist()})
            elif condition == "target":
                servo.accept({"positions": ref.at(t + engine.period).tolist()})
            engine.run_cycles(1)
        return np.array(costs[SKIP:]) / 1e3
    finally:
        engine.stop()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cycles", type=int, default=2500)
    parser.add_argument("--rounds", type=int, default=2)
    args = parser.parse_args()
    for _ in range(args.rounds):
        for condition in CONDITIONS:
            us = measure(condition, args.cycles)
            print(f"{condition:<7} update p50 {np.percentile(us, 50):6.1f} µs  p99 {np.percentile(us, 99):7.1f} µs")


if __name__ == "__main__":
    main()
