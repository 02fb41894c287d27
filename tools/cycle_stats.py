#!/usr/bin/env python3
"""Measure the cycle: run a config's engine on the real cycle thread (wall clock) and print loop statistics.

    python tools/cycle_stats.py configs/arm6_twin.yaml --rates 500 1000 --seconds 10

For each rate it starts the engine (hardware, supervisor, autostart controllers), runs the cycle thread with the
same real-time settings the daemon applies, and after a warm-up reports cycle duration and period error
(p50/p99/p99.9/max, µs) and overruns per 10k cycles over the window (``hild.bench.measure``). No Zenoh session is
opened: this is the cycle alone; ``hild bench`` measures the whole daemon.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from hild.bench.measure import cycle_running, measure_window, start_engine
from hild.bench.report import format_loop_table
from hild.config import load_config

WARMUP_S = 1.0


def measure(config: str, rate: float, seconds: float, activate: list[str]) -> dict[str, Any]:
    loaded = load_config(config)
    loaded.config = loaded.config.model_copy(update={"update_rate": rate})
    engine = start_engine(loaded, activate)
    with cycle_running(engine, loaded.config.realtime):
        window = measure_window(engine, warmup=WARMUP_S, seconds=seconds)
    return {**window.figures(), "rate_hz": rate, "mode": engine.overall_mode(), "realtime": engine.realtime_report}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("config")
    parser.add_argument("--rates", type=float, nargs="+", default=[500.0, 1000.0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--activate", nargs="*", default=[], help="controllers to activate before measuring")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    results = [measure(args.config, rate, args.seconds, args.activate) for rate in args.rates]
    print(json.dumps(results, indent=2) if args.json else format_loop_table(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
