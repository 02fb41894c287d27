"""joint_impedance on the lockstep arm6 twin (configs/arm6_twin_impedance.yaml, the README's): ramped stiffness, a
limp joint an external push moves, streamed targets and their timeout, a chained joint_trajectory goal; and the
hild-side law on the effort path of an emulated ODrive, whose drive does not apply gains."""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np
import pytest

from hild.api.goals import GoalEndpoint
from hild.config import ConfigError, load_config
from hild.controllers.joint_impedance import JointImpedanceController, JointImpedanceParams
from hild.controllers.joint_trajectory import JointTrajectoryController
from hild.cycle.engine import Engine
from tests.conftest import CONFIGS
from tests.test_engine import JumpGuard, events
from tests.test_twin_engine import twin

CONFIG = "arm6_twin_impedance.yaml"
IMP, JTC = "joint_impedance", "joint_trajectory_compliant"
PAN = 0  # shoulder_pan: a vertical axis, no gravity load


def impedance(engine: Engine) -> JointImpedanceController:
    instance = engine.manager.records[IMP].instance
    assert isinstance(instance, JointImpedanceController)
    return instance


def started(*names: str) -> Engine:
    engine = twin(CONFIG)
    assert engine.switch(list(names) or [IMP], []).ok
    events(engine)
    return engine


def stream(engine: Engine, cycles: int, **target: Any) -> None:
    imp = impedance(engine)
    for _ in range(cycles):
        imp.accept({k: list(map(float, v)) for k, v in target.items()})
        engine.run_cycles(1)


def test_the_readme_config_loads_and_chains_the_trajectory_to_the_impedance() -> None:
    loaded = load_config(CONFIGS / CONFIG)
    assert loaded.config.controllers[JTC].chain_to == IMP
    assert "controller joint_trajectory_compliant: joint_trajectory, chained to joint_impedance" in loaded.summary()


def test_activation_is_bumpless_and_the_arm_holds_where_it_was() -> None:
    engine = twin(CONFIG)
    start = engine.state.position.copy()
    guard = JumpGuard(engine)
    assert engine.switch([IMP], []).ok
    guard.run(500)
    np.testing.assert_allclose(engine.state.position, start, atol=2e-3)
    np.testing.assert_allclose(engine.final.kp, [200, 200, 200, 30, 30, 30])  # ramped down from the hold gains


def test_a_stiffness_step_is_ramped_at_the_rate_limit_and_capped_at_the_maximum() -> None:
    engine = started()
    home = engine.state.position.copy()
    per_cycle = 2000.0 * engine.period  # stiffness_rate · dt
    seen = [float(engine.final.kp[PAN])]
    stiff = [600.0, 200, 200, 30, 30, 30]
    imp = impedance(engine)
    for _ in range(400):
        imp.accept({"positions": home.tolist(), "stiffness": stiff})
        engine.run_cycles(1)
        seen.append(float(engine.final.kp[PAN]))
    steps = np.diff(seen)
    assert steps.max() <= per_cycle + 1e-9 and steps.max() > 0.9 * per_cycle  # ramped, at the rate
    assert seen[-1] == 600.0
    with pytest.raises(ValueError, match="stiffness 601 for shoulder_pan is outside"):
        imp.accept({"positions": home.tolist(), "stiffness": [601.0, 200, 200, 30, 30, 30]})
    with pytest.raises(ValueError, match="damping -1 for shoulder_pan is outside"):
        imp.accept({"positions": home.tolist(), "damping": [-1.0, 2, 2, 2, 2, 2]})


def _push(engine: Engine, torque_z: float) -> None:
    """An external torque about the world's z axis on the first link (the pan axis): a hand turning the arm."""
    component = engine.hardware[0].component
    model, data = component.model, component.data  # type: ignore[attr-defined]
    body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, model.body(model.jnt_bodyid[0]).name)
    data.xfrc_applied[body, 5] = torque_z


def test_with_stiffness_zero_an_external_push_moves_the_joint_and_with_stiffness_it_does_not() -> None:
    moved = {}
    for k in (0.0, 600.0):
        engine = started()
        home = engine.state.position.copy()
        stiff = [k, 200, 200, 30, 30, 30]
        damp = [2.0, 20, 20, 2, 2, 2]
        stream(engine, 200, positions=home, stiffness=stiff, damping=damp)
        _push(engine, 5.0)
        stream(engine, 500, positions=home, stiffness=stiff, damping=damp)
        moved[k] = float(engine.state.position[PAN] - home[PAN])
    assert moved[0.0] > 0.3  # limp: 5 N·m against 2 N·m·s/rad of damping turns it on
    assert 0.0 < moved[600.0] < 0.02  # a spring of 600 N·m/rad: 5/600 rad


def test_streamed_targets_are_followed_then_held_compliantly_after_the_timeout() -> None:
    engine = started()
    home = engine.state.position.copy()
    target = home + np.array([0.3, -0.2, 0.2, 0.3, 0.3, 0.3])
    guard = JumpGuard(engine)
    imp = impedance(engine)
    for _ in range(1000):
        imp.accept({"positions": target.tolist(), "stiffness": [600.0, 600, 600, 100, 100, 100]})
        guard.run(1)
    np.testing.assert_allclose(engine.state.position, target, atol=0.02)
    assert not [e for e in events(engine) if "no target" in e]
    guard.run(int(0.5 * engine.update_rate) + 5)  # silence past command_timeout
    assert [e for e in events(engine) if "holding compliantly at the last one" in e]
    np.testing.assert_allclose(engine.final.position, target, atol=1e-9)  # the last target stays
    np.testing.assert_allclose(engine.final.velocity, 0.0)
    np.testing.assert_allclose(engine.final.kp, [600, 600, 600, 100, 100, 100])  # with the gains it had
    guard.run(500)
    np.testing.assert_allclose(engine.state.position, target, atol=0.02)


