"""Contact detection and the collision reflex on the lockstep twin, with a plant 10 % heavier than the model hild
uses (robot.model is the shipped arm6.xml; the twin loads a copy whose masses and inertias are scaled by 1.1)."""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import pytest
import yaml

from drivers.mujoco.twin import MujocoTwin
from hild.arrays import JointState, ServoCommand
from hild.config import load_config
from hild.config.loader import ConfigError
from hild.crossing.ring import RingReader
from hild.cycle.contact import ContactMonitor, ContactSettings
from hild.cycle.engine import Engine
from hild.cycle.supervisor import Fault
from hild.dynamics.friction import FrictionArrays
from hild.modes import JointMode
from tests.conftest import CONFIGS
from tests.helpers import component, heavier_plant
from tests.test_engine import JumpGuard, events, send

WRISTS = ("wrist_1", "wrist_2", "wrist_3")
THRESHOLDS: dict[str, Any] = {
    "contact": 3.0,
    "collision": 5.0,
    "joints": {j: {"contact": 1.0, "collision": 2.0} for j in WRISTS},
}


def config(tmp_path: Path, contact: dict[str, Any], scale: float = 1.1) -> Path:
    raw = yaml.safe_load((CONFIGS / "arm6_twin.yaml").read_text())
    raw["robot"]["model"] = str(CONFIGS / "arm6.xml")  # what hild models
    raw["hardware"]["twin"]["params"]["model"] = str(
        heavier_plant(CONFIGS / "arm6.xml", tmp_path, scale)
    )  # what it drives
    raw["clock"] = {"source": "sim", "real_time_factor": 0.0}
    raw["safety"]["contact"] = contact
    path = tmp_path / "arm6_contact.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


def twin(tmp_path: Path, scale: float = 1.1, **contact: Any) -> Engine:
    engine = Engine(load_config(config(tmp_path, {"enabled": True, **THRESHOLDS, **contact}, scale)))
    engine.start()
    return engine


def push(engine: Engine, force: list[float]) -> None:
    """A force (N, world frame) on the tool body, from now on."""
    tool = component(engine, MujocoTwin)
    body = mujoco.mj_name2id(tool.model, mujoco.mjtObj.mjOBJ_BODY, "wrist_3_link")
    tool.data.xfrc_applied[body, :3] = force


def push_against_motion(engine: Engine, newtons: float = 20.0) -> None:
    """An obstacle in the way: a force against the tool's current velocity."""
    tool = component(engine, MujocoTwin)
    site = mujoco.mj_name2id(tool.model, mujoco.mjtObj.mjOBJ_SITE, "tool")
    velocity = np.zeros(6)
    mujoco.mj_objectVelocity(tool.model, tool.data, mujoco.mjtObj.mjOBJ_SITE, site, velocity, 0)
    push(engine, (-newtons * velocity[3:] / np.linalg.norm(velocity[3:])).tolist())


def collided(engine: Engine) -> bool:
    return bool((engine.supervisor.fault == Fault.COLLISION).any())


def run_until_collision(engine: Engine, cycles: int, guard: JumpGuard | None = None) -> int:
    for k in range(1, cycles + 1):
        guard.run(1) if guard else engine.run_cycles(1)
        if collided(engine):
            return k
    return -1


def test_free_motion_and_abrupt_stops_read_no_contact_despite_the_heavier_plant(tmp_path: Path) -> None:
    engine = twin(tmp_path)
    guard = JumpGuard(engine)
    home = engine.state.position.copy()
    rng = np.random.default_rng(7)
    fastest, largest = 0.0, np.zeros(6)
    for _ in range(6):
        assert engine.switch(["forward_position"], []).ok
        target = home + rng.uniform(-0.8, 0.8, 6)
        for _ in range(150):  # at the velocity limit from a standing start: the hardest acceleration
            send(engine, "forward_position", target.tolist())
            guard.run(1)
            fastest = max(fastest, float(np.abs(engine.state.velocity).max()))
            largest = np.fmax(largest, np.abs(engine.contact.tau_ext))
        assert engine.switch([], ["forward_position"]).ok  # hold latches mid-motion: the most abrupt stop
        for _ in range(150):
            guard.run(1)
            largest = np.fmax(largest, np.abs(engine.contact.tau_ext))
    assert fastest > 2.5  # really fast
    assert largest[1] > 3.0  # the model error shows (so a threshold below it would trip) ...
    assert not engine.supervisor.fault.any()  # ... yet nothing faulted
    assert not [e for e in events(engine) if ":contact:" in e]


