"""teach on the lockstep arm6 twin: a scripted hand of 5 N at the tool moves the arm at sampled poses and it stays
where released (drift ≤ 2 mrad/s after 1 s), with the twin's friction compensated as identified; a thrown joint
brakes; a soft limit pushes back; a release brakes to a stop and hands over to hold without a step."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from drivers.mujoco.twin import MujocoTwin
from hild.bench.hand import ScriptedHand, run_with_hand
from hild.config import load_config
from hild.controllers.teach import LEARN_SPAN, TeachController, TeachParams
from hild.cycle.engine import Engine
from hild.modes import JointMode
from tests.conftest import CONFIGS
from tests.helpers import component

JOINTS = ["shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3"]
HOME = [0.0, 1.0, -1.6, -0.9708, 1.5708, 0.0]
POSES = [  # a sampled workspace: home, reaching out, folded back, twisted
    HOME,
    [0.6, 0.7, -1.1, -1.2, 1.2, 0.4],
    [-0.9, 1.4, -2.1, -0.4, 1.9, -0.6],
    [1.4, 0.5, -0.7, -1.6, 0.9, 1.1],
]
HAND = 5.0  # N at the tool: the target's bound
LEARNED = LEARN_SPAN * TeachParams.model_fields["gravity_learning_time"].default  # s after teach starts
RATE = 500
TWIN_FRICTION = {"big": 1.0, "wrist": 0.2}  # N·m of Coulomb friction in the twin (MuJoCo frictionloss)
TWIN_DAMPING = {"big": 0.3, "wrist": 0.05}  # N·m·s/rad, arm6.xml's own


def kind(joint: str) -> str:
    return "wrist" if joint.startswith("wrist") else "big"


def arm6_config(
    pose: list[float] | None = None, *, friction: bool = False, teach: dict[str, Any] | None = None
) -> dict[str, Any]:
    """arm6 on the twin in lockstep with a ``teach`` controller on every joint; ``friction``: the twin has Coulomb
    friction and the config its identified values (what ``hild identify`` writes)."""
    config = yaml.safe_load((CONFIGS / "arm6_twin.yaml").read_text())
    config["clock"] = {"source": "sim", "real_time_factor": 0}
    params = config["hardware"]["twin"]["params"]
    if pose is not None:
        del params["keyframe"]
        params["initial_positions"] = dict(zip(JOINTS, pose, strict=True))
    if friction:
        params["friction"] = {j: TWIN_FRICTION[kind(j)] for j in JOINTS}
        for j in JOINTS:
            config["joints"][j]["friction"] = {"viscous": TWIN_DAMPING[kind(j)], "coulomb": TWIN_FRICTION[kind(j)]}
    config["controllers"] = {
        "teach": {"type": "teach", "params": {"joints": JOINTS, **(teach or {})}},
        "hold_all": {"type": "forward_command", "params": {"joints": JOINTS, "interface": "position"}},
    }
    return config


def engine_of(tmp_path: Path, config: dict[str, Any]) -> Engine:
    shutil.copy(CONFIGS / "arm6.xml", tmp_path)
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    engine = Engine(load_config(path))
    engine.start()
    return engine


def teaching(tmp_path: Path, pose: list[float] | None = None, **kwargs: Any) -> tuple[Engine, ScriptedHand]:
    engine = engine_of(tmp_path, arm6_config(pose, **kwargs))
    engine.run_cycles(50)
    assert engine.switch(["teach"], []).ok
    engine.run_cycles(round(LEARNED * RATE))  # teach learns the model's error first: a hand then would be learned too
    return engine, ScriptedHand(component(engine, MujocoTwin))


def drift(engine: Engine, seconds: float = 0.2) -> float:
    """The fastest any joint moves over ``seconds``, in mrad/s."""
    before = engine.state.position.copy()
    engine.run_cycles(round(seconds * RATE))
    return float(np.abs(engine.state.position - before).max() / seconds * 1000.0)


def guide_along_axes(
    engine: Engine, hand: ScriptedHand, feels: Callable[[np.ndarray], bool], drift_seconds: float = 0.2
) -> int:
    """5 N at the tool along each world axis whose joint torques ``feels`` says a hand could move the arm with:
    each moves the tool > 10 mm in 0.5 s, and 1 s after the hand lets go the arm drifts ≤ 2 mrad/s. How many axes
    were pushed."""
    pushed = 0
    for direction in np.eye(3):
        if not feels(hand.joint_torques(HAND * direction)[: len(JOINTS)]):
            continue
        pushed += 1
        start = hand.tool_position()
        hand.push(HAND * direction)
        run_with_hand(engine.run_cycles, hand, round(0.5 * RATE))
        moved = float(np.dot(hand.tool_position() - start, direction))
        assert moved > 0.01, f"5 N along {direction} moved the tool {moved * 1000:.1f} mm"
        hand.release()
        engine.run_cycles(RATE)  # 1 s after the hand lets go
        assert drift(engine, drift_seconds) <= 2.0, f"drifting after a push along {direction}"
    return pushed


def teach_of(engine: Engine) -> TeachController:
    found = engine.controllers()["teach"]
    assert isinstance(found, TeachController)
    return found


@pytest.mark.parametrize("pose", POSES, ids=["home", "reach", "folded", "twisted"])
def test_5_n_at_the_tool_moves_the_arm_and_it_stays_where_released(tmp_path: Path, pose: list[float]) -> None:
    engine, hand = teaching(tmp_path, pose, friction=True)
    engine.run_cycles(100)
    assert drift(engine) < 2.0  # weightless, not falling: gravity and friction compensated at rest
    stiction = np.array([TWIN_FRICTION[kind(j)] for j in JOINTS])
    # Along a stretched arm no joint gets much more than its own friction: no hand could move it that way.
    assert guide_along_axes(engine, hand, lambda torques: (np.abs(torques) > 1.25 * stiction).any()) >= 2
    assert (engine.supervisor.mode == JointMode.CONTROLLED).all()
    assert not engine.supervisor.fault.any()


def test_without_friction_compensation_the_same_hand_moves_the_arm_less(tmp_path: Path) -> None:
    """The compensation is what makes 5 N enough: with it off the twin's friction eats most of the push."""
    moved = []
    for share, where in ((0.8, "on"), (0.0, "off")):
        (tmp_path / where).mkdir()
        engine, hand = teaching(tmp_path / where, friction=True, teach={"friction_compensation": share})
        start = hand.tool_position()
        hand.push([HAND, 0.0, 0.0])
        run_with_hand(engine.run_cycles, hand, round(0.5 * RATE))
        moved.append(hand.tool_position()[0] - start[0])
    assert moved[0] > 1.5 * moved[1], moved


