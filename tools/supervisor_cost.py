"""What the safety layer costs per cycle: the supervisor's check (plausibility gate included) and command, and a
whole lockstep engine step, on the arm6 twin (6 joints, gravity feed-forward).

    python tools/supervisor_cost.py            # best of 5 runs; µs per call

The numbers are this machine's, best of several runs so that scheduling noise drops out; compare two checkouts on
the same machine (PYTHONPATH=<checkout>).
"""

from __future__ import annotations

import time
from collections.abc import Callable

from hild.bench.daemon import CONFIGS
from hild.bench.measure import lockstep_engine


def best(fn: Callable[[], object], calls: int, runs: int = 5) -> float:
    """Microseconds per call, best of ``runs``."""
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        for _ in range(calls):
            fn()
        times.append((time.perf_counter() - start) / calls * 1e6)
    return min(times)


def main() -> None:
    engine = lockstep_engine(CONFIGS / "arm6_twin.yaml")
    try:
        engine.run_cycles(500)
        sup, state, command, final = engine.supervisor, engine.state, engine.command, engine.final

        def check_and_command() -> None:
            sup.check(state, engine.period)
            sup.command(engine.period, state, command, final)

        step = best(lambda: engine.run_cycles(1), 4000)
        supervise = best(check_and_command, 20000)
    finally:
        engine.stop()
    print(f"engine step {step:.1f} µs, supervisor check + command {supervise:.1f} µs (arm6 twin, 6 joints)")


if __name__ == "__main__":
    main()
