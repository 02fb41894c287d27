"""What the contact bench does to an emulated arm: model mismatch, pushes on the tool and obstacles in the way.

Plain data (numpy only), so `hild emulate`'s command line and `RuntimeOptions` can carry them without MuJoCo; the
twin plant (`drivers.mujoco.plant.TwinPlant`) applies them:

* `PlantMismatch` — the plant's masses and inertias ×``mass``, its joint friction (frictionloss and damping)
  ×``friction``, each body and joint further ×U[1 − spread, 1 + spread] from ``seed``: the arm differs from the
  model hild computes gravity and the contact observer with (``robot.model``) as a real arm does.
* `Push` — a force (N, world frame) on the tool site from ``start`` for ``duration`` seconds of plant time, ramped
  up and down over ``ramp`` seconds (MuJoCo ``xfrc_applied``: a scripted hand, a collision with a soft object).
* `Obstacle` — a fixed box, sphere or cylinder in the world that the arm's links collide with; ``stiffness``
  (N/m) and ``damping`` (N·s/m) make it padded (MuJoCo's direct ``solref`` = (−stiffness, −damping), the
  obstacle's contact parameters winning by geom priority); 0 keeps MuJoCo's default, nearly rigid contact.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["Obstacle", "PlantMismatch", "Push", "parse_obstacle", "parse_push", "push_force"]

SHAPE_SIZES = {"box": 3, "sphere": 1, "cylinder": 2}


@dataclass(frozen=True)
class PlantMismatch:
    """How the plant differs from the model file: factors on masses/inertias and on joint friction."""

    mass: float = 1.0
    """Every body's mass and rotational inertia ×mass (e.g. 1.1: the real arm is 10 % heavier)."""
    friction: float = 1.0
    """Every joint's frictionloss (Coulomb) and damping (viscous) ×friction."""
    spread: float = 0.0
    """Each body and joint also ×U[1 − spread, 1 + spread], drawn from ``seed`` (0: uniform scaling)."""
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("mass", "friction"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"mismatch {name} must be a positive factor, got {value}")
        if not (math.isfinite(self.spread) and 0.0 <= self.spread < 1.0):
            raise ValueError(f"mismatch spread must be within [0, 1), got {self.spread}")

    @property
    def identity(self) -> bool:
        return self.mass == 1.0 and self.friction == 1.0 and self.spread == 0.0

    def factors(self, bodies: int, dofs: int) -> tuple[np.ndarray, np.ndarray]:
        """Per-body mass factors and per-dof friction factors (the same for the same seed)."""
        rng = np.random.default_rng(self.seed)
        body = self.mass * rng.uniform(1.0 - self.spread, 1.0 + self.spread, bodies)
        dof = self.friction * rng.uniform(1.0 - self.spread, 1.0 + self.spread, dofs)
        return body, dof


@dataclass(frozen=True)
class Push:
    """A force on the tool: ``force`` (N, world frame) from ``start`` (s, plant time) for ``duration`` s, ramped
    linearly from and back to zero over ``ramp`` s at each end (inside the duration)."""

    force: tuple[float, float, float]
    start: float = 0.0
    duration: float = math.inf
    ramp: float = 0.0

    def __post_init__(self) -> None:
        if len(self.force) != 3 or not all(math.isfinite(f) for f in self.force):
            raise ValueError(f"a push's force is three finite numbers (N), got {self.force}")
        if not (math.isfinite(self.start) and self.duration > 0.0 and not math.isnan(self.duration)):
            raise ValueError("a push needs a finite start and a positive duration")
        if not (math.isfinite(self.ramp) and self.ramp >= 0.0 and 2.0 * self.ramp <= self.duration):
            raise ValueError("a push's ramp must be ≥ 0 and fit twice in its duration")

    def scale(self, t: float) -> float:
        """0…1: how much of the force acts at plant time ``t``."""
        since, until = t - self.start, self.start + self.duration - t
        if since < 0.0 or until <= 0.0:
            return 0.0
        if self.ramp <= 0.0:
            return 1.0
        return min(1.0, since / self.ramp, until / self.ramp)


