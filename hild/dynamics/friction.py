"""The joint friction model hild compensates and subtracts: viscous + Coulomb (smoothed) + a constant offset.

One function for teach mode, the contact observer and ``hild identify``'s fit, so the torque identified is the
torque compensated. Plain arithmetic on arrays the caller owns: it runs on the cycle and allocates nothing.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True, slots=True)
class FrictionArrays:
    """Per joint, in the robot's order (zeros where the config gives no ``friction``)."""

    viscous: np.ndarray
    coulomb: np.ndarray
    offset: np.ndarray
    band: np.ndarray

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
        were gone. No temporaries: ``out`` must not be ``velocity``."""
        np.divide(velocity, self.band, out=out)
        np.tanh(out, out=out)
        np.multiply(out, self.coulomb, out=out)
        for i, v in enumerate(velocity.tolist()):  # viscous in place: 6–14 joints, no temporary array
            out[i] += self.viscous[i] * v
        np.add(out, self.offset, out=out)
        return out
