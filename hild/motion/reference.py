"""The standard trajectory: one fixed multi-point motion that tests, the tracking benchmark and docs share.

Four points one second apart, moving every joint by up to 1 rad and back, with velocities given (cubic
interpolation), so results are comparable from run to run and between the twin and the twin behind CAN.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

# Offsets from the start pose per point (rows) for up to six joints (columns); the motion returns to the start.
OFFSETS = np.array(
    [
        [0.4, -0.3, 0.4, 0.3, -0.4, 0.5],
        [0.8, -0.5, 0.7, 0.5, -0.2, 1.0],
        [0.4, -0.2, 0.3, 0.2, 0.2, 0.5],
        [0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    ]
)
TIMES = np.array([1.0, 2.0, 3.0, 4.0])


def standard_trajectory(joint_names: Sequence[str], start: Sequence[float], scale: float = 1.0) -> dict[str, Any]:
    """The standard trajectory as a ``trajectory`` goal body for joints starting at ``start``."""
    n = len(joint_names)
    if n > OFFSETS.shape[1] or len(start) != n:
        raise ValueError(f"the standard trajectory covers 1 to {OFFSETS.shape[1]} joints with a start each")
    positions = np.asarray(start, dtype=float) + scale * OFFSETS[:, :n]
    before = np.vstack([np.asarray(start, dtype=float), positions[:-1]])
    after = np.vstack([positions[1:], positions[-1:]])
    span = np.diff(np.concatenate([[0.0], TIMES]))
    velocities = (after - before) / (span[:, None] + np.append(span[1:], span[-1])[:, None])
    velocities[-1] = 0.0
    points = [
        {"positions": p.tolist(), "velocities": v.tolist(), "time_from_start": float(t)}
        for p, v, t in zip(positions, velocities, TIMES, strict=True)
    ]
    return {"trajectory": {"joint_names": list(joint_names), "points": points}}
