"""The MuJoCo model as an emulator plant: the arm's real dynamics behind emulated CAN drives.

`hild emulate --plant twin` puts firmware-faithful drives (drivers/can/emulator) in front of this plant, so a daemon
talking CAN sees the same arm the twin driver simulates. The emulator works in *actuator space* — the shaft angle a
drive senses and the torque it produces — while the model is built in joint space, so every joint carries the
config's transmission, mapped by the daemon's own :class:`hild.cycle.transmission.Transmissions`:

* positions and velocities are published in actuator space;
* a drive torque acts on the joint through the transmission (applied as ``qfrc_applied``); the drives saturate
  their own torque, so the model's actuatorfrcrange is not applied on top.

Like `MotorPlant`, `positions` and `velocities` are the plant's state: a caller may overwrite them (a brake, a test
placing the arm), and the next `step` starts from the written values. Model joints without a drive move freely,
except mimic joints: a joint equality (``<equality><joint joint1="follower" joint2="leader" polycoef=…/>``) ties a
follower to a driven leader, and every start pose (`reset`) puts the follower where the coupling wants it, so the
constraint does not snap a linkage (e.g. a gripper's second finger) into place on the first step.

For the contact bench (`drivers.can.emulator.disturbances`): ``mismatch`` scales the plant's masses, inertias and
joint friction away from the model file (hild keeps the file's values), ``obstacles`` adds fixed primitives the
links collide with, and `pushes` (a list, appendable while running) apply scheduled forces at ``force_site``
through ``xfrc_applied``. `contact_force` is the true force the obstacles exert on the arm (``mj_contactForce``),
and `peak_contact_force` its largest norm over every physics step since `reset_peak`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import mujoco
import numpy as np

from drivers.can.emulator.disturbances import Obstacle, PlantMismatch, Push, push_force
from hild.cycle.transmission import Transmissions
from hild.dynamics.model import (
    SCALAR_JOINT_TYPES,
    SceneObject,
    couple_joints,
    joint_couplings,
    joint_names,
    load_model,
    scalar_joint_addresses,
)

__all__ = ["TwinPlant"]


def _per_joint(value: float | Sequence[float], n: int, name: str) -> np.ndarray:
    array = np.array(np.broadcast_to(np.asarray(value, dtype=float), (n,)))
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} must be finite")
    return array


class TwinPlant:
    """The joints ``joints`` of the MuJoCo model at ``model_path``, seen through their transmissions.

    ``keyframe`` (a model keyframe name) and ``initial_positions`` (joint space, by joint name) set the start pose;
    ``gravity=False`` switches gravity off. The physics timestep follows the ``dt`` of each `step`.
    """

    def __init__(
        self,
        model_path: Path | str,
        joints: Sequence[str],
        *,
        reduction: float | Sequence[float] = 1.0,
        direction: float | Sequence[float] = 1.0,
        offset: float | Sequence[float] = 0.0,
        keyframe: str | None = None,
        initial_positions: Mapping[str, float] | None = None,
        gravity: bool = True,
        mismatch: PlantMismatch | None = None,
        obstacles: Sequence[Obstacle] = (),
        pushes: Sequence[Push] = (),
        force_site: str = "tool",
    ) -> None:
        objects = [SceneObject(o.name, o.shape, tuple(o.size), o.pos, fixed=True) for o in obstacles]
        self.model = load_model(Path(model_path), objects=objects)
        self.data = mujoco.MjData(self.model)
        self.mismatch = mismatch or PlantMismatch()
        if not self.mismatch.identity:
            self._apply_mismatch(self.mismatch)
        self.obstacles = tuple(o.name for o in obstacles)
        self._obstacle_geoms = frozenset(
            mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_GEOM, o.name) for o in obstacles
        )
        for obstacle in obstacles:
            if obstacle.stiffness > 0.0:  # padded: direct solref, and its parameters win over the arm's
                geom = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_GEOM, obstacle.name)
                self.model.geom_solref[geom] = (-obstacle.stiffness, -obstacle.damping)
                self.model.geom_priority[geom] = 1
        self.pushes: list[Push] = list(pushes)
        """Scheduled forces at ``force_site`` (plant time); append to push while running."""
        site = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_SITE, force_site)
        if site < 0 and (self.pushes or force_site != "tool"):
            raise ValueError(f"model {Path(model_path).name} has no site {force_site!r} to push on")
        self._site = site
        self._site_body = int(self.model.site_bodyid[site]) if site >= 0 else -1
        self.push_now = np.zeros(3)
        """The force (N, world) the pushes applied in the latest step."""
        self._force = np.zeros(6)
        self._contact = np.zeros(3)
        self._contact6 = np.zeros(6)
        self.peak_contact_force = 0.0
        """Largest norm of `contact_force` over every step since `reset_peak` (N)."""
        self.joints = tuple(joints)
        n = len(self.joints)
        _, self._qposadr, self._dofadr = scalar_joint_addresses(self.model, self.joints)
        self.reduction = _per_joint(reduction, n, "reduction")
        self.direction = _per_joint(direction, n, "direction")
        self.offset = _per_joint(offset, n, "offset")
        if np.any(self.reduction <= 0.0) or not np.all(np.abs(self.direction) == 1.0):
            raise ValueError("reduction must be positive and direction ±1")
        self.transmissions = Transmissions(self.reduction, self.direction, self.offset)  # the daemon's maths
        own = set(self._qposadr.tolist())
        names = joint_names(self.model)
        couplings = joint_couplings(self.model)
        self.mimic_joints = {names[c.follower]: names[c.leader] for c in couplings}
        """Model joints a joint equality ties to another (mimic joints): follower → leader."""
        coupled = {c.follower for c in couplings}
        self.free_joints = [
            name
            for i, name in enumerate(names)
            if int(self.model.jnt_type[i]) in SCALAR_JOINT_TYPES
            and int(self.model.jnt_qposadr[i]) not in own
            and i not in coupled
        ]
        """Model joints no drive acts on and no joint equality couples (mimic joints follow): they move freely."""
        if not gravity:
            self.model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_GRAVITY)
        self.model_name = Path(model_path).name
        self._qpos, self._qvel, self._qfrc = self.data.qpos, self.data.qvel, self.data.qfrc_applied
        self.positions = np.zeros(n)
        self.velocities = np.zeros(n)
        self._published_positions = np.zeros(n)
        self._published_velocities = np.zeros(n)
        self._joint_torque = np.zeros(n)
        self._joint_scratch = np.zeros(n)
        self.reset(keyframe, initial_positions)

    @property
    def keyframes(self) -> list[str]:
        """Names of the model's keyframes."""
        return [self.model.key(i).name for i in range(self.model.nkey)]

    def reset(self, keyframe: str | None = None, initial_positions: Mapping[str, float] | None = None) -> None:
        """Back to rest at ``keyframe`` (default: the model's qpos0), then ``initial_positions`` (joint space), then
        every joint a joint equality couples (mimic joints) from its leader."""
        m, d = self.model, self.data
        if keyframe is None:
            mujoco.mj_resetData(m, d)
        else:
            key = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_KEY, keyframe)
            if key < 0:
                raise ValueError(f"model {self.model_name} has no keyframe {keyframe!r} (keyframes: {self.keyframes})")
            mujoco.mj_resetDataKeyframe(m, d, key)
        for name, value in (initial_positions or {}).items():
            if name not in self.joints:
                raise ValueError(f"initial position for {name!r}, which is not one of {list(self.joints)}")
            d.qpos[self._qposadr[self.joints.index(name)]] = value
        d.qvel[:] = 0.0
        couple_joints(m, d)  # mimic joints from their leaders: a violated coupling snaps the linkage at once
        mujoco.mj_forward(m, d)
        self._publish()

    @property
    def time(self) -> float:
        """Simulated seconds since the start."""
        return float(self.data.time)

    def joint_positions(self, out: np.ndarray | None = None) -> np.ndarray:
        """The emulated joints' positions in joint space, from the actuator-space state (written values included)."""
        out = np.empty(len(self.joints)) if out is None else out
        self.transmissions.joint_positions(self.positions, out)
        return out

    def joint_velocities(self, out: np.ndarray | None = None) -> np.ndarray:
        out = np.empty(len(self.joints)) if out is None else out
        self.transmissions.joint_velocities(self.velocities, out)
        return out

    def step(self, torques: np.ndarray, dt: float) -> None:
        """Apply the drives' torques (actuator space) for one physics step of ``dt`` seconds."""
        if not (
            np.array_equal(self.positions, self._published_positions)
            and np.array_equal(self.velocities, self._published_velocities)
        ):
            self._adopt()
        self.transmissions.joint_efforts(torques, self._joint_torque)
        np.put(self._qfrc, self._dofadr, self._joint_torque)
        if self.model.opt.timestep != dt:
            self.model.opt.timestep = dt
        if self.pushes or self.push_now.any():
            self._push()
        mujoco.mj_step(self.model, self.data)
        if self._obstacle_geoms and self.data.ncon:
            peak = float(np.linalg.norm(self.contact_force()))
            if peak > self.peak_contact_force:
                self.peak_contact_force = peak
        self._publish()

    def contact_force(self, out: np.ndarray | None = None) -> np.ndarray:
        """The total force (N, world frame) the obstacles exert on the arm now, from MuJoCo's contact forces."""
        out = self._contact if out is None else out
        out[:] = 0.0
        m, d, f = self.model, self.data, self._contact6
        for i in range(d.ncon):
            contact = d.contact[i]
            g1, g2 = int(contact.geom1), int(contact.geom2)
            first, second = g1 in self._obstacle_geoms, g2 in self._obstacle_geoms
            if first == second:
                continue  # not between an obstacle and the arm
            mujoco.mj_contactForce(m, d, i, f)
            world = contact.frame.reshape(3, 3).T @ f[:3]  # the force geom1 exerts on geom2
            if second:
                out -= world  # the arm is geom1: it feels the opposite
            else:
                out += world
        return out

    def reset_peak(self) -> None:
        """Start a new peak of the contact force."""
        self.peak_contact_force = 0.0

    def tool_position(self, out: np.ndarray | None = None) -> np.ndarray:
        """World position (m) of the push site as of the latest step."""
        out = np.empty(3) if out is None else out
        out[:] = self.data.site_xpos[self._site]
        return out

    def _push(self) -> None:
        """``xfrc_applied`` on the site's body: the pushes' force, and the torque of it acting at the site."""
        d, body = self.data, self._site_body
        if body < 0:
            raise ValueError(f"model {self.model_name} has no site to push on")
        push_force(self.pushes, float(d.time), self.push_now)
        self._force[:3] = self.push_now
        self._force[3:] = np.cross(d.site_xpos[self._site] - d.xipos[body], self.push_now)
        d.xfrc_applied[body] = self._force

    def _apply_mismatch(self, mismatch: PlantMismatch) -> None:
        """Scale masses, inertias and joint friction away from the file (hild keeps the file's values)."""
        m = self.model
        body, dof = mismatch.factors(m.nbody, m.nv)
        body[0] = 1.0  # the world
        m.body_mass[:] *= body
        m.body_inertia[:] *= body[:, None]
        m.dof_frictionloss[:] *= dof
        m.dof_damping[:] *= dof
        mujoco.mj_setConst(m, self.data)

    def _publish(self) -> None:
        """Joint-space state → actuator-space arrays (and remember them, to notice outside writes)."""
        q = self._joint_scratch
        np.take(self._qpos, self._qposadr, out=q)
        self.transmissions.actuator_positions(q, self.positions)
        np.take(self._qvel, self._dofadr, out=q)
        self.transmissions.actuator_velocities(q, self.velocities)
        np.copyto(self._published_positions, self.positions)
        np.copyto(self._published_velocities, self.velocities)

    def _adopt(self) -> None:
        """Someone wrote the actuator-space arrays: make them the model's state."""
        q = self._joint_scratch
        self.transmissions.joint_positions(self.positions, q)
        np.put(self._qpos, self._qposadr, q)
        self.transmissions.joint_velocities(self.velocities, q)
        np.put(self._qvel, self._dofadr, q)
