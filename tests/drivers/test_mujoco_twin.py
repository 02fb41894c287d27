"""The MuJoCo twin behind the hardware contract, in lockstep: read/write are called directly, nothing sleeps."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from drivers.mujoco import MujocoTwin
from hild.arrays import JointState, ServoCommand
from hild.dynamics.gravity import GravityModel
from hild.hardware import ALL_COMMAND_FIELDS, HardwareContext, HardwareError

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
ARM6_JOINTS = ("shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3")
HOME = np.array([0.0, 1.0, -1.6, -0.9708, 1.5708, 0.0])
ARM6_LIMITS = np.array([150.0, 150.0, 150.0, 28.0, 28.0, 28.0])
HOLD_KP = np.array([300.0, 300.0, 300.0, 50.0, 50.0, 50.0])
HOLD_KD = np.array([20.0, 20.0, 20.0, 4.0, 4.0, 4.0])
RATE = 500.0


def make_twin(
    joints: tuple[str, ...] = ARM6_JOINTS,
    *,
    rate: float = RATE,
    config_dir: Path = CONFIGS,
    events: list[tuple[str, str]] | None = None,
    **params: object,
) -> MujocoTwin:
    sink = events if events is not None else []
    context = HardwareContext(
        name="twin",
        joints=joints,
        config_dir=config_dir,
        update_rate=rate,
        clock_source="sim",
        emit_event=lambda level, msg: sink.append((level, msg)),
    )
    params.setdefault("model", "arm6.xml")
    if params["model"] == "arm6.xml":
        params.setdefault("keyframe", "home")
    return MujocoTwin(context, MujocoTwin.Params(**params))


def start(twin: MujocoTwin) -> tuple[JointState, ServoCommand]:
    """The engine's order: configure → read → activate."""
    n = len(twin.joints)
    state, command = JointState.zeros(n), ServoCommand.zeros(n)
    twin.on_configure()
    twin.read(0.0, 1.0 / RATE, state)
    twin.on_activate()
    return state, command


def cycle(twin: MujocoTwin, state: JointState, command: ServoCommand) -> None:
    """One lockstep cycle as the engine runs it after start-up: write, then read the result."""
    twin.write(0.0, 0.0, command)
    twin.read(0.0, 0.0, state)


def hold(command: ServoCommand, position: np.ndarray, kp: np.ndarray = HOLD_KP, kd: np.ndarray = HOLD_KD) -> None:
    command.position[:] = position
    command.velocity[:] = 0.0
    command.effort[:] = 0.0
    command.kp[:] = kp
    command.kd[:] = kd


# ---------------------------------------------------------------------------------------------- start-up


def test_start_pose_from_keyframe_and_state_fields() -> None:
    twin = make_twin()
    state, _ = start(twin)
    np.testing.assert_allclose(state.position, HOME)
    assert np.all(state.velocity == 0.0)
    assert np.all(state.effort == 0.0)
    assert np.all(np.isnan(state.temperature))
    assert np.all(state.fault == 0)
    assert np.all(state.fresh)
    assert twin.sim_time == 0.0
    assert twin.health() is None
    assert MujocoTwin.COMMAND_FIELDS == ALL_COMMAND_FIELDS


def test_start_pose_defaults_to_qpos0_and_initial_positions_override() -> None:
    state, _ = start(make_twin(keyframe=None))
    np.testing.assert_array_equal(state.position, np.zeros(6))
    state, _ = start(make_twin(initial_positions={"elbow": -1.0, "wrist_3": 0.5}))
    np.testing.assert_allclose(state.position, [0.0, 1.0, -1.0, -0.9708, 1.5708, 0.5])


def test_plugin_is_registered() -> None:
    from hild.plugins import DRIVERS, load

    assert load(DRIVERS, "mujoco") is MujocoTwin


# ---------------------------------------------------------------------------------------------- gravity and hold


def test_hold_with_gravity_feedforward_stays_within_1_mrad_for_10_s() -> None:
    twin = make_twin()
    state, command = start(twin)
    start_pose = state.position.copy()
    gravity = GravityModel(CONFIGS / "arm6.xml", ARM6_JOINTS)
    hold(command, start_pose)
    worst = np.zeros(6)
    for _ in range(5000):
        gravity.compute(state.position, command.effort)
        cycle(twin, state, command)
        np.maximum(worst, np.abs(state.position - start_pose), out=worst)
    assert twin.sim_time == pytest.approx(10.0, abs=1e-9)
    assert np.all(worst < 1e-3), worst
    # The drives really carry the arm: shoulder_lift and elbow hold tens of N·m.
    assert state.effort[1] > 20.0
    assert state.effort[2] > 5.0