@pytest.mark.parametrize("force", [[0.0, 20.0, 0.0], [0.0, 0.0, -20.0]])
def test_a_20_newton_push_at_the_tool_is_detected_within_10_ms(tmp_path: Path, force: list[float]) -> None:
    engine = twin(tmp_path)
    engine.run_cycles(250)
    push(engine, force)
    cycles = run_until_collision(engine, 20)
    assert 0 < cycles * engine.period <= 0.010
    texts = set(engine.supervisor.fault_text)
    assert len(texts) == 1  # every joint faulted, for the same collision
    (text,) = texts
    assert re.match(r"collision on (shoulder_pan|shoulder_lift|elbow): external torque [+-]\d", text), text
    assert (engine.supervisor.fault == Fault.COLLISION).all()


def test_the_hold_reflex_stops_compliantly_and_never_pushes_on(tmp_path: Path) -> None:
    engine = twin(tmp_path, reflex_stiffness=0.1)
    guard = JumpGuard(engine)
    assert engine.switch(["forward_position"], []).ok
    start = engine.state.position.copy()
    target = start + np.array([0.8, 0, 0, 0, 0, 0])  # shoulder_pan sweeps the tool sideways
    for _ in range(60):
        send(engine, "forward_position", target.tolist())
        guard.run(1)
    assert engine.state.velocity[0] > 1.0
    leading = float(engine.final.position[0] - engine.state.position[0])
    assert leading > 0.1  # the setpoint leads the shaft at speed (kd·q̇/kp)
    push_against_motion(engine, 40.0)  # an obstacle in the way
    for _ in range(20):
        send(engine, "forward_position", target.tolist())  # the client streams toward the obstacle
        engine.run_cycles(1)
        if collided(engine):
            break
        guard.check()  # no jumps up to the collision
    assert collided(engine), "not detected in 40 ms"
    detected = engine.state.position.copy()
    # The setpoint went back to the shaft in that very cycle (the one step the slew limit allows a reflex).
    assert np.allclose(engine.final.position, detected)
    assert engine.manager.records["forward_position"].state.value != "active"  # as an e-stop does
    assert "warning:controller_manager:collision: deactivated ['forward_position']" in events(engine)
    with pytest.raises(ValueError, match="not active"):  # the stream is refused from now on
        send(engine, "forward_position", target.tolist())
    onward = (target - detected) / np.linalg.norm(target - detected)
    furthest, stopped_at = 0.0, None
    for _ in range(500):  # 1 s with the obstacle still there
        engine.run_cycles(1)
        along = float((engine.state.position - detected) @ onward)
        assert float((engine.final.position - detected) @ onward) <= 1e-9  # the command never leads on
        if stopped_at is None and float(engine.state.velocity @ onward) <= 0.0:
            stopped_at = along  # its momentum is spent: from here on it must not advance again
        if stopped_at is not None:
            assert along <= stopped_at + 1e-4
        furthest = max(furthest, along)
    hold_kp = np.array([400, 400, 400, 60, 60, 60.0])
    assert np.allclose(engine.final.kp, 0.1 * hold_kp)
    assert not engine.final.velocity.any()
    assert stopped_at is not None and furthest < 0.05  # what its momentum carried at detection, then no further
    assert float((engine.state.position - detected) @ onward) < 0.0  # compliant: the obstacle pushed it back
    assert engine.supervisor.mode.tolist() == [int(JointMode.FAULT)] * 6


