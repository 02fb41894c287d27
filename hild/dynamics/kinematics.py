"""Forward kinematics for viewers: the model's shapes as plain data and body poses for joint positions, so the
telemetry draws the arm without importing mujoco."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from hild.dynamics.model import couple_joints, joint_couplings, load_model, scalar_joint_addresses

_GEOM_KINDS = {
    int(mujoco.mjtGeom.mjGEOM_PLANE): "plane",
    int(mujoco.mjtGeom.mjGEOM_SPHERE): "sphere",
    int(mujoco.mjtGeom.mjGEOM_CAPSULE): "capsule",
    int(mujoco.mjtGeom.mjGEOM_ELLIPSOID): "ellipsoid",
    int(mujoco.mjtGeom.mjGEOM_CYLINDER): "cylinder",
    int(mujoco.mjtGeom.mjGEOM_BOX): "box",
    int(mujoco.mjtGeom.mjGEOM_MESH): "mesh",
}


@dataclass(frozen=True)
class GeomShape:
    """One geom of the model as plain data, in its body's frame (MuJoCo conventions).

    ``size`` is MuJoCo's: half-extents for a box, radius (+ half-length) for sphere/capsule/cylinder, semi-axes for
    an ellipsoid. ``quat`` is ``w, x, y, z``. ``body`` indexes :attr:`Kinematics.body_names`, or is -1 for geoms
    fixed to the world. Meshes carry their vertices (in the geom frame) and triangle indices.
    """

    name: str
    body: int
    kind: str
    size: np.ndarray
    pos: np.ndarray
    quat: np.ndarray
    rgba: np.ndarray
    vertices: np.ndarray | None = None
    faces: np.ndarray | None = None


class Kinematics:
    """Forward kinematics of the arm model for viewers: shapes once, body poses for given joint positions.

    Plain numpy in and out, so telemetry draws the arm without importing mujoco. Not for the cycle thread (it
    allocates); the telemetry flusher calls :meth:`body_poses` for a decimated batch of measured positions.
    Joints of the model that are not in ``joint_names`` stay at the model's ``qpos0``, except those a joint
    equality couples to another (URDF ``<mimic>``: a gripper's linkage), which are drawn where their leader puts them.
    """

    def __init__(self, model_path: Path, joint_names: Sequence[str]) -> None:
        self.model = load_model(Path(model_path))
        m = self.model
        try:
            _, self._qposadr, _ = scalar_joint_addresses(m, joint_names)
        except ValueError as exc:
            raise ValueError(f"model {model_path}: {exc}") from None
        self._data = mujoco.MjData(m)
        self._couplings = joint_couplings(m)
        # Body 0 is the world: it never moves, so it is not one of the posed bodies.
        self.body_names: tuple[str, ...] = tuple(m.body(b).name or f"body{b}" for b in range(1, m.nbody))
        self.geoms: tuple[GeomShape, ...] = tuple(self._geom(g) for g in range(m.ngeom))

    def _geom(self, g: int) -> GeomShape:
        m = self.model
        kind = _GEOM_KINDS.get(int(m.geom_type[g]), "other")
        rgba = m.geom_rgba[g].copy()
        if m.geom_matid[g] >= 0:
            rgba = m.mat_rgba[m.geom_matid[g]].copy()
        vertices = faces = None
        if kind == "mesh":
            mesh = int(m.geom_dataid[g])
            v0, nv = int(m.mesh_vertadr[mesh]), int(m.mesh_vertnum[mesh])
            f0, nf = int(m.mesh_faceadr[mesh]), int(m.mesh_facenum[mesh])
            vertices = m.mesh_vert[v0 : v0 + nv].copy()
            faces = m.mesh_face[f0 : f0 + nf].copy()
        return GeomShape(
            name=m.geom(g).name or f"geom{g}",
            body=int(m.geom_bodyid[g]) - 1,
            kind=kind,
            size=m.geom_size[g].copy(),
            pos=m.geom_pos[g].copy(),
            quat=m.geom_quat[g].copy(),
            rgba=rgba,
            vertices=vertices,
            faces=faces,
        )

    def body_poses(self, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World poses of every body for each row of joint ``positions`` (k × joints).

        Returns ``(translations k × bodies × 3, quaternions k × bodies × 4 as w, x, y, z)``.
        """
        m, d = self.model, self._data
        q = np.atleast_2d(np.asarray(positions, dtype=float))
        k, nb = len(q), m.nbody - 1
        xyz, wxyz = np.empty((k, nb, 3)), np.empty((k, nb, 4))
        d.qpos[:] = m.qpos0
        for row in range(k):
            d.qpos[self._qposadr] = q[row]
            if self._couplings:
                couple_joints(m, d, self._couplings)
            mujoco.mj_kinematics(m, d)
            xyz[row] = d.xpos[1:]
            wxyz[row] = d.xquat[1:]
        return xyz, wxyz
