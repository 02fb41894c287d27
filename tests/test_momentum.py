"""The momentum observer against a case solved by hand: a single pendulum, integrated here without MuJoCo."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from hild.dynamics.momentum import MomentumObserver

MASS, LENGTH, G = 2.0, 0.5, 9.81
INERTIA = MASS * LENGTH**2 + 1e-3  # point mass at LENGTH plus the body's own I_yy
PENDULUM = f"""
<mujoco model="pendulum">
  <option gravity="0 0 -{G}"/>
  <worldbody>
    <body name="link">
      <joint name="swing" type="hinge" axis="0 1 0"/>
      <inertial pos="{LENGTH} 0 0" mass="{MASS}" diaginertia="1e-3 1e-3 1e-3"/>
    </body>
  </worldbody>
</mujoco>
"""
PERIOD = 0.002
GAIN = 100.0


def accel(q: float, qd: float, tau: float) -> float:
    """Rotating (LENGTH, 0, 0) about +y by q lowers it to z = −LENGTH·sin q: gravity's torque is m·g·l·cos q."""
    return (tau + MASS * G * LENGTH * math.cos(q)) / INERTIA


def rk4(q: float, qd: float, tau: float, dt: float) -> tuple[float, float]:
    k1 = (qd, accel(q, qd, tau))
    k2 = (qd + 0.5 * dt * k1[1], accel(q + 0.5 * dt * k1[0], qd + 0.5 * dt * k1[1], tau))
    k3 = (qd + 0.5 * dt * k2[1], accel(q + 0.5 * dt * k2[0], qd + 0.5 * dt * k2[1], tau))
    k4 = (qd + dt * k3[1], accel(q + dt * k3[0], qd + dt * k3[1], tau))
    q += dt / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
    qd += dt / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
    return q, qd


def swing(q: float, qd: float, tau: float, period: float = PERIOD, substeps: int = 40) -> tuple[float, float]:
    for _ in range(substeps):
        q, qd = rk4(q, qd, tau, period / substeps)
    return q, qd


@pytest.fixture(params=[True, False], ids=["compiled", "python"])
def observer(tmp_path: Path, request: pytest.FixtureRequest) -> MomentumObserver:
    """Each case on both updates: the compiled one (hild/dynamics/_momentum.c) and the Python path."""
    path = tmp_path / "pendulum.xml"
    path.write_text(PENDULUM)
    built = MomentumObserver(path, ["swing"], GAIN, PERIOD, compiled=request.param)
    assert built.implementation.startswith("compiled" if request.param else "python")
    return built


def test_its_mass_matrix_and_momentum_are_the_pendulums(observer: MomentumObserver) -> None:
    observer.reset(np.array([0.3]), np.array([2.0]))
    assert observer.momentum[0] == pytest.approx(INERTIA * 2.0, rel=1e-9)


def test_a_free_swing_under_a_motor_torque_reads_no_external_torque(observer: MomentumObserver) -> None:
    q, qd, motor = 0.2, 0.0, 1.5  # released near the horizontal: gravity swings it through ±1 rad at ~4 rad/s
    observer.reset(np.array([q]), np.array([qd]))
    worst = fastest = 0.0
    for _ in range(2000):  # 4 s: several swings
        q, qd = swing(q, qd, motor)
        r = observer.update(np.array([q]), np.array([qd]), np.array([motor]), PERIOD)
        worst, fastest = max(worst, abs(r[0])), max(fastest, abs(qd))
    assert fastest > 3.0  # it really swung
    assert worst < 2e-3 * MASS * G * LENGTH  # under 0.2 % of the gravity torque


def test_a_step_of_external_torque_is_followed_as_the_discrete_first_order_filter(observer: MomentumObserver) -> None:
    q, qd, motor, external = -0.4, 1.0, 0.0, 0.8
    observer.reset(np.array([q]), np.array([qd]))
    for _ in range(100):
        q, qd = swing(q, qd, motor)
        observer.update(np.array([q]), np.array([qd]), np.array([motor]), PERIOD)
    seen = []
    for _ in range(60):  # the external torque acts from here on; the observer is told only the motor's
        q, qd = swing(q, qd, motor + external)
        seen.append(observer.update(np.array([q]), np.array([qd]), np.array([motor]), PERIOD)[0])
    # e_k = (1 − K·dt)·e_{k−1} + τ_ext·dt, so r_k = τ_ext·(1 − (1 − K·dt)^k)
    expected = [external * (1.0 - (1.0 - GAIN * PERIOD) ** k) for k in range(1, 61)]
    assert np.allclose(seen, expected, atol=0.01 * external)
    assert seen[-1] == pytest.approx(external, rel=0.01)