def test_the_collision_fault_latches_until_reset_and_names_the_joint_and_torque(tmp_path: Path) -> None:
    engine = twin(tmp_path)
    engine.run_cycles(250)
    push(engine, [0.0, 20.0, 0.0])
    assert run_until_collision(engine, 20) > 0
    logged = [e for e in events(engine) if "fault: collision on" in e]
    assert len(logged) == 6 and "N·m (collision threshold" in logged[0]
    push(engine, [0.0, 0.0, 0.0])
    engine.run_cycles(500)  # the contact is gone: the fault stays
    assert (engine.supervisor.fault == Fault.COLLISION).all()
    assert not engine.switch(["forward_position"], []).ok or engine.supervisor.fault.any()
    reply = engine.reset()
    assert isinstance(reply, dict) and any("collision on" in c for c in reply["cleared"])
    engine.run_cycles(500)
    assert not engine.supervisor.fault.any()
    assert np.abs(engine.contact.tau_ext[:3]).max() < 5.0  # detects again, with nothing to detect
    push(engine, [0.0, 20.0, 0.0])
    assert run_until_collision(engine, 20) > 0  # and trips again after the reset


def test_the_retract_reflex_backs_off_along_the_path(tmp_path: Path) -> None:
    # The plant as modelled and full hold stiffness: what is measured is the retract, not a compliant sag.
    engine = twin(tmp_path, scale=1.0, reflex="retract", retract_distance=0.01, retract_time=0.2, reflex_stiffness=1.0)
    tool = component(engine, MujocoTwin)
    site = mujoco.mj_name2id(tool.model, mujoco.mjtObj.mjOBJ_SITE, "tool")
    assert engine.switch(["forward_position"], []).ok
    target = engine.state.position + np.array([0.8, 0, 0, 0, 0, 0])
    path = []
    for _ in range(60):
        send(engine, "forward_position", target.tolist())
        engine.run_cycles(1)
        path.append(tool.data.site_xpos[site].copy())
    push_against_motion(engine, 40.0)
    assert run_until_collision(engine, 20) > 0
    push(engine, [0.0, 0.0, 0.0])  # the obstacle gives way: only the reflex moves the arm now
    hit = tool.data.site_xpos[site].copy()
    assert re.search(r"retracts 1\d\.\d mm along its path", engine.supervisor.fault_text[0])
    engine.run_cycles(500)
    back = tool.data.site_xpos[site].copy()
    assert 0.008 < np.linalg.norm(back - hit) < 0.02  # ~10 mm back (plus one cycle's travel at detection)
    assert min(np.linalg.norm(p - back) for p in path) < 0.003  # on the path it came along
    assert np.linalg.norm(back - path[0]) < np.linalg.norm(hit - path[0])  # the way it came
    assert np.abs(engine.state.velocity).max() < 0.01  # and there it holds


def test_tau_ext_is_published_in_joint_states(tmp_path: Path) -> None:
    engine = twin(tmp_path)
    ring = engine.manager.records["joint_state_broadcaster"].instance.ring
    reader = RingReader(ring)
    engine.run_cycles(100)
    push(engine, [0.0, 0.0, -10.0])  # below the collision level on the big joints
    engine.run_cycles(50)
    *_, (_seq, _stamp, fields) = reader.read()
    assert "tau_ext" in ring.fields
    assert np.allclose(fields["tau_ext"], engine.contact.tau_ext, atol=0.5)
    assert abs(fields["tau_ext"][1]) > 3.0  # the push shows on shoulder_lift
    assert engine.realtime_report["contact_observer"] == "compiled"  # the status says which update runs


def test_without_the_observer_tau_ext_is_null(tmp_path: Path) -> None:
    engine = Engine(load_config(config(tmp_path, {"enabled": False})))
    engine.start()
    ring = engine.manager.records["joint_state_broadcaster"].instance.ring
    reader = RingReader(ring)
    engine.run_cycles(10)
    *_, (_seq, _stamp, fields) = reader.read()
    assert engine.contact is None
    assert np.isnan(fields["tau_ext"]).all()


@pytest.mark.parametrize(
    ("contact", "words"),
    [
        ({"contact": 6.0, "collision": 5.0}, "contact threshold 6 is above the collision threshold 5"),
        ({"joints": {"elbowz": {"contact": 1.0, "collision": 2.0}}}, "joint 'elbowz' is not defined"),
        ({"enabled": True, "observer_gain": 600.0}, "gain × period must stay below 1"),
    ],
)
def test_bad_contact_settings_are_refused(tmp_path: Path, contact: dict[str, Any], words: str) -> None:
    with pytest.raises(ConfigError, match=re.escape(words)):
        load_config(config(tmp_path, contact))


