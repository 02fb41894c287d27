"""The gravity feed-forward: the torque that balances gravity at the held position, so a hold does not sag by
``τ_gravity / kp``. Used by the supervisor and controllers on the cycle, and by ``hild check``'s stop review."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Protocol

import mujoco
import numpy as np

from hild.arrays import contiguous_slice
from hild.dynamics.model import JointSlots, load_model, scalar_joint_addresses


class GravityAt(Protocol):
    def gravity_at(self, q: np.ndarray, out: np.ndarray) -> bool: ...


class GravityModel:
    """Joint torques that balance gravity at a given pose (``qvel = 0``, ``qacc = 0``).

    ``compute`` runs on the cycle thread: it writes into a caller-owned array and allocates nothing. It uses a
    private ``MjData`` whose velocities stay zero, and runs only position kinematics (``mj_kinematics``,
    ``mj_comPos``) and recursive Newton–Euler without the inertial term (``mj_rne(flg_acc=0)``); with zero
    velocity that is exactly the gravity term of ``qfrc_bias``. Joints of the model that are not in
    ``joint_names`` stay at the model's ``qpos0``.
    """

    def __init__(self, model_path: Path, joint_names: Sequence[str]) -> None:
        self.model = load_model(Path(model_path))
        self.joint_names = tuple(joint_names)
        try:
            _, self._qposadr, self._dofadr = scalar_joint_addresses(self.model, self.joint_names)
        except ValueError as exc:
            raise ValueError(f"model {model_path}: {exc}") from None
        self._data = mujoco.MjData(self.model)
        d = self._data
        d.qpos[:] = self.model.qpos0
        # mj_rne reads qvel, cvel and cdof_dot: keep them zero forever (mj_comVel is never called on this data).
        d.qvel[:] = 0.0
        d.cvel[:] = 0.0
        d.cdof_dot[:] = 0.0
        self._pose = JointSlots(d.qpos, self._qposadr)  # d.qpos once: attribute access on MjData builds a new one
        self._result = np.zeros(self.model.nv)
        # When the joints are one contiguous block in model order (the usual case), copy through prebuilt slice
        # views, which is cheaper than take/put; otherwise gather/scatter by address.
        db = contiguous_slice(self._dofadr)
        self._result_view = self._result[db] if db is not None else None

    def __len__(self) -> int:
        return len(self.joint_names)

    def compute(self, q: np.ndarray, out: np.ndarray) -> None:
        """Write into ``out`` (one entry per joint, ``joint_names`` order) the torque balancing gravity at ``q``."""
        m, d = self.model, self._data
        self._pose.write(q)
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_rne(m, d, 0, self._result)
        if self._result_view is not None:
            np.copyto(out, self._result_view)
        else:
            np.take(self._result, self._dofadr, out=out)


class SharedGravity:
    """The supervisor's gravity feed-forward when the contact observer runs: the observer evaluates the arm's
    dynamics at every reading anyway (``MomentumObserver(..., gravity=True)``), so at that reading its g(q) is taken
    as it is; any other pose (a joint without an accepted reading, held at 0) is computed by the gravity model."""

    def __init__(self, model: GravityModel, observer: GravityAt) -> None:
        self.model = model
        self.observer = observer

    def compute(self, q: np.ndarray, out: np.ndarray) -> None:
        if not self.observer.gravity_at(q, out):
            self.model.compute(q, out)
