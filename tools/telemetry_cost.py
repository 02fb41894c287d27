#!/usr/bin/env python3
"""Measure what rerun telemetry costs the cycle: cycle duration p50/p99 with telemetry off and on.

    python tools/telemetry_cost.py configs/arm6_twin.yaml --rates 500 1000 --seconds 10

For each clock (lockstep = sim clock as fast as possible; wall = real time) and rate, the engine runs on the real
cycle thread (hild.cycle.pacing.CycleThread) with the daemon's real-time settings, without telemetry and with a file
sink in a temporary directory (the recorder process, and ``Telemetry.run`` watching it on an asyncio loop on the main
thread, the way the daemon does). ``--repeat N`` runs N off/on pairs, interleaved (off, on, off, on, …) so a drift
of the machine hits both alike, and reports each run and the mean of each pair of sides. The tap is called where the
daemon's engine calls it (``Engine.step``, right after the hardware writes) and its own cost is timed separately.
Engine, cycle thread and window come from the measuring room (``hild.bench.measure``). Reports cycle duration
(wake-up → writes done) p50/p99 (µs), the p99 rise, overruns per 10k cycles (they count the whole step, tap
included), the tap's p50/p99, the recorder's flush mean/max (ms, in its own process) and the recording's size
(kB/s).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from hild.bench.measure import cycle_running, measure_window, start_engine
from hild.bench.report import rise_pct
from hild.config import load_config
from hild.config.model import TelemetrySection
from hild.crossing.stats import percentiles
from hild.telemetry import Telemetry

WARMUP_S = 1.0  # s, not counted


class TimedTap:
    """Stands in for the engine's tap wherever ``Engine.step`` calls it, timing each real ``record``."""

    def __init__(self, tap: Any, tap_ns: np.ndarray) -> None:
        self.tap, self.tap_ns, self.calls = tap, tap_ns, 0

    def record(self, *args: Any) -> None:
        t0 = time.perf_counter_ns()
        self.tap.record(*args)
        self.tap_ns[self.calls % len(self.tap_ns)] = time.perf_counter_ns() - t0
        self.calls += 1

    def restart(self) -> None:
        self.calls = 0


