"""Does the arm touch itself at given joint positions? MuJoCo's own collision detection on a private copy of the
model, for the virtual walls' self-collision option (``hild.cycle.walls``, docs/safety.md "Virtual walls").

Cycle-safe: one private ``MjData``; per call ``mj_kinematics`` and ``mj_collision``, and the contact list is read
only when MuJoCo found a contact.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import mujoco
import numpy as np

from hild.dynamics.model import JointSlots, load_model, scalar_joint_addresses

DEPTH = 0.001  # m: a contact shallower than this is a touch the geometry's own tolerance allows, not a collision


class SelfCollision:
    """Contacts between two bodies of the arm deeper than ``depth``, with the model's own filters: contype and
    conaffinity, parent–child pairs (MuJoCo skips them unless the model enables them) and its ``<exclude>`` pairs.
    The arm's bodies are those the configured joints move and their fixed ancestors; the world and what is not
    part of the arm (the floor, loose objects) are the environment, which the walls are for."""

    def __init__(self, model_path: Path, joint_names: Sequence[str], depth: float = DEPTH) -> None:
        self.model = m = load_model(Path(model_path))
        try:
            jids, self._qposadr, _ = scalar_joint_addresses(m, joint_names)
        except ValueError as exc:
            raise ValueError(f"model {model_path}: {exc}") from None
        self._data = d = mujoco.MjData(m)
        d.qpos[:] = m.qpos0
        self.depth = depth
        self._arm = _arm_bodies(m, [int(m.jnt_bodyid[j]) for j in jids.tolist()])
        self._pose = JointSlots(d.qpos, self._qposadr)

    def touching(self, q: np.ndarray) -> tuple[str, str] | None:
        """The first pair of the arm's bodies (names, model order) in collision at ``q``, or None."""
        m, d = self.model, self._data
        self._pose.write(q)
        mujoco.mj_kinematics(m, d)
        mujoco.mj_collision(m, d)
        if not d.ncon:
            return None
        contacts = d.contact
        for dist, (g1, g2) in zip(contacts.dist.tolist(), contacts.geom.tolist(), strict=True):
            a, b = int(m.geom_bodyid[g1]), int(m.geom_bodyid[g2])
            if dist < -self.depth and self._arm[a] and self._arm[b]:
                a, b = sorted((a, b))
                return m.body(a).name or f"body{a}", m.body(b).name or f"body{b}"
        return None


def _arm_bodies(m: mujoco.MjModel, joint_bodies: list[int]) -> list[bool]:
    """Per body: is it part of the arm (moved by one of ``joint_bodies``' joints, or a fixed ancestor of one)?"""
    arm = [False] * m.nbody
    for b in range(1, m.nbody):
        up = b
        while up > 0 and up not in joint_bodies:
            up = int(m.body_parentid[up])
        arm[b] = up > 0
    for b in joint_bodies:
        up = int(m.body_parentid[b])
        while up > 0:
            arm[up] = True
            up = int(m.body_parentid[up])
    return arm
