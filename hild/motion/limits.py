"""Per-joint kinematic limits that every planned motion must respect."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def _positive_vector(name: str, values: np.ndarray, joints: int | None) -> np.ndarray:
    arr = np.array(values, dtype=np.float64)  # a private copy, so the caller cannot change it under us
    if arr.ndim != 1 or (joints is not None and arr.shape[0] != joints):
        expected = "a 1-D array" if joints is None else f"shape ({joints},)"
        raise ValueError(f"{name} limits: expected {expected}, found shape {arr.shape}")
    bad = np.flatnonzero(~np.isfinite(arr) | (arr <= 0.0))
    if bad.size:
        raise ValueError(f"{name} limits must be finite and > 0; joints {bad.tolist()} have {arr[bad].tolist()}")
    arr.flags.writeable = False
    return arr


def _check_scale(name: str, scale: float) -> float:
    if not (0.0 < scale <= 1.0):
        raise ValueError(f"{name} must be in (0, 1]; found {scale}")
    return float(scale)


@dataclass(frozen=True, eq=False)
class KinematicLimits:
    """Maximum |velocity|, |acceleration| and |jerk| per joint, shape (J,), all finite and > 0.

    The arrays are read-only copies, so one instance can be shared between a goal and the cycle thread.
    """

    velocity: np.ndarray
    acceleration: np.ndarray
    jerk: np.ndarray

    def __post_init__(self) -> None:
        velocity = _positive_vector("velocity", self.velocity, None)
        object.__setattr__(self, "velocity", velocity)
        object.__setattr__(self, "acceleration", _positive_vector("acceleration", self.acceleration, len(velocity)))
        object.__setattr__(self, "jerk", _positive_vector("jerk", self.jerk, len(velocity)))

    @property
    def joints(self) -> int:
        return len(self.velocity)

    def scaled(self, velocity_scale: float, acceleration_scale: float) -> KinematicLimits:
        """Slower limits for a goal's scaling factors in (0, 1]; jerk scales with acceleration.

        Scaling jerk along with acceleration keeps the time to reach full acceleration unchanged, so a slowed
        motion has the same shape, only gentler.
        """
        vs = _check_scale("velocity_scale", velocity_scale)
        acs = _check_scale("acceleration_scale", acceleration_scale)
        return KinematicLimits(self.velocity * vs, self.acceleration * acs, self.jerk * acs)

    def subset(self, index: np.ndarray) -> KinematicLimits:
        """The limits of the joints ``index`` (e.g. one controller's joints out of the robot's)."""
        idx = np.asarray(index, dtype=np.intp)
        return KinematicLimits(self.velocity[idx], self.acceleration[idx], self.jerk[idx])