def test_feedforward_removes_the_steady_state_sag_after_a_move() -> None:
    """Settle on a target 0.1 rad away: with feed-forward the P error vanishes, without it gravity/kp remains."""
    gravity = GravityModel(CONFIGS / "arm6.xml", ARM6_JOINTS)
    target = HOME + np.array([0.1, -0.1, 0.1, 0.1, -0.1, 0.1])
    errors = {}
    for feedforward in (True, False):
        twin = make_twin()
        state, command = start(twin)
        hold(command, target)
        for _ in range(2500):
            if feedforward:
                gravity.compute(state.position, command.effort)
            cycle(twin, state, command)
        errors[feedforward] = np.abs(state.position - target)
    assert np.all(errors[True] < 1e-3), errors[True]
    assert errors[False][1] > 0.05  # shoulder_lift sags by about τ_gravity / kp ≈ 32 / 300


def test_without_feedforward_or_gains_the_arm_falls() -> None:
    twin = make_twin()
    state, command = start(twin)  # zero command: kp = kd = effort = 0
    start_pose = state.position.copy()
    for _ in range(250):  # 0.5 s
        cycle(twin, state, command)
    assert state.position[1] < start_pose[1] - 0.5  # the upper arm dropped by more than 0.5 rad
    assert abs(state.position[2] - start_pose[2]) > 0.1
    assert np.all(state.effort == 0.0)


def test_gravity_can_be_switched_off() -> None:
    twin = make_twin(gravity=False)
    state, command = start(twin)
    for _ in range(250):
        cycle(twin, state, command)
    np.testing.assert_array_equal(state.position, HOME)


# ---------------------------------------------------------------------------------------------- drive behaviour


def test_servo_law_effort_reports_the_applied_torque() -> None:
    twin = make_twin(gravity=False)
    state, command = start(twin)
    command.position[:] = HOME + 0.01
    command.velocity[:] = 0.5
    command.effort[:] = 1.0
    command.kp[:] = 100.0
    command.kd[:] = 2.0
    twin.write(0.0, 0.0, command)
    twin.read(0.0, 0.0, state)
    # One substep from rest at HOME: τ = 100·0.01 + 2·0.5 + 1 = 3 N·m on every joint.
    np.testing.assert_allclose(state.effort, 3.0, rtol=1e-9)
    assert np.all(state.velocity > 0.0)


def test_huge_command_saturates_at_the_torque_limit() -> None:
    twin = make_twin()
    state, command = start(twin)
    command.effort[:] = [1e6, -1e6, 1e6, -1e6, 1e6, -1e6]
    cycle(twin, state, command)
    np.testing.assert_array_equal(np.abs(state.effort), ARM6_LIMITS)
    np.testing.assert_array_equal(np.sign(state.effort), np.sign(command.effort))
    # A huge position error saturates the same way.
    command.effort[:] = 0.0
    command.position[:] = state.position - 100.0
    command.kp[:] = 1e4
    cycle(twin, state, command)
    np.testing.assert_array_equal(state.effort, -ARM6_LIMITS)


def test_torque_limits_param_overrides_the_model() -> None:
    twin = make_twin(torque_limits={"elbow": 40.0})
    state, command = start(twin)
    command.effort[:] = -1e6
    cycle(twin, state, command)
    np.testing.assert_array_equal(state.effort, [-150.0, -150.0, -40.0, -28.0, -28.0, -28.0])


@pytest.mark.filterwarnings("ignore:invalid value:RuntimeWarning")
def test_non_finite_command_applies_no_torque() -> None:
    twin = make_twin(gravity=False)
    state, command = start(twin)
    command.position[2] = math.inf  # kp = 0 here, so 0·inf = nan
    command.effort[3] = math.nan
    cycle(twin, state, command)
    assert np.all(np.isfinite(state.position))
    np.testing.assert_array_equal(state.effort, 0.0)
    np.testing.assert_array_equal(state.position, HOME)


