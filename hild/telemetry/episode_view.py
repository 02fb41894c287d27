"""``hild record view``: an episode's cycles in rerun, as live telemetry shows them (docs/recording.md).

Every cycle of the episode goes out under the entities live telemetry uses (``layout``, ``columns``): measured
and commanded position, velocity and effort, tracking error, joint modes and loop timing on the ``tick`` and
``cycle_time`` timelines, the episode's events as a text log, and, when the robot's model can be loaded, the arm
in 3D at ``pose_rate``. So ``hild.telemetry.replay`` reads a saved episode back like any telemetry file.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import rerun as rr

from hild.record.frames import frame_rows
from hild.record.model import Episode
from hild.telemetry import columns, layout
from hild.telemetry.outlets import new_stream

BATCH = 20_000  # rows per send_columns call: bounded memory however long the episode
POSE_RATE = 30.0  # Hz of the 3D arm's poses


def _scene(episode: Episode, model: Path | None):  # -> ArmScene | None; mujoco only when there is a model
    if model is None:
        return None
    from hild.dynamics.kinematics import Kinematics
    from hild.telemetry.arm3d import ArmScene

    return ArmScene(Kinematics(model, episode.meta.joints))


def send_episode(rec: rr.RecordingStream, episode: Episode, model: Path | None = None) -> None:
    """Log ``episode`` into ``rec``: static styles and layout, every cycle, the events, the arm's poses."""
    rows = episode.rows
    scene = _scene(episode, model)
    columns.log_series_styles(rec, episode.meta.joints)
    if scene is not None:
        scene.log_static(rec)
    rec.send_blueprint(layout.default_blueprint(episode.meta.joints, scene is not None))
    for start in range(0, len(rows), BATCH):
        part = rows.select(slice(start, start + BATCH))
        index = columns.time_index(part.tick, part.t)
        for path, batch in columns.row_columns(part):
            rec.send_columns(path, indexes=index, columns=batch)
    if scene is not None and len(rows):
        _, picked = frame_rows(rows.t, POSE_RATE)
        picked = np.unique(picked)
        index = columns.time_index(rows.tick[picked], rows.t[picked])
        for path, batch in scene.pose_columns(rows.measured_position[picked]):
            rec.send_columns(path, indexes=index, columns=batch)
    _send_events(rec, episode)


def _send_events(rec: rr.RecordingStream, episode: Episode) -> None:
    rows = episode.rows
    if not episode.events or not len(rows):
        return
    t = np.array([e.t if math.isfinite(e.t) else np.interp(e.wall, rows.wall, rows.t) for e in episode.events])
    tick = np.round(np.interp(t, rows.t, rows.tick.astype(np.float64))).astype(np.int64)
    text = [f"[{e.kind}] {json.dumps(e.data, sort_keys=True)}" for e in episode.events]
    level = ["WARN" if e.data.get("level") == "warning" else "INFO" for e in episode.events]
    rec.send_columns(
        layout.EVENTS, indexes=columns.time_index(tick, t), columns=rr.TextLog.columns(text=text, level=level)
    )


def _stream(episode: Episode) -> rr.RecordingStream:
    return new_stream(f"episode-{episode.meta.id}", episode.meta.id)


def save_episode(episode: Episode, path: Path, model: Path | None = None) -> Path:
    """Write the episode as an ``.rrd`` file (``rerun FILE`` opens it)."""
    rec = _stream(episode)
    rec.save(path)
    try:
        send_episode(rec, episode, model)
        rec.flush(timeout_sec=60.0)
    finally:
        rec.disconnect()
    return path


def show_episode(episode: Episode, model: Path | None = None) -> None:
    """Open the episode in a new rerun viewer (the viewer keeps running after this returns)."""
    rec = _stream(episode)
    rec.spawn(hide_welcome_screen=True)
    try:
        send_episode(rec, episode, model)
        rec.flush(timeout_sec=60.0)
    finally:
        rec.disconnect()
