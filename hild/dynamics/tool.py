"""The tool point's position and position Jacobian for joint positions: what the virtual walls check and correct
on the cycle (``hild.cycle.walls``, docs/safety.md "Virtual walls").

Cycle-safe like :mod:`hild.dynamics.gravity`: one private ``MjData``, views and result arrays built once, and per
call only ``mj_kinematics`` (plus ``mj_comPos`` and ``mj_jac`` for the Jacobian) on caller-owned arrays.

``ReadingJacobian`` is the contact force's cheaper way to the same Jacobian: the momentum observer has just evaluated
the model at the very reading the force check wants, so only ``mj_jac`` is left to do (docs/performance.md, "Contact
safety").
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import mujoco
import numpy as np

from hild.dynamics.model import JointSlots, load_model, scalar_joint_addresses
from hild.dynamics.momentum import MomentumObserver

DEFAULT_SITES = ("tool", "flange", "tool0", "tcp")  # the tool frame a model names, in this order of preference


class ToolPoint:
    """A point fixed in a site or body of the arm model (plus an offset in that frame), in the world frame.

    ``frame``: ``"site <name>"`` or ``"body <name>"``, the one it was resolved to. When neither ``site`` nor
    ``body`` is given: the first of ``DEFAULT_SITES`` the model has, else the body of the deepest of
    ``joint_names`` (the last link of the chain). Joints of the model not in ``joint_names`` stay at ``qpos0``.
    Raises ``ValueError`` naming what the model has when the site or body is not there.
    """

    def __init__(
        self,
        model_path: Path,
        joint_names: Sequence[str],
        *,
        site: str | None = None,
        body: str | None = None,
        offset: Sequence[float] = (0.0, 0.0, 0.0),
    ) -> None:
        self.model = m = load_model(Path(model_path))
        try:
            jids, self._qposadr, self._dofadr = scalar_joint_addresses(m, joint_names)
        except ValueError as exc:
            raise ValueError(f"model {model_path}: {exc}") from None
        self._data = d = mujoco.MjData(m)
        d.qpos[:] = m.qpos0
        self.site, self.body = self._frame(m, jids, site, body, model_path)
        if self.site >= 0:
            self.frame = f"site {m.site(self.site).name}"
            self._origin, self._rotation = d.site_xpos[self.site], d.site_xmat[self.site].reshape(3, 3)
        else:
            self.frame = f"body {m.body(self.body).name}"
            self._origin, self._rotation = d.xpos[self.body], d.xmat[self.body].reshape(3, 3)
        self.offset = np.array(offset, dtype=float)
        self.reach = self._reach(m, jids)
        self.point = np.zeros(3)  # the last position computed (world frame)
        self._rotated = np.zeros(3)
        self._jacp = np.zeros((3, m.nv))
        self._pose = JointSlots(d.qpos, self._qposadr)

    @staticmethod
    def _frame(m: mujoco.MjModel, jids: np.ndarray, site: str | None, body: str | None, path: Path) -> tuple[int, int]:
        """``(site id or -1, body id)`` of the tool frame."""
        if site is not None:
            sid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, site)
            if sid < 0:
                known = ", ".join(m.site(i).name for i in range(m.nsite) if m.site(i).name) or "none"
                raise ValueError(f"model {path}: no site {site!r} for the tool (sites: {known})")
            return sid, int(m.site_bodyid[sid])
        if body is not None:
            bid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, body)
            if bid < 0:
                known = ", ".join(m.body(i).name for i in range(1, m.nbody) if m.body(i).name) or "none"
                raise ValueError(f"model {path}: no body {body!r} for the tool (bodies: {known})")
            return -1, bid
        for name in DEFAULT_SITES:
            sid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, name)
            if sid >= 0:
                return sid, int(m.site_bodyid[sid])
        bodies = [int(m.jnt_bodyid[j]) for j in jids]
        return -1, max(bodies, key=lambda b: (_depth(m, b), b))

    def _reach(self, m: mujoco.MjModel, jids: np.ndarray) -> np.ndarray:
        """Per joint, an upper bound on how fast the tool point moves per unit of its speed (m/rad, or 1 for a
        slide joint): the distance from its axis to the tool is at most the sum of the offsets along the chain
        from the joint's anchor to the tool (rotations keep lengths). 0 for a joint that does not move the tool."""
        tail = float(np.linalg.norm(self.offset))
        if self.site >= 0:
            tail += float(np.linalg.norm(m.site_pos[self.site]))
        reach = np.zeros(len(jids))
        for k, j in enumerate(jids.tolist()):
            if int(m.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_SLIDE):
                reach[k] = 1.0 if _descends(m, self.body, int(m.jnt_bodyid[j])) else 0.0
                continue
            home, body, length = int(m.jnt_bodyid[j]), self.body, tail + float(np.linalg.norm(m.jnt_pos[j]))
            while body > 0 and body != home:
                length += float(np.linalg.norm(m.body_pos[body]))
                body = int(m.body_parentid[body])
            reach[k] = length if body == home else 0.0
        return reach

    def __len__(self) -> int:
        return len(self._qposadr)

    def position(self, q: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """The tool point at joint positions ``q`` (``joint_names`` order), written into ``out`` (and ``point``).
        Leaves the pose in the private data: :meth:`jacobian` right after is at the same ``q``."""
        d = self._data
        self._pose.write(q)
        mujoco.mj_kinematics(self.model, d)
        np.matmul(self._rotation, self.offset, out=self._rotated)
        np.add(self._origin, self._rotated, out=self.point)
        if out is not None:
            np.copyto(out, self.point)
        return self.point

    def jacobian(self, out: np.ndarray) -> np.ndarray:
        """∂point/∂q (3 × joints) at the pose of the last :meth:`position` call, written into ``out``."""
        m, d = self.model, self._data
        mujoco.mj_comPos(m, d)
        mujoco.mj_jac(m, d, self._jacp, None, self.point, self.body)
        np.take(self._jacp, self._dofadr, axis=1, out=out)
        return out


class ReadingJacobian:
    """The tool point's position Jacobian at the momentum observer's last reading (``MomentumObserver.data``: an
    ``MjData`` of the same model whose kinematics and ``mj_comPos`` are done), read off it with one ``mj_jac``.

    ``jacobian`` returns one array it reuses (3 × joints, ``joint_names`` order), valid until its next call.
    """

    def __init__(self, tool: ToolPoint, observer: MomentumObserver) -> None:
        if tool.model.nv != observer.model.nv or tool.model.nbody != observer.model.nbody:
            raise ValueError("the tool point and the observer must be built on the same model")
        self.model, self.data, self.body, self.offset = observer.model, observer.data, tool.body, tool.offset
        self._moved = bool(np.any(tool.offset != 0.0))  # a point off the frame's origin: R·offset to add
        self._jacp = np.zeros((3, observer.model.nv))
        dofs = tool._dofadr
        whole = dofs.tolist() == list(range(observer.model.nv))
        self._jac = self._jacp if whole else np.zeros((3, len(dofs)))  # every dof a joint of ours: no copy
        self._dofadr = None if whole else dofs
        self._point = np.zeros(3)
        self._rotated = np.zeros(3)
        # The frame's origin and rotation in the observer's data, as prebuilt views (MjData builds new ones per access)
        d = self.data
        if tool.site >= 0:
            self._origin, self._rotation = d.site_xpos[tool.site], d.site_xmat[tool.site].reshape(3, 3)
        else:
            self._origin, self._rotation = d.xpos[tool.body], d.xmat[tool.body].reshape(3, 3)

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        """∂point/∂q at ``q``, which must be the observer's latest reading (the contact monitor calls it right after
        the observer's ``update``)."""
        point = self._origin
        if self._moved:
            np.matmul(self._rotation, self.offset, out=self._rotated)
            point = np.add(point, self._rotated, out=self._point)
        mujoco.mj_jac(self.model, self.data, self._jacp, None, point, self.body)
        if self._dofadr is not None:
            np.take(self._jacp, self._dofadr, axis=1, out=self._jac)
        return self._jac


def _descends(m: mujoco.MjModel, body: int, ancestor: int) -> bool:
    while body > 0 and body != ancestor:
        body = int(m.body_parentid[body])
    return body == ancestor


def _depth(m: mujoco.MjModel, body: int) -> int:
    depth = 0
    while body > 0:
        body = int(m.body_parentid[body])
        depth += 1
    return depth
