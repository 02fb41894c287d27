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
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from hild.config import load_config
from hild.engine import Engine
from hild.motion.reference import standard_trajectory

CONDITIONS = (  # label, sleep (s), spin (ns)
    ("hot (back to back)", 0.0, 0),
    ("sleep 0.8 ms", 0.0008, 0),
    ("sleep 0.6 + spin 0.2 ms", 0.0006, 200_000),
    ("sleep 0.4 + spin 0.4 ms", 0.0004, 400_000),
    ("spin 0.8 ms", 0.0, 800_000),
)


def lockstep_engine(config: Path, rate: float) -> Engine:
    loaded = load_config(config)
    cfg = loaded.config
    for name, params in loaded.driver_params.items():  # keep the twin's physics step
        substeps = getattr(params, "substeps", None)
        if substeps is not None:
            loaded.driver_params[name] = params.model_copy(
                update={"substeps": max(1, round(substeps * cfg.update_rate / rate))}
            )
    clock = cfg.clock.model_copy(update={"source": "sim", "real_time_factor": 0.0})
    loaded.config = cfg.model_copy(update={"update_rate": rate, "clock": clock})
    engine = Engine(loaded)
    engine.start()
    return engine


def wake_costs(engine: Engine, cycles: int) -> list[tuple[str, float, float]]:
    jtc = engine.manager.records["joint_trajectory"].instance
    home = engine.state.position.copy()
    rows = []
    for label, sleep, spin in CONDITIONS:
        reply = jtc.action.submit(standard_trajectory(engine.joints, home))
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
        rows.append((label, float(np.percentile(took, 50)), float(np.percentile(took, 99))))
    return rows


def gil_release(engine: Engine) -> dict[str, int]:
    from drivers.mujoco.probe import gil_release as measure  # MuJoCo stays in its room

    twin = engine.hardware[0].component
    return measure(twin.model, twin.data)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("config", nargs="?", default="configs/arm6_twin.yaml")
    parser.add_argument("--rate", type=float, default=1000.0)
    parser.add_argument("--cycles", type=int, default=3000)
    args = parser.parse_args()
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
    return 0


if __name__ == "__main__":
    sys.exit(main())