async def _measure(
    config: str, clock: str, rate: float, seconds: float, with_telemetry: bool, flush_period: float = 0.1
) -> dict[str, Any]:
    loaded = load_config(config)
    cfg = loaded.config
    tmp = tempfile.TemporaryDirectory()
    section = TelemetrySection(
        enabled=with_telemetry,
        flush_period=flush_period,
        sinks=[{"kind": "file", "path": str(Path(tmp.name) / "cost.rrd")}] if with_telemetry else [],  # type: ignore[list-item]
    )
    loaded.config = cfg.model_copy(update={"update_rate": rate, "telemetry": section})
    engine = start_engine(loaded)
    telemetry = Telemetry.from_config(loaded, engine.stats)
    tap_ns = np.zeros(200_000, dtype=np.int64)
    timed = TimedTap(telemetry.tap, tap_ns) if telemetry else None
    engine.tap = timed  # where the daemon puts it: Engine.step calls it after the hardware writes
    watcher = asyncio.create_task(telemetry.run()) if telemetry else None
    with cycle_running(engine, cfg.realtime, clock, 0.0 if clock == "sim" else 1.0):
        window = await asyncio.to_thread(
            measure_window, engine, warmup=WARMUP_S, seconds=seconds, also_restart=timed.restart if timed else None
        )
        taps = min(timed.calls if timed else 0, len(tap_ns))
    size = 0
    if telemetry is not None:
        telemetry.close()
        assert watcher is not None
        await watcher
        size = sum(f.stat().st_size for f in telemetry.files)
    tmp.cleanup()
    figures = window.figures()
    d = figures["duration_us"]
    result: dict[str, Any] = {
        "clock": "lockstep" if clock == "sim" else "wall",
        "rate_hz": rate,
        "telemetry": with_telemetry,
        "cycles": window.cycles,
        "overruns": window.overruns,
        "ovr_per_10k": figures["overruns_per_10k"],
        "p50_us": d["p50"],
        "p99_us": d["p99"],
        "max_us": d["max"],
    }
    if telemetry is not None:
        tap = percentiles(tap_ns[:taps], "ns", digits=2)
        result["tap_p50_us"], result["tap_p99_us"] = tap["p50"], tap["p99"]
        result["flush_mean_ms"] = round(float(telemetry.info["flush_mean_ms"]), 2)
        result["flush_max_ms"] = round(float(telemetry.info["flush_max_ms"]), 2)
        result["rrd_kB_per_s"] = round(size / 1e3 / (seconds + 1.0), 1)
        result["dropped_rows"] = telemetry.tap.dropped
    return result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("config", nargs="?", default="configs/arm6_twin.yaml")
    parser.add_argument("--rates", type=float, nargs="+", default=[500.0, 1000.0])
    parser.add_argument("--clocks", nargs="+", choices=["sim", "wall"], default=["sim", "wall"])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--flush-period", type=float, default=0.1, help="telemetry flush_period (s)")
    parser.add_argument("--repeat", type=int, default=1, help="off/on pairs per clock and rate, interleaved")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    rows, means = [], []
    for clock in args.clocks:
        for rate in args.rates:
            pairs = []
            for _ in range(max(1, args.repeat)):
                off = asyncio.run(_measure(args.config, clock, rate, args.seconds, False))
                on = asyncio.run(_measure(args.config, clock, rate, args.seconds, True, args.flush_period))
                on["p99_rise_pct"] = rise_pct(on["p99_us"], off["p99_us"])
                rows += [off, on]
                pairs.append((off, on))
            mean = {
                "clock": off["clock"],
                "rate_hz": rate,
                "runs": len(pairs),
                **{
                    f"{side}_{k}": round(float(np.mean([p[i][k] for p in pairs])), 1)
                    for i, side in enumerate(("off", "on"))
                    for k in ("p50_us", "p99_us", "ovr_per_10k")
                },
            }
            mean["p99_rise_pct"] = rise_pct(mean["on_p99_us"], mean["off_p99_us"])
            means.append(mean)
    if args.json:
        print(json.dumps({"runs": rows, "means": means}, indent=2))
        return 0
    print(
        f"{'clock':>8} {'rate':>5} {'tele':>5} {'cycles':>7} {'p50':>6} {'p99':>6} {'max':>8} {'ovr/10k':>7} "
        f"{'rise%':>6} "
        f"{'tap50':>6} {'tap99':>6} {'flush ms':>9} {'max':>6} {'kB/s':>6} {'drop':>5}"
    )
    for r in rows:
        extra = (
            f"{r['p99_rise_pct']:>6} {r['tap_p50_us']:>6} {r['tap_p99_us']:>6} {r['flush_mean_ms']:>9} "
            f"{r['flush_max_ms']:>6} {r['rrd_kB_per_s']:>6} {r['dropped_rows']:>5}"
            if r["telemetry"]
            else ""
        )
        print(
            f"{r['clock']:>8} {r['rate_hz']:>5g} {'on' if r['telemetry'] else 'off':>5} {r['cycles']:>7} "
            f"{r['p50_us']:>6} {r['p99_us']:>6} {r['max_us']:>8} {r['ovr_per_10k']:>7} {extra}"
        )
    print("\nmean over the interleaved pairs")
    print(f"{'clock':>8} {'rate':>5} {'runs':>4} {'off p99':>8} {'on p99':>7} {'rise%':>6} {'ovr off':>8} {'on':>6}")
    for m in means:
        print(
            f"{m['clock']:>8} {m['rate_hz']:>5g} {m['runs']:>4} {m['off_p99_us']:>8} {m['on_p99_us']:>7} "
            f"{m['p99_rise_pct']:>6} {m['off_ovr_per_10k']:>8} {m['on_ovr_per_10k']:>6}"
        )
    print(
        "(µs unless noted; duration = wake → writes done; overruns count the whole step; tap = TelemetryTap.record)",
        file=sys.stderr,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
