"""``hild check``: would stopping the daemon drop a gravity-loaded joint?

With ``safety.stop_descent`` at 0, stopping releases the drives after one hold cycle; drives that go limp when
deactivated (``on_deactivate: disable`` / ``idle``, the twin, the mock) then drop every joint that carries weight
unless it has a brake. A joint is gravity-loaded when the gravity torque the robot's model gives it exceeds
``LOADED_SHARE`` of its effort limit at some pose inside its limits (the zero pose clamped to the limits, and a few
fixed samples). Only ``hild check`` runs this: it loads the model, which every ``load_config`` should not pay for.
"""

from __future__ import annotations

import numpy as np

from hild.config.loader import LoadedConfig

LOADED_SHARE = 0.02
SAMPLE_POSES = 16


def limp_at_stop(loaded: LoadedConfig) -> list[str]:
    """Warnings naming each gravity-loaded joint that would go limp at stop, with its torque and the fix."""
    cfg = loaded.config
    if cfg.robot.model is None or cfg.safety.stop_descent > 0.0:
        return []
    limp = [
        joint
        for name, hw in cfg.hardware.items()
        if not loaded.driver_classes[name].holds_at_stop(loaded.driver_params[name])
        for joint in hw.joints
    ]
    if not limp:
        return []
    from hild.dynamics import GravityModel  # mujoco stays behind this seam

    joints = list(cfg.joints)
    model = GravityModel(loaded.directory / cfg.robot.model, joints)
    lower = np.array([cfg.joints[j].limits.position.lower for j in joints])
    upper = np.array([cfg.joints[j].limits.position.upper for j in joints])
    poses = [np.clip(np.zeros(len(joints)), lower, upper)]
    rng = np.random.default_rng(0)
    poses += [rng.uniform(lower, upper) for _ in range(SAMPLE_POSES)]
    worst = np.zeros(len(joints))
    torque = np.zeros(len(joints))
    for pose in poses:
        model.compute(pose, torque)
        np.maximum(worst, np.abs(torque), out=worst)
    loaded_joints = [
        f"{joint} (up to {worst[i]:.3g} N·m)"
        for i, joint in enumerate(joints)
        if joint in limp and worst[i] > LOADED_SHARE * cfg.joints[joint].limits.effort
    ]
    if not loaded_joints:
        return []
    return [
        f"warning: stopping releases gravity-loaded joints limp: {', '.join(loaded_joints)}; an unbraked arm falls. "
        "Set safety.stop_descent (e.g. 2.0 s: damped, gravity fading out) or on_deactivate: hold"
    ]
