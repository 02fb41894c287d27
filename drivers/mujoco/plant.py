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
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import mujoco
import numpy as np

from hild.cycle.transmission import Transmissions
from hild.dynamics.model import (
    SCALAR_JOINT_TYPES,
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
    ) -> None:
        self.model = load_model(Path(model_path))
        self.data = mujoco.MjData(self.model)
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
        mujoco.mj_step(self.model, self.data)
        self._publish()

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
