#!/usr/bin/env python3
"""What the recorder process and its handle cost, end to end (docs/recording.md, "Episodes and the recorder process"):
starting the process, each chunk in the live recorder (take from the cycle log, write, flush, the free-space check),
a stop (the last rows, close, metadata), a black box, and ``Recorder.log`` on the loop.

    python tools/recorder_figures.py                      # 6 mock joints at 1 kHz, a 10 s episode, fsync on
    python tools/recorder_figures.py --seconds 30 --no-fsync --dir /mnt/sd

The cycle is a lockstep engine stepped here in batches of one chunk period's cycles, at the real-time average rate
(the recorder sees what a 1 kHz cycle writes); figures are wall-clock, on the machine as it is.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from hild.config import load_config
from hild.crossing.events import Event
from hild.daemon.local import LocalCycle
from hild.record.events import cycle_event
from hild.record.model import EPISODE_JSON
from hild.record.recorder import Recorder

JOINT = {"limits": {"position": {"lower": -1, "upper": 1}, "velocity": 2, "effort": 50}, "hold": {"kp": 100, "kd": 5}}


def config(directory: Path, joints: int, rate: int, fsync: bool) -> Path:
    names = [f"j{i}" for i in range(joints)]
    data = {
        "robot": {"name": "figures"},
        "update_rate": rate,
        "clock": {"source": "sim", "real_time_factor": 0},
        "hardware": {"bus": {"driver": "mock", "joints": {n: {} for n in names}}},
        "joints": {n: JOINT for n in names},
        "controllers": {"jsb": {"type": "joint_state_broadcaster", "autostart": True}},
        "recording": {"dir": str(directory / "recordings"), "fsync": fsync, "min_free_mb": 0},
    }
    path = directory / "robot.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


async def measure(link: LocalCycle, seconds: float) -> dict[str, float]:
    recorder = Recorder.from_config(link.loaded, link)
    assert recorder is not None
    begin = time.perf_counter()
    await recorder.open()
    figures = {"open_s": time.perf_counter() - begin}
    period = recorder.setup.chunk_period
    batch = round(period * recorder.setup.update_rate)
    link.engine.run_cycles(3 * batch)
    await recorder.start("figures", None, None)
    event = cycle_event(Event(link.t, "info", "engine", "x"))
    logs = []
    deadline = time.perf_counter()
    for _ in range(round(seconds / period)):
        link.engine.run_cycles(batch)
        start = time.perf_counter_ns()
        recorder.log(event)
        logs.append(time.perf_counter_ns() - start)
        deadline += period
        await asyncio.sleep(max(0.0, deadline - time.perf_counter()))
    begin = time.perf_counter()
    reply = await recorder.stop()
    figures["stop_s"] = time.perf_counter() - begin
    begin = time.perf_counter()
    box = await recorder.blackbox("figures")
    figures["blackbox_s"] = time.perf_counter() - begin
    figures["blackbox_cycles"] = box["cycles"]
    await recorder.close()
    extra = json.loads((Path(reply["directory"]) / EPISODE_JSON).read_text())["extra"]
    figures.update(
        chunks=extra["chunks"],
        chunk_ms_mean=extra["chunk_ms_mean"],
        chunk_ms_max=extra["chunk_ms_max"],
        cycles=reply["cycles"],
        dropped=reply["dropped"],
        log_us_median=statistics.median(logs) / 1e3,
        log_us_max=max(logs) / 1e3,
        mcap_mib=Path(next(f for f in reply["files"] if f.endswith(".mcap"))).stat().st_size / 2**20,
    )
    return figures


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--joints", type=int, default=6)
    parser.add_argument("--rate", type=int, default=1000)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--no-fsync", action="store_true")
    parser.add_argument("--dir", type=Path, default=None, help="where to write (default: a temporary directory)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        link = LocalCycle(load_config(config(Path(tmp), args.joints, args.rate, not args.no_fsync)))
        link.engine.start()
        try:
            figures = asyncio.run(measure(link, args.seconds))
        finally:
            link.engine.stop()
            link.close()
    print(f"{args.joints} joints at {args.rate} Hz, {args.seconds:g} s, fsync {'off' if args.no_fsync else 'on'}")
    for key, value in figures.items():
        print(f"  {key:30s} {value:.3f}" if isinstance(value, float) else f"  {key:30s} {value}")


if __name__ == "__main__":
    main()