@pytest.mark.parametrize("latency", [0, 1, 3])
def test_command_latency_delays_an_effort_step_by_exactly_n_cycles(latency: int) -> None:
    twin = make_twin(gravity=False, command_latency_cycles=latency)
    state, command = start(twin)
    step_at = 5
    moved_at = None
    for k in range(step_at + latency + 3):
        command.effort[:] = 1.0 if k >= step_at else 0.0
        cycle(twin, state, command)
        if moved_at is None and np.any(state.velocity != 0.0):
            moved_at = k
            assert np.all(state.velocity > 0.0)
            np.testing.assert_allclose(state.effort, 1.0)
    assert moved_at == step_at + latency


def test_latency_ring_is_cleared_on_reactivation() -> None:
    twin = make_twin(gravity=False, command_latency_cycles=2)
    state, command = start(twin)
    command.effort[:] = 1.0
    cycle(twin, state, command)  # queued, not applied yet
    twin.on_deactivate()
    twin.reset()
    twin.on_activate()
    command.effort[:] = 0.0
    for _ in range(4):
        cycle(twin, state, command)
    np.testing.assert_array_equal(state.position, HOME)  # the stale queued command never came out


def test_zero_torque_before_activate_and_after_deactivate() -> None:
    reference = make_twin()
    ref_state, idle = start(reference)  # active, zero command
    disabled = make_twin()
    state = JointState.zeros(6)
    disabled.on_configure()
    disabled.read(0.0, 0.0, state)
    push = ServoCommand.zeros(6)
    push.effort[:] = 20.0
    for _ in range(50):
        cycle(disabled, state, push)
        cycle(reference, ref_state, idle)
    np.testing.assert_array_equal(state.effort, 0.0)
    np.testing.assert_array_equal(state.position, ref_state.position)  # falls exactly as with zero torque

    disabled.on_activate()
    cycle(disabled, state, push)
    assert np.all(state.effort == 20.0)
    disabled.on_deactivate()
    disabled.read(0.0, 0.0, state)
    np.testing.assert_array_equal(state.effort, 0.0)
    cycle(disabled, state, push)
    np.testing.assert_array_equal(state.effort, 0.0)


def test_friction_armature_damping_overrides() -> None:
    twin = make_twin(friction={"elbow": 3.0}, armature={"wrist_1": 0.7}, damping={"shoulder_pan": 2.5})
    start(twin)
    model = twin.model
    assert model.dof_frictionloss[model.joint("elbow").dofadr[0]] == 3.0
    assert model.dof_armature[model.joint("wrist_1").dofadr[0]] == 0.7
    assert model.dof_damping[model.joint("shoulder_pan").dofadr[0]] == 2.5

    # Behaviour: Coulomb friction well above the gravity load keeps the unpowered arm (nearly) in place.
    sticky = make_twin(friction=dict.fromkeys(ARM6_JOINTS[:3], 100.0) | dict.fromkeys(ARM6_JOINTS[3:], 20.0))
    state, command = start(sticky)
    for _ in range(250):
        cycle(sticky, state, command)
    assert np.max(np.abs(state.position - HOME)) < 0.05  # without friction it falls > 1 rad (test above)


# ---------------------------------------------------------------------------------------------- clock


@pytest.mark.parametrize(("rate", "substeps"), [(500.0, 1), (500.0, 2), (1000.0, 1), (1000.0, 5)])
def test_substeps_set_the_timestep_and_each_write_advances_one_period(rate: float, substeps: int) -> None:
    twin = make_twin(rate=rate, substeps=substeps)
    state, command = start(twin)
    assert twin.model.opt.timestep == pytest.approx(1.0 / rate / substeps, rel=1e-12)
    for k in range(1, 101):
        cycle(twin, state, command)
        assert twin.sim_time == pytest.approx(k / rate, abs=1e-12)


def test_substeps_evaluate_the_drive_law_inside_each_step() -> None:
    """A stiff servo (explicit PD with kd·dt/I > 2 on the light wrists) chatters between its torque limits at one
    law evaluation per 2 ms cycle, and settles when the law runs in each of 4 substeps, as a real drive's faster
    inner loop does."""
    kp, kd = np.full(6, 3000.0), np.full(6, 300.0)
    target = HOME + 0.01
    chatter = {}
    for substeps in (1, 4):
        twin = make_twin(substeps=substeps, gravity=False)
        state, command = start(twin)
        hold(command, target, kp, kd)
        efforts = []
        for _ in range(500):
            cycle(twin, state, command)
            efforts.append(state.effort[5])
        last = np.array(efforts[-50:])
        chatter[substeps] = last.max() - last.min()
        if substeps == 4:
            np.testing.assert_allclose(state.position, target, atol=1e-5)
    assert chatter[4] < 1e-3
    assert chatter[1] > 50.0  # flips between -28 and +28 N·m every cycle