def test_a_thrown_joint_brakes_to_the_teach_speed_limit(tmp_path: Path) -> None:
    engine, _ = teaching(tmp_path)
    twin = component(engine, MujocoTwin)
    k = JOINTS.index("wrist_1")
    limit = 0.5 * 3.14  # speed_limit x velocity limit
    twin.data.qvel[twin.model.joint("wrist_1").dofadr[0]] = 2.5  # thrown well above it
    engine.run_cycles(1)
    teach = teach_of(engine)
    assert engine.final.kd[k] == pytest.approx(teach.brake[JOINTS.index("wrist_1")])  # the brake's damping
    assert teach.brake[k] > 1.5 * teach.damping[k]
    engine.run_cycles(round(0.05 * RATE))
    assert abs(engine.state.velocity[k]) < limit  # braked within 50 ms
    assert engine.final.kd[k] < teach.brake[k]  # and light again below the limit


def test_a_soft_limit_pushes_back_and_a_thrown_joint_stops_short_of_it(tmp_path: Path) -> None:
    config = arm6_config()
    config["joints"]["wrist_1"]["limits"]["position"] = {"lower": -1.3, "upper": -0.6}  # soft: [-1.25, -0.65]
    config["hardware"]["twin"]["params"]["initial_positions"] = {"wrist_1": -0.68}  # inside the 0.1 rad wall zone
    engine = engine_of(tmp_path, config)
    engine.run_cycles(50)
    assert engine.switch(["teach"], []).ok
    k = JOINTS.index("wrist_1")
    engine.run_cycles(RATE)
    assert -0.85 < engine.state.position[k] <= -0.749  # pushed out of the zone (and coasting a little beyond)
    twin = component(engine, MujocoTwin)
    twin.data.qvel[twin.model.joint("wrist_1").dofadr[0]] = 1.5  # thrown at the wall
    highest = -np.inf
    for _ in range(RATE):
        engine.run_cycles(1)
        highest = max(highest, engine.state.position[k])
    assert -0.75 < highest < -0.65  # into the zone, never past the soft limit
    assert engine.state.position[k] <= -0.749  # and back out
    assert not engine.supervisor.fault.any()


