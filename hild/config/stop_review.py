"""``hild check`` with the robot's model loaded: would the daemon fail on it, and would stopping drop the arm?

Only ``hild check`` runs this, because it loads the model through MuJoCo (``hild.dynamics``), which every
``load_config`` should not pay for. Two findings:

- The model must load and have every configured joint (an error): the daemon builds its gravity feed-forward from
  it and refuses to start otherwise, so a config that passes ``check`` must not fail ``run`` on it.
- With ``safety.stop_descent`` at 0, stopping releases the drives after one hold cycle; drives that go limp when
  deactivated (``on_deactivate: disable`` / ``idle``, the twin, the mock) then drop every joint that carries
  weight unless it has a brake (a warning). A joint is gravity-loaded when the gravity torque the model gives it
  exceeds ``LOADED_SHARE`` of its effort limit at some pose inside its limits: the zero pose clamped to the limits
  and ``SAMPLE_POSES`` fixed samples (a seeded generator: the verdict never changes between two runs).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hild.config.loader import ConfigError, LoadedConfig
from hild.config.safety import SafetyFinding
from hild.config.walls_review import review_walls

LOADED_SHARE = 0.02
SAMPLE_POSES = 16
SUGGESTED_DESCENT = 2.0  # s: what the shipped CAN configs use


def check_with_model(loaded: LoadedConfig) -> None:
    """Raise ``ConfigError`` on errors; add warnings to ``loaded.notes`` (printed by ``summary``)."""
    findings = review_model(loaded) + review_walls(loaded)
    errors = [loaded.issue(f.loc, f.message) for f in findings if f.level == "error"]
    if errors:
        raise ConfigError(errors)
    loaded.notes += [f"warning: {loaded.issue(f.loc, f.message)}" for f in findings]


def review_model(loaded: LoadedConfig) -> list[SafetyFinding]:
    """The model loads with the config's joints; no gravity-loaded joint goes limp at stop."""
    cfg = loaded.config
    if cfg.robot.model is None:
        return []
    from hild.dynamics.gravity import GravityModel  # mujoco stays behind this seam

    joints = list(cfg.joints)
    try:
        model = GravityModel(loaded.directory / cfg.robot.model, joints)
    except ValueError as exc:  # what the daemon would refuse to start with
        return [SafetyFinding("error", ("robot", "model"), str(exc))]
    if cfg.safety.stop_descent > 0.0:
        return []
    limp = {
        joint: name
        for name, hw in cfg.hardware.items()
        if not loaded.driver_classes[name].holds_at_stop(loaded.driver_params[name])
        for joint in hw.joints
    }
    worst = _worst_gravity(model, loaded)
    dropped = [
        f"{joint} (up to {worst[i]:.3g} N·m, effort limit {cfg.joints[joint].limits.effort:g})"
        for i, joint in enumerate(joints)
        if joint in limp and worst[i] > LOADED_SHARE * cfg.joints[joint].limits.effort
    ]
    if not dropped:
        return []
    fixes = [f"set safety.stop_descent (e.g. {SUGGESTED_DESCENT:.1f} s: a damped descent, gravity fading out)"]
    can_hold = sorted({name for name in limp.values() if hasattr(loaded.driver_params[name], "on_deactivate")})
    if can_hold:
        fixes.append(f"on_deactivate: hold on hardware {', '.join(can_hold)} (the drives stay enabled)")
    return [
        SafetyFinding(
            "warning",
            ("safety", "stop_descent"),
            f"0 s, so stopping releases gravity-loaded joints limp: {', '.join(dropped)}; an unbraked arm falls when "
            f"the daemon stops. Fix: {' or '.join(fixes)}",
        )
    ]


def _worst_gravity(model: Any, loaded: LoadedConfig) -> np.ndarray:
    """Per joint, the largest |gravity torque| over the sampled poses."""
    limits = [loaded.config.joints[j].limits.position for j in model.joint_names]
    # A joint without finite limits (allowed on simulated drives) is sampled over one turn.
    lower = np.nan_to_num(np.array([p.lower for p in limits], dtype=float), neginf=-np.pi)
    upper = np.nan_to_num(np.array([p.upper for p in limits], dtype=float), posinf=np.pi)
    rng = np.random.default_rng(0)
    poses = [np.clip(np.zeros(len(limits)), lower, upper)] + [rng.uniform(lower, upper) for _ in range(SAMPLE_POSES)]
    worst = np.zeros(len(limits))
    torque = np.zeros(len(limits))
    for pose in poses:
        model.compute(pose, torque)
        np.maximum(worst, np.abs(torque), out=worst)
    return worst