def push_force(pushes: Sequence[Push], t: float, out: np.ndarray) -> np.ndarray:
    """The sum of every push's force at plant time ``t``, written into ``out`` (3,)."""
    out[:] = 0.0
    for push in pushes:
        s = push.scale(t)
        if s > 0.0:
            out[0] += s * push.force[0]
            out[1] += s * push.force[1]
            out[2] += s * push.force[2]
    return out


@dataclass(frozen=True)
class Obstacle:
    """A fixed primitive in the plant's world: ``size`` are MuJoCo half-sizes (box x y z, sphere r, cylinder r h)."""

    name: str
    shape: str
    size: tuple[float, ...]
    pos: tuple[float, float, float]
    stiffness: float = 0.0
    """N/m of a padded obstacle (0: MuJoCo's default contact)."""
    damping: float = 0.0
    """N·s/m with ``stiffness``."""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.stiffness) and self.stiffness >= 0.0):
            raise ValueError(f"an obstacle's stiffness must be ≥ 0 N/m, got {self.stiffness}")
        if not (math.isfinite(self.damping) and self.damping >= 0.0):
            raise ValueError(f"an obstacle's damping must be ≥ 0 N·s/m, got {self.damping}")
        if self.shape not in SHAPE_SIZES:
            raise ValueError(f"obstacle shape must be one of {', '.join(SHAPE_SIZES)}, got {self.shape!r}")
        if len(self.size) != SHAPE_SIZES[self.shape] or not all(math.isfinite(s) and s > 0.0 for s in self.size):
            raise ValueError(f"a {self.shape} takes {SHAPE_SIZES[self.shape]} positive half-size(s), got {self.size}")
        if len(self.pos) != 3 or not all(math.isfinite(p) for p in self.pos):
            raise ValueError(f"an obstacle's pos is three finite numbers (m), got {self.pos}")
        if not self.name:
            raise ValueError("an obstacle needs a name")


def _numbers(text: str, what: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"{what}: expected comma-separated numbers, got {text!r}") from None
    return values


def parse_obstacle(text: str, index: int = 0) -> Obstacle:
    """``SHAPE:X,Y,Z:SIZES[:STIFFNESS[,DAMPING]]`` (e.g. ``box:0.5,0,0.2:0.05,0.2,0.2:5000,100``) → an Obstacle
    named ``obstacle<index>``."""
    parts = text.split(":")
    if len(parts) not in (3, 4):
        raise ValueError(
            f"expected SHAPE:X,Y,Z:HALF-SIZES[:STIFFNESS[,DAMPING]] (e.g. box:0.5,0,0.2:0.05,0.2,0.2), got {text!r}"
        )
    pos = _numbers(parts[1], "obstacle position")
    if len(pos) != 3:
        raise ValueError(f"an obstacle's position is X,Y,Z, got {parts[1]!r}")
    padding = _numbers(parts[3], "obstacle stiffness") if len(parts) == 4 else (0.0,)
    if len(padding) > 2:
        raise ValueError(f"an obstacle's padding is STIFFNESS[,DAMPING], got {parts[3]!r}")
    stiffness, damping = padding[0], padding[1] if len(padding) == 2 else 0.0
    size = _numbers(parts[2], "obstacle size")
    return Obstacle(f"obstacle{index}", parts[0], size, (pos[0], pos[1], pos[2]), stiffness, damping)


def parse_push(text: str) -> Push:
    """``FX,FY,FZ[@START[+DURATION[~RAMP]]]`` (N, s; e.g. ``0,0,-20@1+0.5~0.05``) → a Push."""
    force_text, _, timing = text.partition("@")
    force = _numbers(force_text, "push force")
    if len(force) != 3:
        raise ValueError(f"a push's force is FX,FY,FZ (N), got {force_text!r}")
    start, duration, ramp = 0.0, math.inf, 0.0
    if timing:
        start_text, _, rest = timing.partition("+")
        duration_text, _, ramp_text = rest.partition("~")
        try:
            start = float(start_text)
            duration = float(duration_text) if duration_text else math.inf
            ramp = float(ramp_text) if ramp_text else 0.0
        except ValueError:
            raise ValueError(f"expected FX,FY,FZ@START+DURATION~RAMP, got {text!r}") from None
    return Push((force[0], force[1], force[2]), start, duration, ramp)