class Recorder:
    """A stand-in observer that keeps the torque it is told acted."""

    def __init__(self, n: int) -> None:
        self.residual = np.zeros(n)
        self.told: list[list[float]] = []

    def reset(self, q: np.ndarray, qd: np.ndarray) -> None:
        self.residual.fill(0.0)

    def update(self, q: np.ndarray, qd: np.ndarray, tau: np.ndarray, dt: float) -> np.ndarray:
        self.told.append(tau.tolist())
        return self.residual


def monitor(use_reply: bool, friction: FrictionArrays) -> tuple[ContactMonitor, Recorder]:
    settings = ContactSettings(
        gain=100.0,
        use_reply=use_reply,
        contact=np.full(2, 1.0),
        collision=np.full(2, 2.0),
        model_margin=0.0,
        retract=False,
        reflex_stiffness=0.25,
        retract_distance=0.005,
        retract_time=0.2,
    )
    recorder = Recorder(2)
    found = ContactMonitor(
        ("a", "b"),
        settings,
        recorder,
        effort_limit=np.array([10.0, 10.0]),
        applies_gains=np.array([True, False]),
        friction=friction,
        emit=lambda *_: None,
        update_rate=500.0,
    )
    return found, recorder


def test_the_observer_is_told_the_reply_or_the_predicted_command_torque_minus_friction() -> None:
    friction = FrictionArrays(np.array([0.5, 0.0]), np.array([1.0, 0.0]), np.array([0.1, 0.0]), np.full(2, 0.02))
    state, last = JointState.zeros(2), ServoCommand.zeros(2)
    state.velocity[:] = [1.0, 1.0]
    last.position[:], last.velocity[:], last.effort[:] = [0.1, 5.0], [0.0, 0.0], [2.0, 3.0]
    last.kp[:], last.kd[:] = [100.0, 100.0], [1.0, 1.0]
    for use_reply, reply, expected in (
        # a: the reply (4) minus friction (0.5·1 + 1·tanh(50) + 0.1 = 1.6); b: the reply, no friction
        (True, [4.0, -3.0], [4.0 - 1.6, -3.0]),
        # a: no reply → kp·(0.1 − 0) + kd·(0 − 1) + 2 = 11, saturated at 10, minus friction; b: ff only (own gains)
        (True, [math.nan, math.nan], [10.0 - 1.6, 3.0]),
        (False, [4.0, -3.0], [10.0 - 1.6, 3.0]),  # torque: command ignores the reply
    ):
        found, recorder = monitor(use_reply, friction)
        state.effort[:] = reply
        found.observe(state, last, True, 0.002)  # starts the observer
        found.observe(state, last, True, 0.002)
        assert np.allclose(recorder.told[-1], expected, atol=1e-9)


def test_an_untrusted_cycle_restarts_the_observer_and_publishes_nan() -> None:
    found, recorder = monitor(True, FrictionArrays.zeros(2))
    state, last = JointState.zeros(2), ServoCommand.zeros(2)
    found.observe(state, last, True, 0.002)
    found.observe(state, last, True, 0.002)
    assert np.isfinite(found.tau_ext).all() and len(recorder.told) == 1
    found.observe(state, last, False, 0.002)  # a reading missing, a drive fault, an e-stop
    assert np.isnan(found.tau_ext).all() and len(recorder.told) == 1


# ---- the finding issue 28 quotes: "a trajectory that hits an obstacle today pushes with the full effort limit until
# path tolerance aborts it" ---------------------------------------------------------------------------------------
SWEEP = 0.8  # rad of shoulder_pan: the tool sweeps sideways through a post in its way


def post_in_the_way(tmp_path: Path, contact: dict[str, Any]) -> Engine:
    """arm6 on the lockstep twin (the plant as modelled) with a fixed post where the tool passes at pan + SWEEP/2."""
    path = config(tmp_path, contact, scale=1.0)
    raw = yaml.safe_load(path.read_text())
    model = mujoco.MjModel.from_xml_path(str(CONFIGS / "arm6.xml"))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, "home"))
    data.qpos[0] += SWEEP / 2
    mujoco.mj_kinematics(model, data)
    tool = data.site_xpos[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "tool")].tolist()
    post = {"name": "post", "size": [0.03, 0.03, 0.03], "pos": tool, "fixed": True}
    raw["hardware"]["twin"]["params"]["objects"] = [post]
    path.write_text(yaml.safe_dump(raw))
    engine = Engine(load_config(path))
    engine.start()
    return engine


