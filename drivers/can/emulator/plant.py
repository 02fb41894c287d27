"""What the emulated drives push against: a plant maps joint torques to joint motion.

`MotorPlant` is the cheap default — independent rigid joints with inertia, viscous damping and a gravity-like
load — so an emulator runs without MuJoCo. Anything with the same three members (e.g. an adapter around the
twin) can stand in for it.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import numpy as np


class Plant(Protocol):
    positions: np.ndarray
    """rad, one per motor, updated in place by `step`."""
    velocities: np.ndarray
    """rad/s"""

    def step(self, torques: np.ndarray, dt: float) -> None: ...


def _per_joint(value: float | Sequence[float], n: int, name: str) -> np.ndarray:
    array = np.array(np.broadcast_to(np.asarray(value, dtype=float), (n,)))
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} must be finite")
    return array


class MotorPlant:
    """n independent joints: J·q̈ = τ − b·q̇ − g·sin(q + φ) + c.

    `gravity` is the m·g·l amplitude (Nm; 0 for a horizontal or balanced joint), `gravity_phase` φ shifts where
    the load peaks, `constant_load` c is a steady external torque. Semi-implicit Euler with the damping term
    implicit, so heavy damping stays stable at coarse steps.
    """

    def __init__(
        self,
        n: int,
        *,
        inertia: float | Sequence[float] = 0.01,
        damping: float | Sequence[float] = 0.0,
        gravity: float | Sequence[float] = 0.0,
        gravity_phase: float | Sequence[float] = 0.0,
        constant_load: float | Sequence[float] = 0.0,
        positions: float | Sequence[float] = 0.0,
        velocities: float | Sequence[float] = 0.0,
    ) -> None:
        self.inertia = _per_joint(inertia, n, "inertia")
        if np.any(self.inertia <= 0.0):
            raise ValueError("inertia must be positive")
        self.damping = _per_joint(damping, n, "damping")
        if np.any(self.damping < 0.0):
            raise ValueError("damping must not be negative")
        self.gravity = _per_joint(gravity, n, "gravity")
        self.gravity_phase = _per_joint(gravity_phase, n, "gravity_phase")
        self.constant_load = _per_joint(constant_load, n, "constant_load")
        self.positions = _per_joint(positions, n, "positions")
        self.velocities = _per_joint(velocities, n, "velocities")
        self._scratch = np.zeros(n)

    def load(self) -> np.ndarray:
        """External torque on each joint at the current position (Nm)."""
        np.add(self.positions, self.gravity_phase, out=self._scratch)
        np.sin(self._scratch, out=self._scratch)
        self._scratch *= -self.gravity
        self._scratch += self.constant_load
        return self._scratch

    def step(self, torques: np.ndarray, dt: float) -> None:
        acceleration = self.load()
        acceleration += torques
        acceleration /= self.inertia
        self.velocities += dt * acceleration
        self.velocities /= 1.0 + dt * self.damping / self.inertia
        self.positions += dt * self.velocities