def test_reset_returns_to_the_start_pose_at_time_zero() -> None:
    twin = make_twin()
    state, command = start(twin)
    for _ in range(100):
        cycle(twin, state, command)
    assert not np.allclose(state.position, HOME)
    twin.reset()
    twin.read(0.0, 0.0, state)
    np.testing.assert_allclose(state.position, HOME)
    assert np.all(state.velocity == 0.0)
    assert twin.sim_time == 0.0


def test_divergence_is_reported_by_health_until_reset(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)  # MuJoCo appends its warning to MUJOCO_LOG.TXT in the working directory
    twin = make_twin(gravity=False, torque_limits=dict.fromkeys(ARM6_JOINTS, 1e12))
    state, command = start(twin)
    hold(command, HOME + 0.5, np.full(6, 1e9), np.full(6, 1e7))  # absurd gains: the explicit PD explodes
    for _ in range(20):
        cycle(twin, state, command)
    assert twin.health() is not None
    assert "diverged" in twin.health()
    twin.reset()
    assert twin.health() is None


def test_lockstep_is_deterministic() -> None:
    runs = []
    for _ in range(2):
        twin = make_twin(substeps=2, command_latency_cycles=1)
        state, command = start(twin)
        hold(command, HOME + 0.2)
        trace = []
        for _ in range(300):
            cycle(twin, state, command)
            trace.append(state.position.copy())
        runs.append(np.array(trace))
    np.testing.assert_array_equal(runs[0], runs[1])


# ---------------------------------------------------------------------------------------------- joint mapping


def test_joints_map_by_name_in_any_order() -> None:
    joints = tuple(reversed(ARM6_JOINTS))
    twin = make_twin(joints=joints)
    state, command = start(twin)
    np.testing.assert_allclose(state.position, HOME[::-1])
    command.effort[:] = -1e6
    cycle(twin, state, command)
    np.testing.assert_array_equal(state.effort, -ARM6_LIMITS[::-1])

    # And a hold with feed-forward in that order works as well.
    twin = make_twin(joints=joints)
    state, command = start(twin)
    gravity = GravityModel(CONFIGS / "arm6.xml", joints)
    hold(command, HOME[::-1], HOLD_KP[::-1], HOLD_KD[::-1])
    for _ in range(500):
        gravity.compute(state.position, command.effort)
        cycle(twin, state, command)
    np.testing.assert_allclose(state.position, HOME[::-1], atol=1e-3)


def test_subset_of_joints_warns_that_the_others_are_passive() -> None:
    events: list[tuple[str, str]] = []
    twin = make_twin(joints=ARM6_JOINTS[:3], events=events)
    start(twin)
    assert events and events[0][0] == "warning"
    assert "wrist_1" in events[0][1]


def test_model_actuators_are_reported_as_unused(tmp_path: Path) -> None:
    (tmp_path / "with_motor.xml").write_text(
        """<mujoco><worldbody><body name="link"><joint name="hinge_a" axis="0 1 0" actuatorfrcrange="-5 5"/>
        <geom type="capsule" fromto="0 0 0 0.5 0 0" size="0.05"/></body></worldbody>
        <actuator><motor joint="hinge_a"/></actuator></mujoco>"""
    )
    events: list[tuple[str, str]] = []
    start(make_twin(joints=("hinge_a",), config_dir=tmp_path, model="with_motor.xml", events=events))
    assert any(level == "warning" and "<actuator>" in msg for level, msg in events)


def test_joint_name_mismatch_lists_both_sets() -> None:
    joints = ("shoulder_pan", "shoulder_lift", "elbo", "wrist_1", "wrist_2", "wrist_3")
    with pytest.raises(HardwareError) as info:
        make_twin(joints=joints).on_configure()
    message = str(info.value)
    assert "elbo" in message
    assert "elbow" in message  # the model's names
    assert "configured joints: shoulder_pan, shoulder_lift, elbo" in message


def test_missing_torque_limit_names_the_joint(tmp_path: Path) -> None:
    (tmp_path / "bare.xml").write_text(
        """<mujoco><worldbody><body name="link"><joint name="hinge_a" axis="0 1 0"/>
        <geom type="capsule" fromto="0 0 0 0.5 0 0" size="0.05"/></body></worldbody></mujoco>"""
    )
    with pytest.raises(HardwareError, match=r"no torque limit for joint hinge_a"):
        make_twin(joints=("hinge_a",), config_dir=tmp_path, model="bare.xml").on_configure()
    twin = make_twin(joints=("hinge_a",), config_dir=tmp_path, model="bare.xml", torque_limits={"hinge_a": 5.0})
    state, command = start(twin)
    command.effort[:] = 100.0
    cycle(twin, state, command)
    assert state.effort[0] == 5.0