def sweep_into_the_post(engine: Engine, seconds: float) -> tuple[str, float, float, float]:
    """A joint_trajectory move through the post: its final status, the largest torque shoulder_pan's drive applied
    (the twin's reply, N·m), that torque at the end (``seconds`` later), and the sim time the collision fault
    latched (inf if never)."""
    from hild.api.goals import GoalEndpoint  # the client half of the goal, as the API builds it

    assert engine.switch(["joint_trajectory"], []).ok
    jtc = engine.manager.records["joint_trajectory"].instance
    goals = GoalEndpoint.of(jtc.action)
    goal = {j: float(engine.state.position[engine.joints.index(j)]) for j in jtc.params.joints}
    goal["shoulder_pan"] += SWEEP
    reply = goals.submit({"positions": list(goal.values()), "duration": 1.0})  # in the controller's joint order
    assert reply["ok"], reply
    pan = engine.joints.index("shoulder_pan")
    peak, latched = 0.0, math.inf
    for _ in range(round(seconds * engine.update_rate)):
        engine.run_cycles(1)
        peak = max(peak, abs(float(engine.state.effort[pan])))
        if latched == math.inf and collided(engine):
            latched = engine.t
    status = goals.result({"goal_id": reply["goal_id"]}).get("status", "")
    return status, peak, abs(float(engine.state.effort[pan])), latched


def test_without_contact_detection_a_trajectory_into_an_obstacle_presses_on_it_until_path_tolerance(
    tmp_path: Path,
) -> None:
    """The finding, reproduced: nothing notices the post but the path tolerance (0.2 rad); until then the drive
    presses on it with kp × the lag, 100+ of arm6's 150 N·m. And the abort must end the pressing: it used to stop
    the *desired* state, beyond the post, and press on with 137 N·m for good."""
    engine = post_in_the_way(tmp_path, {"enabled": False})
    status, peak, after, latched = sweep_into_the_post(engine, 2.0)
    assert latched == math.inf and status == "aborted"  # the path tolerance ended it, not a contact check
    assert peak > 100.0
    assert after < 5.0  # stopped where the arm is: only what holds it there against gravity and friction


def test_with_contact_detection_the_same_move_stops_on_touching(tmp_path: Path) -> None:
    engine = post_in_the_way(tmp_path, {"enabled": True, **THRESHOLDS})
    status, peak, after, latched = sweep_into_the_post(engine, 2.0)
    assert latched < 2.0 and status == "aborted"  # the reflex deactivated the controller: its goal ended
    assert peak < 40.0  # stopped at a fraction of what the path tolerance let through
    assert after < 5.0
    assert engine.supervisor.mode.tolist() == [int(JointMode.FAULT)] * 6


def test_the_supervisors_gravity_is_the_observers_at_its_reading_and_the_models_elsewhere(tmp_path: Path) -> None:
    """With the observer on, one evaluation of the arm's dynamics per cycle serves the observer and the supervisor's
    gravity feed-forward: the same torques, to the last bit, as the gravity model's own."""
    from hild.dynamics.gravity import GravityModel

    engine = twin(tmp_path)
    model = GravityModel(CONFIGS / "arm6.xml", engine.joints)
    assert engine.switch(["forward_position"], []).ok
    target = engine.state.position + 0.3
    expected = np.zeros(6)
    for _ in range(200):  # moving: a new reading every cycle
        send(engine, "forward_position", target.tolist())
        engine.run_cycles(1)
        model.compute(engine.state.position, expected)
        assert np.array_equal(engine.supervisor.gravity_torque, expected)
    observer = engine.contact.observer  # type: ignore[union-attr]
    elsewhere, out = engine.state.position + 0.1, np.zeros(6)
    assert not observer.gravity_at(elsewhere, out) and not out.any()  # not its reading: the model computes it
    engine.supervisor.gravity(elsewhere, out)
    model.compute(elsewhere, expected)
    assert np.array_equal(out, expected)
