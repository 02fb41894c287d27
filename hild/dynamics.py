"""Rigid-body dynamics of the arm model: gravity feed-forward for hold and controllers, kinematics for viewers,
and what the importer needs to know of a model (inertia over poses, contacts at the start pose).

This and ``drivers/mujoco`` are the only places that import mujoco (DESIGN.md §5). The supervisor and controllers
use :class:`GravityModel` to add the torque that balances gravity at the held position, so a hold does not sag by
``τ_gravity / kp``.

The model is MuJoCo's: ``load_model`` reads MJCF (``.xml``) or URDF (``.urdf``) with MuJoCo's own loader, so the
twin and the feed-forward always agree on the same file.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from hild.arrays import contiguous_slice

__all__ = [
    "SCALAR_JOINT_TYPES",
    "BodyContact",
    "GeomShape",
    "GravityModel",
    "JointDofs",
    "Kinematics",
    "body_contacts",
    "contiguous_slice",
    "joint_dofs",
    "joint_names",
    "load_model",
    "scalar_joint_addresses",
]

# Joint types that own exactly one position and one velocity coordinate.
SCALAR_JOINT_TYPES = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))


def load_model(path: Path, exclude_contacts: Sequence[tuple[str, str]] = ()) -> mujoco.MjModel:
    """Load and compile an MJCF (``.xml``) or URDF (``.urdf``) model with MuJoCo's loader.

    ``exclude_contacts``: body pairs whose contacts MuJoCo ignores (``<contact><exclude>``), added before the model
    is compiled, since a URDF cannot say it. Raises ``ValueError`` naming the file, with MuJoCo's own message, when
    the file is missing or does not compile, or a pair names a body the model does not have.
    """
    path = Path(path)
    if path.suffix.lower() not in (".xml", ".urdf", ".mjcf"):
        raise ValueError(f"model {path}: expected an MJCF (.xml) or URDF (.urdf) file")
    if not path.is_file():
        raise ValueError(f"model {path}: file not found")
    try:
        if not exclude_contacts:
            return mujoco.MjModel.from_xml_path(str(path))
        spec = mujoco.MjSpec.from_file(str(path))
    except Exception as exc:  # mujoco raises ValueError; be robust to other binding errors
        raise ValueError(f"model {path}: MuJoCo could not load it: {exc}") from exc
    bodies = {body.name for body in spec.bodies}
    unknown = sorted({name for pair in exclude_contacts for name in pair} - bodies)
    if unknown:
        raise ValueError(f"model {path}: exclude_contacts names bodies it does not have: {', '.join(unknown)}")
    for first, second in exclude_contacts:
        spec.add_exclude(bodyname1=first, bodyname2=second)
    try:
        return spec.compile()
    except Exception as exc:
        raise ValueError(f"model {path}: MuJoCo could not load it: {exc}") from exc


def joint_names(model: mujoco.MjModel) -> list[str]:
    """Names of the model's joints, in model order (unnamed joints as ``<unnamed #i>``)."""
    return [model.joint(i).name or f"<unnamed #{i}>" for i in range(model.njnt)]


