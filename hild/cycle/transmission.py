"""Transmissions: the one place joint space and actuator space meet (docs/architecture.md, "The servo command").

``q_joint = direction · q_actuator / reduction + offset``; velocities scale like positions, efforts inversely,
and gains by ``1 / reduction²`` so the drive's torque law gives the same joint torque. Drivers only ever see
actuator space; controllers and the supervisor only ever see joint space.
"""

from __future__ import annotations

import numpy as np

from hild.arrays import JointState, ServoCommand


class Transmissions:
    def __init__(self, reduction: np.ndarray, direction: np.ndarray, offset: np.ndarray) -> None:
        self.reduction = np.asarray(reduction, dtype=float)
        self.direction = np.asarray(direction, dtype=float)
        self.offset = np.asarray(offset, dtype=float)
        self._pos_scale = self.direction / self.reduction  # actuator → joint, positions and velocities
        self._eff_scale = self.direction * self.reduction  # actuator → joint, efforts
        self._gain_scale = 1.0 / self.reduction**2  # joint → actuator, kp and kd
        self.identity = bool(
            np.all(self.reduction == 1.0) and np.all(self.direction == 1.0) and np.all(self.offset == 0.0)
        )

    def to_joint(self, actuator: JointState, joint: JointState) -> None:
        self.joint_positions(actuator.position, joint.position)
        self.joint_velocities(actuator.velocity, joint.velocity)
        self.joint_efforts(actuator.effort, joint.effort)
        np.copyto(joint.temperature, actuator.temperature)
        np.copyto(joint.fault, actuator.fault)
        np.copyto(joint.fresh, actuator.fresh)

    def to_actuator(self, joint: ServoCommand, actuator: ServoCommand) -> None:
        self.actuator_positions(joint.position, actuator.position)
        self.actuator_velocities(joint.velocity, actuator.velocity)
        np.divide(joint.effort, self._eff_scale, out=actuator.effort)
        np.multiply(joint.kp, self._gain_scale, out=actuator.kp)
        np.multiply(joint.kd, self._gain_scale, out=actuator.kd)
        np.copyto(actuator.written, joint.written)

    # ---- plain arrays (the emulator's MuJoCo plant maps its state with the same maths) --------------------------
    def joint_positions(self, actuator: np.ndarray, out: np.ndarray) -> None:
        np.multiply(actuator, self._pos_scale, out=out)
        np.add(out, self.offset, out=out)

    def actuator_positions(self, joint: np.ndarray, out: np.ndarray) -> None:
        np.subtract(joint, self.offset, out=out)
        np.divide(out, self._pos_scale, out=out)

    def joint_velocities(self, actuator: np.ndarray, out: np.ndarray) -> None:
        np.multiply(actuator, self._pos_scale, out=out)

    def actuator_velocities(self, joint: np.ndarray, out: np.ndarray) -> None:
        np.divide(joint, self._pos_scale, out=out)

    def joint_efforts(self, actuator: np.ndarray, out: np.ndarray) -> None:
        np.multiply(actuator, self._eff_scale, out=out)
