"""Synthetic episodes for the record room's offline tests: ``Episode`` objects built straight from ``CycleRows`` and
``EpisodeMeta`` (no MCAP file: reading and writing those is tested beside hild/record/mcap_files.py)."""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path

import numpy as np

from hild.crossing.cyclelog import CycleRows
from hild.record.model import Episode, EpisodeMeta, RecordedEvent

JOINTS = ("j1", "j2", "j3")


def cycle_rows(
    n: int, rate: float = 1000.0, t0: float = 12.5, wall0: float = 1.7e9, joints: int = 3, tick0: int = 1000, seed=0
) -> CycleRows:
    """``n`` cycles at ``rate``; every value tells the row it came from (position = row · 1e-3 + joint · 10,
    command = position + 0.5), so a test knows which cycle a frame holds."""
    rng = np.random.default_rng(seed)
    k = np.arange(n)
    rows = CycleRows.empty(joints)
    values = {f.name: getattr(rows, f.name) for f in fields(CycleRows)}
    per_joint = np.arange(joints) * 10.0
    out = {
        "tick": (tick0 + k).astype(np.int64),
        "t": t0 + k / rate,
        "wall": wall0 + k / rate,
        "period": np.full(n, 1.0 / rate),
        "duration": np.full(n, 1e-4),
        "measured_position": k[:, None] * 1e-3 + per_joint,
        "measured_velocity": rng.normal(size=(n, joints)),
        "measured_effort": rng.normal(size=(n, joints)),
        "fresh": np.ones((n, joints), dtype=bool),
        "fault": np.zeros((n, joints), dtype=np.int16),
        "position": k[:, None] * 1e-3 + per_joint + 0.5,
        "velocity": rng.normal(size=(n, joints)),
        "effort": rng.normal(size=(n, joints)),
        "kp": np.full((n, joints), 100.0),
        "kd": np.full((n, joints), 5.0),
        "mode": np.ones((n, joints), dtype=np.int8),
        "owner": np.ones((n, joints), dtype=np.int16),
        "tau_ext": np.full((n, joints), np.nan),
        "source": np.full((n, joints), 1, dtype=np.int8),
    }
    return CycleRows(**{name: out[name].astype(values[name].dtype) for name in out})


def episode(
    episode_id: str = "20250101-120000-arm",
    n: int = 2000,
    *,
    rate: float = 1000.0,
    fps: float = 30.0,
    task: str | None = "pick the cube",
    rows: CycleRows | None = None,
    events: list[RecordedEvent] | None = None,
    directory: Path | None = None,
    state: str = "complete",
    joints: tuple[str, ...] = JOINTS,
) -> Episode:
    rows = rows if rows is not None else cycle_rows(n, rate, joints=len(joints))
    meta = EpisodeMeta(
        id=episode_id,
        robot="arm",
        joints=list(joints),
        state=state,
        task=task,
        note=None,
        fps=fps,
        update_rate=rate,
        config_path="/nonexistent/arm.yaml",
        config_sha256="0" * 64,
        versions={"hild": "0.1.0"},
        started_wall=float(rows.wall[0]) if len(rows) else 0.0,
        start_tick=int(rows.tick[0]) if len(rows) else 0,
        stopped_wall=float(rows.wall[-1]) if len(rows) else None,
        stop_tick=int(rows.tick[-1]) if len(rows) else None,
        cycles=len(rows),
    )
    return Episode(directory or Path("/nonexistent") / episode_id, meta, rows, events or [])