def test_a_gain_the_discrete_observer_cannot_run_at_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "pendulum.xml"
    path.write_text(PENDULUM)
    with pytest.raises(ValueError, match="gain below 500/s"):
        MomentumObserver(path, ["swing"], 600.0, PERIOD)
    with pytest.raises(ValueError, match="joints not in the model: elbow"):
        MomentumObserver(path, ["elbow"], GAIN, PERIOD)


def test_update_allocates_nothing(observer: MomentumObserver) -> None:
    import tracemalloc

    q, qd, tau = np.array([0.1]), np.array([0.5]), np.array([0.2])
    observer.reset(q, qd)
    observer.update(q, qd, tau, PERIOD)
    tracemalloc.start()
    try:
        for _ in range(200):  # numpy's and the bindings' own caches settle
            observer.update(q, qd, tau, PERIOD)
        start, _ = tracemalloc.get_traced_memory()
        tracemalloc.reset_peak()
        for _ in range(2000):
            observer.update(q, qd, tau, PERIOD)
        end, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert end - start < 1024  # nothing kept per update (2000 updates: a byte each would show)
    assert peak - start < 2048  # only call overhead in flight (keyword dicts), never a result array per step


def test_on_a_six_joint_arm_whose_mass_matrix_changes_it_reads_only_the_torque_it_was_not_told() -> None:
    """arm6 (M(q) changes along the motion, damping, armature) integrated by MuJoCo itself at 0.1 ms: the torque
    told explains the motion (r stays near 0), then an untold constant torque on the elbow is what r reads."""
    import mujoco

    from tests.conftest import CONFIGS

    joints = ["shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3"]
    plant = mujoco.MjModel.from_xml_path(str(CONFIGS / "arm6.xml"))
    plant.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4
    plant.opt.timestep = 1e-4
    plant.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)
    data = mujoco.MjData(plant)
    observer = MomentumObserver(CONFIGS / "arm6.xml", joints, 150.0, 0.001)
    rng = np.random.default_rng(2)
    observer.reset(data.qpos.copy(), data.qvel.copy())
    worst, fastest, external = 0.0, 0.0, np.array([0.0, 0.0, 4.0, 0.0, 0.0, 0.0])
    for k in range(1000):  # 1 s at 1 kHz
        mujoco.mj_forward(plant, data)
        tau = data.qfrc_bias + rng.normal(0.0, 5.0, 6)  # about gravity: it swings, never falls far
        data.qfrc_applied[:] = tau + (external if k >= 700 else 0.0)
        for _ in range(10):
            mujoco.mj_step(plant, data)
        r = observer.update(data.qpos.copy(), data.qvel.copy(), tau, 0.001)
        if k < 700:
            worst, fastest = max(worst, float(np.abs(r).max())), max(fastest, float(np.abs(data.qvel).max()))
    assert fastest > 0.5  # it really moved
    assert worst < 0.05  # N·m, against ~50 N·m of gravity on shoulder_lift
    assert np.allclose(r, external, atol=0.05)  # 300 ms after the step: e^(−45) of it left to follow


def test_the_stages_it_runs_give_the_figures_of_the_full_forward_pass_to_the_bit() -> None:
    """On arm6 (no tendon, no flex) the observer runs only the stages it reads; the residual must be the one the two
    full calls (mj_fwdPosition, mj_fwdVelocity) give, exactly."""
    from tests.conftest import CONFIGS

    joints = ["shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3"]
    staged = MomentumObserver(CONFIGS / "arm6.xml", joints, 150.0, 0.001, compiled=False)
    full = MomentumObserver(CONFIGS / "arm6.xml", joints, 150.0, 0.001, compiled=False)
    assert staged._staged
    full._staged = False
    rng = np.random.default_rng(5)
    q, qd = rng.uniform(-2.0, 2.0, 6), rng.normal(0.0, 2.0, 6)
    for o in (staged, full):
        o.reset(q, qd)
    for _ in range(50):
        q, qd, tau = q + 0.001 * qd, qd + rng.normal(0.0, 0.5, 6), rng.normal(0.0, 10.0, 6)
        assert staged.update(q, qd, tau, 0.001).tolist() == full.update(q, qd, tau, 0.001).tolist()
