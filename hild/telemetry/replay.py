"""Read a hild recording back as numpy: the replay side of telemetry (compare commanded and measured motion).

Uses rerun's chunk reader (``rerun.chunk.RrdReader``), which needs nothing beyond rerun-sdk and pyarrow. Rotated
files of one run can be read one after another and concatenated.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rerun.chunk import RrdReader

from hild.telemetry import layout

_SCALARS = "Scalars:scalars"
_NAMES = "SeriesLines:names"


@dataclass(frozen=True)
class Series:
    """One scalar entity over time, sorted by tick: ``values`` is rows × series (one series per joint)."""

    tick: np.ndarray
    t: np.ndarray  # cycle_time, s
    values: np.ndarray
    names: tuple[str, ...]  # series names (joint names for per-joint entities), from the static SeriesLines

    def column(self, joint: str) -> np.ndarray:
        """One joint's values (commanded series are named ``<joint> cmd`` in the viewer's legend)."""
        names = [n.removesuffix(" cmd") for n in self.names]
        return self.values[:, names.index(joint)]


def load_scalars(path: str | Path, entity: str) -> Series:
    """Every ``Scalars`` row logged to ``entity`` (e.g. ``joints/position/measured``) in one .rrd file."""
    want = "/" + entity.strip("/")
    ticks: list[np.ndarray] = []
    times: list[np.ndarray] = []
    values: list[np.ndarray] = []
    names: tuple[str, ...] = ()
    for chunk in RrdReader(path).stream().to_chunks():
        if chunk.entity_path != want:
            continue
        batch = chunk.to_record_batch()
        if chunk.is_static:
            if _NAMES in batch.schema.names:
                names = tuple(batch.column(_NAMES).to_pylist()[-1] or ())
            continue
        if _SCALARS not in batch.schema.names:
            continue
        ticks.append(batch.column(layout.TICK).to_numpy())
        times.append(batch.column(layout.CYCLE_TIME).cast("int64").to_numpy() * 1e-9)
        values.append(np.array(batch.column(_SCALARS).to_pylist(), dtype=float).reshape(batch.num_rows, -1))
    if not ticks:
        return Series(np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros((0, len(names))), names)
    tick, t, v = np.concatenate(ticks), np.concatenate(times), np.concatenate(values)
    order = np.argsort(tick, kind="stable")
    return Series(tick[order], t[order], v[order], names)


def entity_row_counts(path: str | Path) -> dict[str, int]:
    """Rows per entity path (temporal data only; static rows are not counted)."""
    counts: dict[str, int] = {}
    for chunk in RrdReader(path).stream().to_chunks():
        if not chunk.is_static:
            counts[chunk.entity_path] = counts.get(chunk.entity_path, 0) + chunk.num_rows
    return counts


def tracking(path: str | Path, quantity: str = "position") -> tuple[Series, Series]:
    """``(commanded, measured)`` of every joint for one quantity; ``series.column("elbow")`` picks a joint."""
    return (
        load_scalars(path, layout.joint_path(quantity, layout.COMMANDED)),
        load_scalars(path, layout.joint_path(quantity, layout.MEASURED)),
    )
