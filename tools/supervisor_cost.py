"""What the safety layer costs per cycle: the supervisor's check (plausibility gate included) and command, and a
whole lockstep engine step, on the arm6 twin (6 joints, gravity feed-forward).

    python tools/supervisor_cost.py            # best of 5 runs; µs per call

Run it on two checkouts to compare (PYTHONPATH=<checkout>); the numbers are this machine's, best of several runs
so that scheduling noise drops out.
"""

from __future__ import annotations

import inspect
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from hild.engine import Engine
from tests.faults.rigs import twin_config


def best(fn: object, calls: int, runs: int = 5) -> float:
    """Microseconds per call, best of ``runs``."""
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        for _ in range(calls):
            fn()  # type: ignore[operator]
        times.append((time.perf_counter() - start) / calls * 1e6)
    return min(times)


def main() -> None:
    engine = Engine(twin_config("arm6_twin.yaml"))
    engine.start()
    engine.run_cycles(500)
    sup, state, command, final = engine.supervisor, engine.state, engine.command, engine.final
    with_dt = len(inspect.signature(sup.check).parameters) == 2  # before [trust], check took the state only

    def check_and_command() -> None:
        if with_dt:
            sup.check(state, engine.period)
        else:
            sup.check(state)  # type: ignore[call-arg]
        sup.command(engine.period, state, command, final)

    step = best(lambda: engine.run_cycles(1), 4000)
    supervise = best(check_and_command, 20000)
    print(f"engine step {step:.1f} µs, supervisor check + command {supervise:.1f} µs (arm6 twin, 6 joints)")


if __name__ == "__main__":
    main()
