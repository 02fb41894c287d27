#!/usr/bin/env python3
"""Measure the cycle: run a config's engine on the real cycle thread (wall clock) and print loop statistics.

    python tools/cycle_stats.py configs/arm6_twin.yaml --rates 500 1000 --seconds 10

For each rate it starts the engine (hardware, supervisor, autostart controllers), runs the cycle thread for the
given time with the same real-time settings the daemon applies, and reports cycle duration and period error
(p50/p99/p99.9/max, µs) and overruns per 10k cycles. No Zenoh session is opened: this is the cycle alone.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from hild.config import load_config
from hild.cycle import CycleThread
from hild.engine import Engine
from hild.realtime import apply_process_settings, freeze_heap


def measure(config: str, rate: float, seconds: float, activate: list[str]) -> dict[str, object]:
    loaded = load_config(config)
    loaded.config = loaded.config.model_copy(update={"update_rate": rate})
    cfg = loaded.config
    engine = Engine(loaded)
    apply_process_settings(cfg.realtime)
    engine.start()
    if activate:
        result = engine.switch(activate, [])
        if not result.ok:
            raise SystemExit(f"cannot activate {activate}: {result.error}")
    freeze_heap(cfg.realtime)
    cycle = CycleThread(engine, "wall", 1.0, cfg.realtime)
    cycle.start()
    time.sleep(1.0)  # warm-up, not counted
    engine.stats.reset()
    time.sleep(seconds)
    summary = engine.stats.summary()
    cycle.stop()
    cycle.join()
    cycles = max(1, int(summary["cycles"]))
    summary["overruns_per_10k"] = round(int(summary["overruns"]) * 10_000 / cycles, 2)
    summary["rate_hz"] = rate
    summary["mode"] = engine.overall_mode()
    summary["realtime"] = engine.realtime_report
    return summary


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("config")
    parser.add_argument("--rates", type=float, nargs="+", default=[500.0, 1000.0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--activate", nargs="*", default=[], help="controllers to activate before measuring")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    results = [measure(args.config, rate, args.seconds, args.activate) for rate in args.rates]
    if args.json:
        print(json.dumps(results, indent=2))
        return 0
    print(
        f"{'rate':>6} {'cycles':>7} {'dur p50':>8} {'p99':>7} {'p99.9':>7} {'max':>8} "
        f"{'perr p50':>8} {'p99':>7} {'p99.9':>7} {'max':>8} {'ovr/10k':>8}"
    )
    for r in results:
        d, p = r["duration_us"], r["period_error_us"]
        print(
            f"{r['rate_hz']:>6g} {r['cycles']:>7} {d['p50']:>8} {d['p99']:>7} {d['p999']:>7} {d['max']:>8} "
            f"{p['p50']:>8} {p['p99']:>7} {p['p999']:>7} {p['max']:>8} {r['overruns_per_10k']:>8}"
        )
    print("(µs; duration = wake → write done; period error = |Δwake − T|)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
