"""Dense sampling of segments and trajectories, shared by the motion tests."""

from __future__ import annotations

import numpy as np

from hild.motion.limits import KinematicLimits
from hild.motion.segments import Segment
from hild.motion.trajectory import Trajectory


def sample_segment(segment: Segment, joints: int, steps: int = 2000) -> tuple[np.ndarray, ...]:
    """Times (steps+1,) and p, v, a (steps+1, J) at evenly spaced times over the whole segment."""
    times = np.linspace(0.0, segment.duration, steps + 1)
    p, v, a = (np.empty((len(times), joints)) for _ in range(3))
    for i, t in enumerate(times):
        segment.sample(float(t), p[i], v[i], a[i])
    return times, p, v, a


def state_at(sampler: Segment | Trajectory, t: float, joints: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    p, v, a = np.empty(joints), np.empty(joints), np.empty(joints)
    sampler.sample(t, p, v, a)
    return p, v, a


def assert_within_limits(segment: Segment, limits: KinematicLimits, steps: int = 2000) -> None:
    """|v|, |a| and the finite-difference jerk of a densely sampled segment stay within the limits."""
    times, _, v, a = sample_segment(segment, limits.joints, steps)
    slack = 1.0 + 1e-6
    assert np.all(np.abs(v) <= limits.velocity * slack + 1e-12), f"velocity peak {np.abs(v).max(axis=0)}"
    assert np.all(np.abs(a) <= limits.acceleration * slack + 1e-12), f"acceleration peak {np.abs(a).max(axis=0)}"
    if segment.duration > 1e-12:  # a (subnormal) blip has no room for a meaningful difference
        dt = np.diff(times)[:, None]
        jerk = np.abs(np.diff(a, axis=0)) / dt
        rounding = 1e-14 * limits.acceleration / dt  # acceleration rounding, amplified by the division
        assert np.all(jerk <= limits.jerk * slack + rounding), f"jerk peak {jerk.max(axis=0)}"
