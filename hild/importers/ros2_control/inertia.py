"""How heavy each joint feels, over the poses it can take: the basis of default gains and the twin's step.

A joint's inertia (the diagonal of the joint-space mass matrix) changes with the pose: a base pan joint carries
almost nothing with the arm folded up and several times more with it stretched out. Gains tuned for the
heaviest pose track everywhere; the drive law must also stay stable in the lightest pose at the twin's physics
step. So the range matters, not one value. It is MuJoCo's own mass matrix of the twin's model
(:func:`hild.dynamics.inspection.joint_dofs`) at the zero pose and a fixed set of pseudo-random poses within the limits.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hild.dynamics.inspection import joint_dofs

SAMPLED_POSES = 64  # plus the zero pose; deterministic (fixed seed)


@dataclass(frozen=True)
class JointInertia:
    at_zero: float  # kg·m² (kg for a prismatic joint), at qpos0
    lightest: float  # over the sampled poses
    heaviest: float
    damping: float  # the model's viscous damping (N·m·s/rad) and Coulomb friction (N·m) of the joint
    friction: float


def joint_inertias(
    model_path: Path, joints: Sequence[str], ranges: Mapping[str, tuple[float, float]]
) -> dict[str, JointInertia]:
    """Inertia range of each joint over the zero pose and ``SAMPLED_POSES`` poses within ``ranges``.

    Loading the model here is also the check that the twin can load the URDF at all (``ValueError`` if not).
    """
    lower = np.array([ranges[j][0] for j in joints])
    upper = np.array([ranges[j][1] for j in joints])
    samples = lower + (upper - lower) * np.random.default_rng(0).random((SAMPLED_POSES, len(joints)))
    dofs = joint_dofs(model_path, joints, samples)
    every = np.vstack([dofs.at_qpos0, dofs.inertia])
    return {
        j: JointInertia(
            at_zero=float(dofs.at_qpos0[i]),
            lightest=float(every[:, i].min()),
            heaviest=float(every[:, i].max()),
            damping=float(dofs.damping[i]),
            friction=float(dofs.friction[i]),
        )
        for i, j in enumerate(joints)
    }