def test_bad_targets_are_refused_with_a_reason() -> None:
    engine = started()
    imp = impedance(engine)
    with pytest.raises(ValueError, match="expected an object"):
        imp.accept({"values": [0.0] * 6})
    with pytest.raises(ValueError, match="unknown keys"):
        imp.accept({"positions": [0.0] * 6, "gain": [1] * 6})
    with pytest.raises(ValueError, match="positions: expected 6 values"):
        imp.accept({"positions": [0.0] * 5})
    with pytest.raises(ValueError, match="must be finite"):
        imp.accept({"positions": [float("nan")] * 6})


def test_a_chained_trajectory_goal_succeeds_through_the_impedance_and_streams_are_refused_meanwhile() -> None:
    engine = started(IMP, JTC)
    assert [r.name for r in engine.manager.active].index(JTC) < [r.name for r in engine.manager.active].index(IMP)
    jtc = engine.manager.records[JTC].instance
    assert isinstance(jtc, JointTrajectoryController)
    home = engine.state.position.copy()
    goal = home + np.array([0.4, -0.3, 0.3, 0.3, -0.2, 0.5])
    endpoint = GoalEndpoint.of(jtc.action)
    reply = endpoint.submit({"positions": goal.tolist()})
    assert reply["ok"], reply
    with pytest.raises(ValueError, match="is chained"):
        impedance(engine).accept({"positions": home.tolist()})
    guard, result = JumpGuard(engine), None
    for _ in range(int(10 * engine.update_rate)):
        guard.run(1)
        if results := endpoint.collect():
            result = results[0]
            break
    assert result is not None and result.status == "succeeded", result
    np.testing.assert_allclose(engine.state.position, goal, atol=0.03)
    assert engine.status()["joints"][0]["owner"] == IMP  # the impedance commands the hardware; the supervisor last
    listed = {c["name"]: c for c in engine.status()["controllers"]}
    assert listed[IMP]["is_chainable"] and listed[IMP]["is_chained"]
    assert listed[JTC]["chain_connections"][0]["name"] == IMP
    assert "joint_impedance/shoulder_pan/position" in listed[JTC]["claimed"]


def test_stiffness_and_damping_params_are_checked() -> None:
    base = {"joints": ["a", "b"], "stiffness": [10, 10], "damping": [1, 1], "max_stiffness": [20, 20]}
    with pytest.raises(ValueError, match="max_damping"):
        JointImpedanceParams.model_validate(base)
    with pytest.raises(ValueError, match="stiffness of \\['b'\\] above max_stiffness"):
        JointImpedanceParams.model_validate({**base, "max_damping": [2, 2], "stiffness": [10, 30]})
    with pytest.raises(ValueError, match="not negative"):
        JointImpedanceParams.model_validate({**base, "max_damping": [2, 2], "damping": [-1, 1]})


# ---- a drive that does not apply gains: the law on the effort path ------------------------------------------------
def test_on_an_odrive_the_law_runs_in_hild_and_reaches_the_drive_as_torque() -> None:
    from tests.faults.rigs import CanRig

    rig = CanRig("odrive", 2)
    try:
        engine = rig.engine
        assert engine.applies_gains.tolist() == [False, False]
        params = {"joints": ["j1", "j2"], "stiffness": [2.0, 2.0], "damping": [0.05, 0.05]}
        params |= {"max_stiffness": [5.0, 5.0], "max_damping": [0.2, 0.2], "gravity_compensation": False}
        with pytest.raises(ValueError, match="list them in pd_on_effort"):
            JointImpedanceController(engine.controller_context("imp"), JointImpedanceParams.model_validate(params))
        params["pd_on_effort"] = ["j1", "j2"]
        imp = JointImpedanceController(engine.controller_context("imp"), JointImpedanceParams.model_validate(params))
        assert imp.claims() == ["j1/effort", "j2/effort"]
        engine.add_controller("imp", "joint_impedance", imp)
        assert engine.switch(["imp"], []).ok
        rig.seconds(0.05)
        home = engine.state.position.copy()
        target = home + np.array([0.1, 0.0])
        torques = []
        for _ in range(1500):
            imp.accept({"positions": target.tolist()})
            rig.cycle()
            torques.append(rig.firmware("j1").input_torque)
            q = float(engine.state.position[0])
            expected = 2.0 * (imp.set_point[0] - q) - 0.05 * float(engine.state.velocity[0])
            assert float(engine.final.effort[0]) == pytest.approx(expected, abs=1e-9)  # the law, computed here
        assert engine.final.kp.tolist() == [0.0, 0.0]  # torque control on the drive: its own gains are not used
        assert 0.1 < max(torques) <= 2.0 * 0.1 + 1e-3  # the drive got the spring's torque, never more than k·Δp
        assert abs(float(engine.state.position[0] - target[0])) < 0.01  # the spring pulled it there
        assert abs(float(engine.state.position[1] - home[1])) < 0.01
    finally:
        rig.close()


def test_a_config_that_claims_gains_on_an_odrive_is_refused_by_hild_check(tmp_path: Any) -> None:
    import yaml

    from tests.faults.rigs import can_robot

    config = can_robot("odrive", 2, "vcan-impedance-check", 1000.0, None, None)
    config["controllers"]["imp"] = {
        "type": "joint_impedance",
        "params": {"joints": ["j1", "j2"], "stiffness": [1, 1], "damping": [0, 0], "max_stiffness": [2, 2],
                   "max_damping": [1, 1]},
    }  # fmt: skip
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(config))
    with pytest.raises(ConfigError, match="claims 'j1/kp', which driver 'odrive_can' does not offer"):
        load_config(path)
