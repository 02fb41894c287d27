"""Fitting a joint's friction from steady-speed samples: ``τ = viscous·v + coulomb·tanh(v / band) + offset``, the model
of :mod:`hild.dynamics.friction`, so what ``hild identify`` writes is what teach mode compensates.

``τ`` is the torque the drive gave minus the model's gravity at the sample's pose: at a steady speed of one joint
alone nothing else is left (no acceleration; a single joint's own speed gives it no Coriolis torque). Linear least
squares in (viscous, coulomb, offset) for a fixed ``band``; viscous and Coulomb are friction, never negative, so a
negative one is pinned at 0 and the rest fitted again.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

SPEED_SPREAD = 1.5  # the fastest sample at least this many times the slowest: viscous and Coulomb apart


@dataclass(frozen=True)
class FrictionFit:
    viscous: float  # N·m·s/rad
    coulomb: float  # N·m
    offset: float  # N·m
    band: float  # rad/s, as given
    samples: int
    rms: float  # N·m: residual
    r2: float  # share of the torque's variance the model explains (1: all)
    speeds: tuple[float, float]  # slowest and fastest |v| sampled (rad/s)

    def as_config(self) -> dict[str, float]:
        """``joints.<j>.friction`` as the config takes it (rounded to what a drive resolves)."""
        return {
            "viscous": round(self.viscous, 4),
            "coulomb": round(self.coulomb, 4),
            "offset": round(self.offset, 4),
            "band": self.band,
        }


def fit_friction(velocity: np.ndarray, torque: np.ndarray, band: float = 0.02) -> FrictionFit:
    """The friction model that best explains ``torque`` at ``velocity`` (samples at steady speeds, both ways).

    Raises ValueError when the samples cannot tell the terms apart: fewer than 3 of them, speeds in one direction
    only (Coulomb and offset are then the same column), or at one speed (viscous and Coulomb the same)."""
    v = np.asarray(velocity, dtype=float)
    tau = np.asarray(torque, dtype=float)
    keep = np.isfinite(v) & np.isfinite(tau)
    v, tau = v[keep], tau[keep]
    if v.size < 3:
        raise ValueError(f"{v.size} samples at a steady speed: at least 3 are needed")
    if not ((v > 0).any() and (v < 0).any()):
        raise ValueError("samples in one direction only: Coulomb friction and an offset cannot be told apart")
    speeds = np.abs(v)
    if speeds.max() < SPEED_SPREAD * speeds.min():
        raise ValueError(
            f"speeds {speeds.min():.3g}–{speeds.max():.3g} only: at one speed viscous and Coulomb friction cannot be "
            "told apart; sweep at two speeds or more"
        )
    columns = np.column_stack([v, np.tanh(v / band), np.ones_like(v)])
    free = [0, 1, 2]
    coef = np.zeros(3)
    for _ in range(3):  # pin a negative friction term at 0 and refit the others
        solution, *_ = np.linalg.lstsq(columns[:, free], tau, rcond=None)
        coef[:] = 0.0
        coef[free] = solution
        negative = [k for k in (0, 1) if k in free and coef[k] < 0.0]
        if not negative:
            break
        free = [k for k in free if k not in negative]
        coef[negative] = 0.0
    residual = tau - columns @ coef
    spread = float(np.sum((tau - tau.mean()) ** 2))
    r2 = 1.0 - float(np.sum(residual**2)) / spread if spread > 0.0 else 1.0
    return FrictionFit(
        viscous=float(coef[0]),
        coulomb=float(coef[1]),
        offset=float(coef[2]),
        band=band,
        samples=int(v.size),
        rms=math.sqrt(float(np.mean(residual**2))),
        r2=r2,
        speeds=(float(speeds.min()), float(speeds.max())),
    )