def test_teach_off_brakes_to_a_stop_then_hands_over_to_hold_without_a_step(tmp_path: Path) -> None:
    engine, hand = teaching(tmp_path)
    teach = teach_of(engine)
    hand.push([HAND, 0.0, 0.0])
    run_with_hand(engine.run_cycles, hand, round(0.5 * RATE))
    hand.release()
    assert np.abs(engine.state.velocity).max() > 0.05  # still moving when the operator says off
    teach.set_teach(dict.fromkeys(JOINTS, False))
    handed_over, speed_then = np.full(6, np.nan), np.zeros(6)
    cycles = 0
    while np.isnan(handed_over).any():
        engine.run_cycles(1)
        cycles += 1
        assert cycles <= 0.5 * RATE + 1, "release_time bounds the braking"
        now = (engine.supervisor.mode == JointMode.HOLD) & np.isnan(handed_over)
        handed_over[now] = engine.state.position[now]  # each joint's position the cycle it went to hold
        speed_then[now] = np.abs(engine.state.velocity[now])
    assert teach.phases() == ["released"] * 6
    np.testing.assert_allclose(engine.supervisor.latched, handed_over, atol=1e-12)  # held where it stopped
    assert speed_then.max() < 0.01  # each at rest when handed over
    engine.run_cycles(RATE // 2)
    assert np.abs(engine.state.position - handed_over).max() < 1e-3  # no pull back: it was at rest
    assert engine.switch([], ["teach"]).ok  # deactivating it now changes nothing
    engine.run_cycles(RATE // 2)
    assert np.abs(engine.state.position - handed_over).max() < 1e-3


def test_deactivating_a_moving_teach_directly_pulls_the_arm_back_to_where_it_was(tmp_path: Path) -> None:
    """Why teach off brakes first: the supervisor latches the position of the cycle teach ends, the arm coasts on,
    and the hold spring pulls it back (here a few mrad); teach off hands over at rest instead."""
    engine, hand = teaching(tmp_path)
    hand.push([HAND, 0.0, 0.0])
    run_with_hand(engine.run_cycles, hand, round(0.5 * RATE))
    hand.release()
    assert engine.switch([], ["teach"]).ok
    engine.run_cycles(1)  # the supervisor latches on the first cycle without teach
    latched = engine.supervisor.latched.copy()
    overshoot = 0.0
    for _ in range(RATE // 2):
        engine.run_cycles(1)
        overshoot = max(overshoot, float(np.abs(engine.state.position - latched).max()))
    assert overshoot > 1e-3  # it coasted past the latch
    assert np.abs(engine.state.position - latched).max() < 5e-4  # and was pulled back


def test_a_released_joint_can_be_taught_again_and_the_others_stay_in_teach(tmp_path: Path) -> None:
    engine, _ = teaching(tmp_path)
    teach = teach_of(engine)
    teach.set_teach({"wrist_3": False})
    engine.run_cycles(RATE)
    assert teach.phases()[5] == "released" and teach.phases()[:5] == ["teach"] * 5
    assert engine.supervisor.mode[5] == JointMode.HOLD and (engine.supervisor.mode[:5] == JointMode.CONTROLLED).all()
    teach.set_teach({"wrist_3": True})
    engine.run_cycles(1)
    assert engine.supervisor.mode[5] == JointMode.CONTROLLED
    with pytest.raises(ValueError, match="does not teach"):
        teach.set_teach({"gripper": True})
    with pytest.raises(ValueError, match="6 values true, false or null"):
        teach.accept({"teach": [True]})


def test_effort_damping_for_drives_that_ignore_kd(tmp_path: Path) -> None:
    engine, hand = teaching(tmp_path, teach={"damping_via": "effort"})
    hand.push([HAND, 0.0, 0.0])
    run_with_hand(engine.run_cycles, hand, round(0.5 * RATE))
    assert (engine.final.kd == 0.0).all()  # no kd reaches the drive: the damping is in the effort
    hand.release()
    engine.run_cycles(RATE)
    assert drift(engine) <= 2.0


def test_params_refuse_joints_listed_twice_and_stray_damping() -> None:
    with pytest.raises(ValueError, match="twice"):
        TeachParams.model_validate({"joints": ["a", "a"]})
    with pytest.raises(ValueError, match="not in joints"):
        TeachParams.model_validate({"joints": ["a"], "damping": {"b": 1.0}})
