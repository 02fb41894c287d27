#!/usr/bin/env python3
"""What writing an episode costs the recorder process: rows and messages a second, ending a chunk with and
without fsync, reading back, bytes on disk (docs/recording.md, "Files").

    python tools/record_cost.py                         # 6 joints, 30 000 rows (30 s at 1 kHz), 100-row chunks
    python tools/record_cost.py --joints 7 --rows 60000 --chunk 50 --dir /mnt/sd

Rows are a smooth trajectory with sensor noise, two controllers, a few events; every chunk is ``write_rows`` of
the chunk's rows then ``end_chunk``, timed separately (wall clock, one process, the machine as it is).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from hild.crossing.cyclelog import CycleRows
from hild.record.mcap_files import EpisodeWriter, read_episode
from hild.record.model import EpisodeMeta, RecordedEvent


def trajectory(count: int, joints: int, rate: float) -> CycleRows:
    rng = np.random.default_rng(0)
    tick = np.arange(count, dtype=np.int64)
    t = tick / rate
    phase = np.arange(joints) * 0.7
    position = 0.5 * np.sin(0.8 * t[:, None] + phase)
    velocity = 0.4 * np.cos(0.8 * t[:, None] + phase)
    owner = np.ones((count, joints), np.int16)
    owner[:, -1] = 2
    return CycleRows(
        tick=tick,
        t=t,
        wall=1.767e9 + t + rng.normal(0, 5e-6, count),
        period=np.full(count, 1 / rate) + rng.normal(0, 2e-6, count),
        duration=rng.uniform(2e-5, 1e-4, count),
        measured_position=position + rng.normal(0, 1e-4, (count, joints)),
        measured_velocity=velocity + rng.normal(0, 1e-3, (count, joints)),
        measured_effort=rng.normal(0, 0.5, (count, joints)),
        fresh=np.ones((count, joints), bool),
        fault=np.zeros((count, joints), np.int16),
        position=position,
        velocity=velocity,
        effort=np.zeros((count, joints)),
        kp=np.full((count, joints), 80.0),
        kd=np.full((count, joints), 4.0),
        mode=np.ones((count, joints), np.int8),
        owner=owner,
        tau_ext=np.full((count, joints), np.nan),
        source=np.ones((count, joints), np.int8),
    )


def meta(joints: int, rate: float) -> EpisodeMeta:
    names = [f"joint{i + 1}" for i in range(joints)]
    return EpisodeMeta(
        id="cost", robot="bench", joints=names, state="recording", task=None, note=None, fps=30.0,
        update_rate=rate, config_path="", config_sha256="", versions={}, started_wall=1.767e9, start_tick=0,
        controller_codes={1: "arm", 2: "gripper"},
    )  # fmt: skip


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[round(q * (len(ordered) - 1))]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--joints", type=int, default=6)
    parser.add_argument("--rows", type=int, default=30_000)
    parser.add_argument("--chunk", type=int, default=100, help="rows a chunk (the chunk period × the rate)")
    parser.add_argument("--rate", type=float, default=1000.0)
    parser.add_argument("--dir", type=Path, default=None, help="where to write (default: a temporary directory)")
    args = parser.parse_args()
    rows = trajectory(args.rows, args.joints, args.rate)
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        for fsync in (False, True):
            directory = Path(tmp) / f"fsync-{fsync}"
            writer = EpisodeWriter(directory, meta(args.joints, args.rate), fsync=fsync)
            write, end = [], []
            for start in range(0, args.rows, args.chunk):
                part = rows.select(slice(start, start + args.chunk))
                began = time.perf_counter()
                writer.write_rows(part, {})
                writer.write_event(RecordedEvent(float(part.wall[0]), float(part.t[0]), "event", {"chunk": start}))
                wrote = time.perf_counter()
                writer.end_chunk()
                write.append(wrote - began)
                end.append(time.perf_counter() - wrote)
            writer.close()
            total = sum(write) + sum(end)
            print(
                f"fsync {'on ' if fsync else 'off'}: {args.rows / total:8.0f} rows/s "
                f"{writer.messages / total:9.0f} messages/s ({writer.messages / args.rows:.2f} a row); write_rows of "
                f"{args.chunk} rows median {statistics.median(write) * 1e3:.2f} ms; end_chunk median "
                f"{statistics.median(end) * 1e3:.2f} ms, p99 {percentile(end, 0.99) * 1e3:.2f} ms; "
                f"{writer.path.stat().st_size / args.rows:.0f} B a row on disk"
            )
        began = time.perf_counter()
        back = read_episode(directory)
        print(f"read back: {len(back.rows) / (time.perf_counter() - began):.0f} rows/s")


if __name__ == "__main__":
    main()
