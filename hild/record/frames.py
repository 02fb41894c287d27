"""Frames from cycles: which cycle a reader sampling at a fixed rate would have seen (docs/recording.md).

Frame ``k`` is at ``t0 + k/fps`` on the cycle clock (``t0``: the first cycle), for ``k = 0 … ⌊duration·fps⌋``
(one fewer if that time lands after the last cycle), and holds the last cycle at or before its time: a
zero-order hold. The LeRobot export, the viewer's 3D poses and replay's waypoints all pick cycles this way.
"""

from __future__ import annotations

import math

import numpy as np

from hild.record.model import RecordError

TIME_SLACK = 1e-9  # s: a cycle this close after a frame's time counts as at it (float rounding of t0 + k/fps)


def frame_rows(t: np.ndarray, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """``(offsets, rows)``: frame ``k``'s time after the first cycle (``k/fps``) and the index of the cycle it
    holds, the last one at or before ``t[0] + k/fps``. ``t`` is the cycle clock, non-decreasing."""
    if len(t) == 0:
        raise RecordError("the episode has no cycles")
    if np.any(np.diff(t) < 0.0):
        raise RecordError("the episode's cycle clock goes backwards: cannot resample it")
    t0, duration = float(t[0]), float(t[-1] - t[0])
    last = math.floor((duration + TIME_SLACK) * fps)
    if t0 + last / fps > t[-1] + TIME_SLACK:  # ⌊duration·fps⌋ rounded up past the last cycle
        last -= 1
    offsets = np.arange(last + 1, dtype=np.float64) / fps
    rows = np.searchsorted(t, t0 + offsets + TIME_SLACK, side="right") - 1
    return offsets, rows.astype(np.int64)
