"""Where the tool is for given joint positions: the collision reflex measures its retract along the tool's path."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import mujoco
import numpy as np

from hild.dynamics.model import load_model, scalar_joint_addresses


class ToolPoint:
    """The world position of ``site`` (default: the origin of the body the last of ``joint_names`` moves).

    Not for every cycle: a collision asks it a few dozen times, once, to find where along the recent path the arm
    was ``retract_distance`` ago."""

    def __init__(self, model_path: Path, joint_names: Sequence[str], site: str | None = None) -> None:
        self.model = m = load_model(Path(model_path))
        try:
            jid, self._qposadr, _ = scalar_joint_addresses(m, joint_names)
        except ValueError as exc:
            raise ValueError(f"model {model_path}: {exc}") from None
        self._data = mujoco.MjData(m)
        self._data.qpos[:] = m.qpos0
        self._site = -1
        if site:
            self._site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, site)
            if self._site < 0:
                sites = [m.site(s).name for s in range(m.nsite)]
                raise ValueError(f"model {model_path} has no site {site!r} (its sites: {', '.join(sites) or 'none'})")
        self._body = int(m.jnt_bodyid[jid[-1]])

    def position(self, q: np.ndarray) -> np.ndarray:
        m, d = self.model, self._data
        d.qpos[self._qposadr] = q
        mujoco.mj_kinematics(m, d)
        return (d.site_xpos[self._site] if self._site >= 0 else d.xpos[self._body]).copy()