def scalar_joint_addresses(
    model: mujoco.MjModel, names: Sequence[str], what: str = "model"
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Map joint names to ``(joint ids, qpos addresses, dof addresses)``.

    Every name must be a hinge or slide joint of ``model``; otherwise ``ValueError`` lists the names that are
    missing (or of the wrong type) and the model's joint names.
    """
    ids: list[int] = []
    missing: list[str] = []
    wrong_type: list[str] = []
    for name in names:
        jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        if jid < 0:
            missing.append(name)
        elif int(model.jnt_type[jid]) not in SCALAR_JOINT_TYPES:
            wrong_type.append(name)
        else:
            ids.append(jid)
    if missing or wrong_type:
        parts = []
        if missing:
            parts.append(f"joints not in the {what}: {', '.join(missing)}")
        if wrong_type:
            parts.append(f"not hinge/slide joints: {', '.join(wrong_type)}")
        raise ValueError(f"{'; '.join(parts)} (the {what} has joints: {', '.join(joint_names(model)) or 'none'})")
    if len(set(ids)) != len(ids):
        raise ValueError(f"joint names repeat: {', '.join(names)}")
    jid = np.asarray(ids, dtype=np.intp)
    return jid, model.jnt_qposadr[jid].astype(np.intp), model.jnt_dofadr[jid].astype(np.intp)


@dataclass(frozen=True)
class JointDofs:
    """What a joint's drive moves, from the model: its inertia at given poses and its passive dynamics."""

    inertia: np.ndarray  # poses × joints: diagonal of the joint-space mass matrix (armature included)
    at_qpos0: np.ndarray  # joints: the same at the model's reference pose
    damping: np.ndarray  # joints: viscous damping (N·m·s/rad or N·s/m)
    friction: np.ndarray  # joints: Coulomb friction (frictionloss)
    qpos0: np.ndarray  # joints: the reference pose


def joint_dofs(path: Path, joints: Sequence[str], poses: np.ndarray) -> JointDofs:
    """MuJoCo's own mass matrix, evaluated for ``joints`` at each row of ``poses`` (other joints at qpos0).

    A joint's inertia changes with the pose (a base joint carries far more with the arm stretched out), so tools
    that pick gains or a physics step need it over the poses the arm can take, not at one pose."""
    model = load_model(path)
    data = mujoco.MjData(model)
    _, qposadr, dofadr = scalar_joint_addresses(model, joints)
    full = np.zeros((model.nv, model.nv))
    inertia = np.empty((len(poses), len(joints)))
    for k, pose in enumerate(np.atleast_2d(poses)):
        data.qpos[:] = model.qpos0
        data.qpos[qposadr] = pose
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        mujoco.mj_crb(model, data)
        mujoco.mj_fullM(model, data, full)
        inertia[k] = full[dofadr, dofadr]
    return JointDofs(
        inertia=inertia,
        at_qpos0=model.dof_M0[dofadr].copy(),
        damping=model.dof_damping[dofadr].copy(),
        friction=model.dof_frictionloss[dofadr].copy(),
        qpos0=model.qpos0[qposadr].copy(),
    )


@dataclass(frozen=True)
class BodyContact:
    first: str  # body names, in model order
    second: str
    depth: float  # m: the deepest penetration between their geoms


def body_contacts(path: Path, pose: Mapping[str, float]) -> list[BodyContact]:
    """Pairs of bodies whose geoms MuJoCo finds penetrating at ``pose`` (joint name → position; other joints at
    qpos0), each once, in model order — the contacts the model would fight from its first step."""
    model = load_model(path)
    data = mujoco.MjData(model)
    data.qpos[:] = model.qpos0
    if pose:
        _, qposadr, _ = scalar_joint_addresses(model, list(pose))
        data.qpos[qposadr] = list(pose.values())
    mujoco.mj_forward(model, data)
    deepest: dict[tuple[int, int], float] = {}
    for contact in data.contact[: data.ncon]:
        if contact.dist >= 0.0:
            continue
        a, b = sorted((int(model.geom_bodyid[contact.geom1]), int(model.geom_bodyid[contact.geom2])))
        deepest[a, b] = max(deepest.get((a, b), 0.0), -float(contact.dist))
    return [BodyContact(model.body(a).name, model.body(b).name, depth) for (a, b), depth in sorted(deepest.items())]


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
        self._qpos = d.qpos  # cached view: attribute access on MjData builds a new ndarray each time
        self._result = np.zeros(self.model.nv)
        # When the joints are one contiguous block in model order (the usual case), copy through prebuilt slice
        # views, which is cheaper than take/put; otherwise gather/scatter by address.
        qb, db = contiguous_slice(self._qposadr), contiguous_slice(self._dofadr)
        self._qpos_view = self._qpos[qb] if qb is not None else None
        self._result_view = self._result[db] if db is not None else None

    def __len__(self) -> int:
        return len(self.joint_names)

    def compute(self, q: np.ndarray, out: np.ndarray) -> None:
        """Write into ``out`` (one entry per joint, ``joint_names`` order) the torque balancing gravity at ``q``."""
        m, d = self.model, self._data
        if self._qpos_view is not None:
            np.copyto(self._qpos_view, q)
        else:
            np.put(self._qpos, self._qposadr, q)
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_rne(m, d, 0, self._result)
        if self._result_view is not None:
            np.copyto(out, self._result_view)
        else:
            np.take(self._result, self._dofadr, out=out)


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
    Joints of the model that are not in ``joint_names`` stay at the model's ``qpos0``.
    """

    def __init__(self, model_path: Path, joint_names: Sequence[str]) -> None:
        self.model = load_model(Path(model_path))
        m = self.model
        try:
            _, self._qposadr, _ = scalar_joint_addresses(m, joint_names)
        except ValueError as exc:
            raise ValueError(f"model {model_path}: {exc}") from None
        self._data = mujoco.MjData(m)
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
            mujoco.mj_kinematics(m, d)
            xyz[row] = d.xpos[1:]
            wxyz[row] = d.xquat[1:]
        return xyz, wxyz
