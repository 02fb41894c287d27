"""The status reply, rendered from the cycle's snapshot and its live numbers: by the client domain for a cycle in
another process, by the engine itself for one in this process (both render it the same way)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from hild.crossing.snapshot import Snapshot
from hild.crossing.stats import LoopStats

HARDWARE_STATUS_FIELDS = ("name", "driver", "state", "fault")
SENSOR_STATUS_FIELDS = ("name", "type", "frame_id", "hardware", "fault")
STATS_MAX_AGE = 0.1  # s: status polled at 200 Hz recomputes loop percentiles at most 10 times a second


def loop_status(update_rate: float, clock: str, stats: LoopStats) -> dict[str, Any]:
    """The status reply's ``loop``: the rate, the clock and the loop statistics."""
    return {"update_rate": update_rate, "clock": clock, **stats.summary(STATS_MAX_AGE)}


def render_status(
    robot: str, snapshot: Snapshot, stamp: float, longest_silence: Sequence[float], loop: dict[str, Any]
) -> dict[str, Any]:
    """``longest_silence`` in seconds per joint; ``loop`` is the update rate, clock and loop statistics."""
    joints = [
        {**joint, "longest_silence_ms": round(float(silence) * 1000.0, 1)}
        for joint, silence in zip(snapshot.joints, longest_silence, strict=True)
    ]
    return {
        "robot": robot,
        "stamp": stamp,
        "mode": snapshot.mode,
        "joints": joints,
        "controllers": [dict(c) for c in snapshot.controllers],
        "hardware": [{k: h[k] for k in HARDWARE_STATUS_FIELDS} for h in snapshot.hardware],
        "loop": loop,
        "realtime": dict(snapshot.realtime),
        "sensors": [{k: s[k] for k in SENSOR_STATUS_FIELDS} for s in snapshot.sensors],
        "walls": snapshot.walls,
        "homing": [dict(h) for h in snapshot.homing],
    }
