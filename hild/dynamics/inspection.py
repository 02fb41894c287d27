"""What the importer and ``hild check`` ask of a model: a joint's inertia over the poses the arm can take, and
which bodies already touch at a pose."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from hild.dynamics.model import couple_joints, load_model, scalar_joint_addresses


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
    qpos0, joints a joint equality couples where their leaders put them, as the twin starts), each once, in model
    order — the contacts the model would fight from its first step."""
    model = load_model(path)
    data = mujoco.MjData(model)
    data.qpos[:] = model.qpos0
    if pose:
        _, qposadr, _ = scalar_joint_addresses(model, list(pose))
        data.qpos[qposadr] = list(pose.values())
    couple_joints(model, data)
    mujoco.mj_forward(model, data)
    deepest: dict[tuple[int, int], float] = {}
    for contact in data.contact[: data.ncon]:
        if contact.dist >= 0.0:
            continue
        a, b = sorted((int(model.geom_bodyid[contact.geom1]), int(model.geom_bodyid[contact.geom2])))
        deepest[a, b] = max(deepest.get((a, b), 0.0), -float(contact.dist))
    return [BodyContact(model.body(a).name, model.body(b).name, depth) for (a, b), depth in sorted(deepest.items())]


def finger_spread(path: Path, joint: str, positions: Sequence[float]) -> list[float]:
    """How far apart the bodies ``joint`` moves are (with every joint a joint equality couples to it: a gripper's
    mimic linkage), at each of ``positions`` of ``joint``, other joints at qpos0: the mean distance between their
    centres of mass. A gripper's fingers are closest at the position that closes it — whichever end of its range
    that is (a Robotiq knuckle closes toward its upper limit, a linear finger's opening toward its lower)."""
    model = load_model(path)
    data = mujoco.MjData(model)
    _, qposadr, _ = scalar_joint_addresses(model, [joint])
    centres = []
    for position in positions:
        data.qpos[:] = model.qpos0
        data.qpos[qposadr[0]] = position
        couple_joints(model, data)
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        centres.append(np.array(data.xipos))
    moved = [b for b in range(1, model.nbody) if any(np.linalg.norm(c[b] - centres[0][b]) > 1e-9 for c in centres)]
    spreads = []
    for c in centres:
        points = c[moved]
        pairs = [np.linalg.norm(points[i] - points[j]) for i in range(len(points)) for j in range(i + 1, len(points))]
        spreads.append(float(np.mean(pairs)) if pairs else 0.0)
    return spreads