@pytest.mark.parametrize("table", ["friction", "armature", "damping", "torque_limits", "initial_positions"])
def test_unknown_joint_in_a_param_table_is_an_error(table: str) -> None:
    with pytest.raises(HardwareError, match=rf"params\.{table} names unknown joints \['elbw'\]"):
        make_twin(**{table: {"elbw": 1.0}}).on_configure()


def test_bad_model_keyframe_and_start_position_are_clear_errors() -> None:
    with pytest.raises(HardwareError, match=r"missing\.xml"):
        make_twin(model="missing.xml").on_configure()
    with pytest.raises(HardwareError, match=r"no keyframe 'park'.*home"):
        make_twin(keyframe="park").on_configure()
    with pytest.raises(HardwareError, match=r"initial position 4\.0 of elbow is outside"):
        make_twin(initial_positions={"elbow": 4.0}).on_configure()


def test_params_are_strict() -> None:
    with pytest.raises(ValueError):
        MujocoTwin.Params(model="arm6.xml", substep=2)  # typo: unknown key
    with pytest.raises(ValueError):
        MujocoTwin.Params(model="arm6.xml", substeps=0)
    with pytest.raises(ValueError):
        MujocoTwin.Params(model="arm6.xml", torque_limits={"elbow": -1.0})


# ---------------------------------------------------------------------------------------------- rrbot (URDF)


def test_rrbot_urdf_keeps_joint_names_and_effort_limits() -> None:
    twin = make_twin(joints=("joint1", "joint2"), model="rrbot.urdf", initial_positions={"joint1": 0.6})
    state, command = start(twin)
    assert [twin.model.joint(i).name for i in range(twin.model.njnt)] == ["joint1", "joint2"]
    np.testing.assert_allclose(state.position, [0.6, 0.0])

    gravity = GravityModel(CONFIGS / "rrbot.urdf", ("joint1", "joint2"))
    hold(command, state.position.copy(), np.array([200.0, 100.0]), np.array([20.0, 10.0]))
    for _ in range(500):
        gravity.compute(state.position, command.effort)
        cycle(twin, state, command)
    np.testing.assert_allclose(state.position, [0.6, 0.0], atol=1e-3)
    assert state.effort[0] < -5.0  # holding the links up against gravity

    command.effort[:] = 1e6
    command.kp[:] = 0.0
    cycle(twin, state, command)
    np.testing.assert_array_equal(state.effort, [30.0, 30.0])  # <limit effort="30">


def test_a_twin_whose_configure_failed_can_still_be_deactivated_and_cleaned_up() -> None:
    twin = make_twin(model="missing.xml")
    with pytest.raises(HardwareError):
        twin.on_configure()
    twin.on_deactivate()  # the engine's release path after a failed start
    twin.on_cleanup()
    assert twin.data is None


def test_excluded_contacts_are_ignored_and_unknown_bodies_refused(tmp_path: Path) -> None:
    """A link sitting 1 cm into its world-welded parent: MuJoCo pushes it out unless the pair is excluded."""
    (tmp_path / "overlap.xml").write_text(
        """<mujoco><worldbody><body name="base"><geom type="box" size="0.1 0.1 0.1"/>
        <body name="arm" pos="0 0 0.15"><joint name="lift" type="slide" axis="0 0 1" actuatorfrcrange="-50 50"/>
        <geom type="box" size="0.05 0.05 0.06" mass="1"/></body></body></worldbody>
        <option gravity="0 0 0"/></mujoco>"""
    )
    for exclude, pushed in (([], True), ([("base", "arm")], False)):
        twin = make_twin(joints=("lift",), config_dir=tmp_path, model="overlap.xml", exclude_contacts=exclude)
        state, command = start(twin)
        for _ in range(50):
            cycle(twin, state, command)
        assert (state.position[0] > 1e-3) == pushed
    with pytest.raises(HardwareError, match=r"exclude_contacts names bodies it does not have: nope"):
        make_twin(
            joints=("lift",), config_dir=tmp_path, model="overlap.xml", exclude_contacts=[("arm", "nope")]
        ).on_configure()
