"""What a recording of cycle rows holds, as rerun calls: the series' static styles and one batch of rows as columns.

Shared by the recorder process (live rows from the telemetry ring) and ``hild record view`` (an episode's rows read
back from its files), so a recorded episode opens in the viewer exactly as live telemetry does, with the same
entities (``layout``) and the same replay helpers reading it back (``replay``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np
import rerun as rr

from hild.telemetry import layout

# One colour per joint, shared by its measured (thick) and commanded (thin) series.
PALETTE = [
    (31, 119, 180),
    (255, 127, 14),
    (44, 160, 44),
    (214, 39, 40),
    (148, 103, 189),
    (140, 86, 75),
    (227, 119, 194),
    (127, 127, 127),
    (188, 189, 34),
    (23, 190, 207),
]


class Rows(Protocol):
    """The fields of a batch of cycle rows the viewer shows (``TelemetryRows`` and ``CycleRows`` both have them)."""

    tick: np.ndarray
    t: np.ndarray
    period: np.ndarray
    duration: np.ndarray
    measured_position: np.ndarray
    measured_velocity: np.ndarray
    measured_effort: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray
    mode: np.ndarray


def log_series_styles(rec: rr.RecordingStream, joints: Sequence[str]) -> None:
    """The series' names and colours, static: once per recording stream."""
    joints = list(joints)
    colors = [PALETTE[i % len(PALETTE)] for i in range(len(joints))]
    for q in layout.QUANTITIES:
        rec.log(
            layout.joint_path(q, layout.MEASURED),
            rr.SeriesLines(names=joints, colors=colors, widths=[2.0] * len(joints)),
            static=True,
        )
        rec.log(
            layout.joint_path(q, layout.COMMANDED),
            rr.SeriesLines(names=[f"{j} cmd" for j in joints], colors=colors, widths=[1.0] * len(joints)),
            static=True,
        )
    rec.log(layout.TRACKING_ERROR, rr.SeriesLines(names=joints, colors=colors), static=True)
    rec.log(layout.MODE, rr.SeriesLines(names=joints, colors=colors), static=True)
    rec.log(layout.LOOP_PERIOD, rr.SeriesLines(names=["period"]), static=True)
    rec.log(layout.LOOP_DURATION, rr.SeriesLines(names=["duration (previous cycle)"]), static=True)


def time_index(tick: np.ndarray, t: np.ndarray) -> list[rr.TimeColumn]:
    return [rr.TimeColumn(layout.TICK, sequence=tick), rr.TimeColumn(layout.CYCLE_TIME, duration=t)]


def row_columns(rows: Rows) -> list[tuple[str, Any]]:
    """``(entity, Scalars columns)`` for every per-cycle entity, one call's worth each."""
    out: list[tuple[str, Any]] = []
    measured = (rows.measured_position, rows.measured_velocity, rows.measured_effort)
    commanded = (rows.position, rows.velocity, rows.effort)
    for q, meas, cmd in zip(layout.QUANTITIES, measured, commanded, strict=True):
        out.append((layout.joint_path(q, layout.MEASURED), rr.Scalars.columns(scalars=meas)))
        out.append((layout.joint_path(q, layout.COMMANDED), rr.Scalars.columns(scalars=cmd)))
    out.append((layout.TRACKING_ERROR, rr.Scalars.columns(scalars=rows.position - rows.measured_position)))
    out.append((layout.MODE, rr.Scalars.columns(scalars=rows.mode.astype(float))))
    out.append((layout.LOOP_PERIOD, rr.Scalars.columns(scalars=rows.period * 1e6)))
    out.append((layout.LOOP_DURATION, rr.Scalars.columns(scalars=rows.duration * 1e6)))
    return out
