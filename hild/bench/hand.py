"""A scripted hand: a force at the tool of a MuJoCo arm (the twin's or the CAN emulator's plant), through
``MjData.xfrc_applied``, for hand-guiding tests and the contact bench.

``xfrc_applied`` acts at a body's centre of mass; the hand pushes at a site (the tool), so the torque of the force's
offset is added and re-computed from the current pose by :meth:`ScriptedHand.apply`, which the caller runs before
each cycle (the arm moves under the hand). Anything with ``model`` and ``data`` (MuJoCo's) will do:
``drivers.mujoco.twin.MujocoTwin``, ``drivers.mujoco.plant.TwinPlant``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import mujoco
import numpy as np


class ScriptedHand:
    def __init__(self, sim: Any, site: str = "tool") -> None:
        """``sim``: the twin (or plant) whose ``model``/``data`` the hand pushes; ``site``: where it pushes."""
        self.sim = sim
        model = sim.model
        self.site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, site)
        if self.site < 0:
            raise ValueError(f"the model has no site {site!r}")
        self.body = int(model.site_bodyid[self.site])
        self.force = np.zeros(3)

    def push(self, force: Sequence[float]) -> None:
        """Push with ``force`` (N, world frame) from now on, until :meth:`release`."""
        self.force[:] = force
        self.apply()

    def release(self) -> None:
        self.force[:] = 0.0
        self.apply()

    def apply(self) -> None:
        """Set the force and its torque about the body's centre of mass at the current pose."""
        data = self.sim.data
        arm = data.site_xpos[self.site] - data.xipos[self.body]
        data.xfrc_applied[self.body, :3] = self.force
        data.xfrc_applied[self.body, 3:] = np.cross(arm, self.force)

    def joint_torques(self, force: Sequence[float]) -> np.ndarray:
        """The torque ``force`` at the site gives each degree of freedom of the model at the current pose (Jᵀ·F):
        whether a push can move a joint at all, against its friction (a stretched arm pushed along itself cannot)."""
        model, data = self.sim.model, self.sim.data
        jacobian = np.zeros((3, model.nv))
        mujoco.mj_jacSite(model, data, jacobian, None, self.site)
        return np.asarray(jacobian.T @ np.asarray(force, dtype=float))

    def tool_position(self) -> np.ndarray:
        """Where the hand pushes, world frame (m)."""
        return np.array(self.sim.data.site_xpos[self.site])


def run_with_hand(step: Callable[[int], Any], hand: ScriptedHand, cycles: int) -> None:
    """Run ``cycles`` cycles (``step(1)``: e.g. ``engine.run_cycles``), the hand's torque re-aimed before each."""
    for _ in range(cycles):
        hand.apply()
        step(1)
