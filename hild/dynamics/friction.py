"""The joint friction model hild compensates and subtracts: viscous + Coulomb (smoothed) + a constant offset.

One function for teach mode, the contact observer and ``hild identify``'s fit, so the torque identified is the
torque compensated. It runs on the cycle: one pass over plain floats into an array the caller owns (short-lived
lists only, as the supervisor's loop has).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass(frozen=True, slots=True)
class FrictionArrays:
    """Per joint, in the robot's order (zeros where the config gives no ``friction``)."""

    viscous: np.ndarray
    coulomb: np.ndarray
    offset: np.ndarray
    band: np.ndarray
    # The same values as Python floats, for the per-cycle loop (set once, from the arrays above).
    _per_joint: tuple[list[float], ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        lists = (self.viscous.tolist(), self.coulomb.tolist(), self.offset.tolist(), self.band.tolist())
        object.__setattr__(self, "_per_joint", lists)

    @classmethod
    def of(cls, cfg: Any) -> FrictionArrays:
        models = [j.friction for j in cfg.joints.values()]
        return cls(
            viscous=np.array([m.viscous if m else 0.0 for m in models]),
            coulomb=np.array([m.coulomb if m else 0.0 for m in models]),
            offset=np.array([m.offset if m else 0.0 for m in models]),
            band=np.array([m.band if m else 0.02 for m in models]),
        )

    @classmethod
    def zeros(cls, n: int) -> FrictionArrays:
        return cls(np.zeros(n), np.zeros(n), np.zeros(n), np.full(n, 0.02))

    @property
    def any(self) -> bool:
        return bool(self.viscous.any() or self.coulomb.any() or self.offset.any())

    def torque(self, velocity: np.ndarray, out: np.ndarray) -> np.ndarray:
        """Write into ``out`` the torque friction takes from the motion at ``velocity`` (the sign of the motion),
        plus the offset: ``viscous·v + coulomb·tanh(v / band) + offset``. A drive adds it to move as if friction
        were gone. One pass over plain floats: for the 2–14 joints of an arm, cheaper than numpy's calls."""
        viscous, coulomb, offset, band = self._per_joint
        tanh = math.tanh
        out[:] = [viscous[i] * v + coulomb[i] * tanh(v / band[i]) + offset[i] for i, v in enumerate(velocity.tolist())]
        return out
