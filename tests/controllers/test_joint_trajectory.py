"""joint_trajectory on the lockstep arm6 twin: tracking, every result path, jump-free starts, bad goals."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from hild.action import ErrorCode, GoalResult
from hild.api.goals import GoalEndpoint
from hild.controllers.joint_trajectory import JointTrajectoryController
from hild.crossing.requests import SetParams
from hild.cycle.engine import Engine
from hild.cycle.supervisor import Fault
from hild.motion.reference import standard_trajectory
from tests.test_engine import JumpGuard, events
from tests.test_twin_engine import twin

JTC = "joint_trajectory"


class Recorder(JumpGuard):
    """Runs cycles under the jump guard and records what the controller asked for and what the arm did."""

    def __init__(self, engine: Engine) -> None:
        super().__init__(engine)
        self.desired: list[np.ndarray] = []
        self.velocity: list[np.ndarray] = []
        self.measured: list[np.ndarray] = []

    def run(self, cycles: int) -> None:
        for _ in range(cycles):
            super().run(1)
            self.desired.append(self.engine.final.position.copy())
            self.velocity.append(self.engine.final.velocity.copy())
            self.measured.append(self.engine.state.position.copy())


def controller(engine: Engine) -> JointTrajectoryController:
    instance = engine.manager.records[JTC].instance
    assert isinstance(instance, JointTrajectoryController)
    return instance


def started(name: str = "arm6_twin.yaml") -> Engine:
    engine = twin(name)
    assert engine.switch([JTC], []).ok
    return engine


def submit(engine: Engine, goal: dict[str, Any]) -> str:
    reply = GoalEndpoint.of(controller(engine).action).submit(goal)
    assert reply["ok"], reply["error"]
    return str(reply["goal_id"])


def run_until_result(recorder: Recorder, goal_id: str, limit_s: float = 20.0) -> GoalResult:
    action = GoalEndpoint.of(controller(recorder.engine).action)
    for _ in range(int(limit_s * recorder.engine.update_rate)):
        recorder.run(1)
        for result in action.collect():
            if result.goal_id == goal_id:
                return result
    raise AssertionError(f"goal {goal_id} has no result after {limit_s} s")


def results_of(engine: Engine) -> dict[str, GoalResult]:
    return {r.goal_id: r for r in GoalEndpoint.of(controller(engine).action).collect()}


def test_standard_trajectory_is_tracked_within_tolerance_and_succeeds() -> None:
    engine = started()
    home = engine.state.position.copy()
    rec = Recorder(engine)
    goal_id = submit(engine, standard_trajectory(engine.joints, home))
    result = run_until_result(rec, goal_id)
    assert result.status == "succeeded", result
    desired, measured = np.array(rec.desired), np.array(rec.measured)
    assert np.abs(desired - measured).max() < 0.05  # path tolerance in the config is 0.2
    np.testing.assert_allclose(engine.state.position, home, atol=0.01)  # the standard trajectory returns home
    reached = np.abs(desired - (home + np.array([0.8, -0.5, 0.7, 0.5, -0.2, 1.0]))).min(axis=0)
    assert (reached < 1e-3).all()  # it really went through the middle point


def test_success_holds_the_final_point() -> None:
    engine = started()
    target = engine.state.position + 0.2
    rec = Recorder(engine)
    goal_id = submit(engine, {"positions": target.tolist()})
    assert run_until_result(rec, goal_id).status == "succeeded"
    rec.run(500)
    np.testing.assert_allclose(engine.final.position, target, atol=1e-9)
    np.testing.assert_allclose(engine.state.position, target, atol=2e-3)


def test_activation_holds_the_current_position() -> None:
    engine = twin("arm6_twin.yaml")
    engine.run_cycles(10)
    before = engine.state.position.copy()
    assert engine.switch([JTC], []).ok
    JumpGuard(engine).run(500)
    np.testing.assert_allclose(engine.final.position, before, atol=1e-6)
    np.testing.assert_allclose(engine.state.position, before, atol=1e-3)


def test_preemption_continues_from_the_desired_state_without_a_jump() -> None:
    engine = started()
    home = engine.state.position.copy()
    rec = Recorder(engine)
    first = submit(engine, {"positions": (home + 0.8).tolist()})
    rec.run(150)  # mid-move: moving fast
    assert np.abs(engine.final.velocity).max() > 0.3
    second = submit(engine, {"positions": (home - 0.3).tolist()})
    rec.run(1)
    results = results_of(engine)
    assert results[first].status == "preempted"
    assert second in results[first].error_string
    result = run_until_result(rec, second)
    assert result.status == "succeeded"
    velocity = np.array(rec.velocity)
    assert np.abs(np.diff(velocity, axis=0)).max() <= 12.0 * engine.period * 1.01  # no velocity step: ≤ a_max·dt
    np.testing.assert_allclose(engine.state.position, home - 0.3, atol=0.01)


def test_cancel_decelerates_jerk_limited_then_holds() -> None:
    engine = started()
    home = engine.state.position.copy()
    rec = Recorder(engine)
    goal_id = submit(engine, {"positions": (home + 1.0).tolist()})
    rec.run(100)
    assert GoalEndpoint.of(controller(engine).action).cancel({"goal_id": goal_id})["ok"]
    result = run_until_result(rec, goal_id, 5.0)
    assert result.status == "canceled"
    stopped_at = engine.final.position.copy()
    rec.run(250)
    np.testing.assert_allclose(engine.final.position, stopped_at, atol=1e-12)
    velocity = np.array(rec.velocity)
    acceleration = np.diff(velocity, axis=0) / engine.period
    limits = engine.limits
    assert (np.abs(acceleration) <= limits.acceleration * 1.01 + 1e-6).all()
    assert (np.abs(home + 1.0 - stopped_at) > 0.05).all()  # it stopped short, it did not run on to the target


def test_cancel_of_an_unknown_or_finished_goal_is_refused() -> None:
    engine = started()
    action = GoalEndpoint.of(controller(engine).action)
    reply = action.cancel({"goal_id": "nope"})
    assert not reply["ok"] and "unknown" in reply["error"]
    goal_id = submit(engine, {"positions": (engine.state.position + 0.01).tolist()})
    run_until_result(Recorder(engine), goal_id)
    reply = action.cancel({"goal_id": goal_id})
    assert not reply["ok"] and "finished" in reply["error"]
    assert action.result({"goal_id": goal_id})["status"] == "succeeded"


def test_path_tolerance_violation_aborts_and_stops() -> None:
    engine = started()
    rec = Recorder(engine)
    target = engine.state.position + 0.5
    goal = {"positions": target.tolist(), "path_tolerance": [{"name": "shoulder_lift", "position": 1e-5}]}
    result = run_until_result(rec, submit(engine, goal))
    assert result.status == "aborted"
    assert result.error_code == ErrorCode.PATH_TOLERANCE_VIOLATED
    assert "shoulder_lift" in result.error_string
    assert any("goal aborted" in e for e in events(engine))
    rec.run(500)
    assert np.abs(engine.final.velocity).max() == 0.0
    assert (np.abs(engine.final.position - target) > 0.3).all()  # it stopped instead of carrying on


def test_goal_tolerance_violation_aborts_after_goal_time() -> None:
    engine = started()
    rec = Recorder(engine)
    others = [{"name": j, "position": -1, "velocity": -1} for j in engine.joints if j != "elbow"]
    goal = {
        "positions": (engine.state.position + 0.1).tolist(),
        "goal_tolerance": [*others, {"name": "elbow", "position": 1e-9}],
        "goal_time_tolerance": 0.05,
    }
    result = run_until_result(rec, submit(engine, goal))
    assert result.status == "aborted"
    assert result.error_code == ErrorCode.GOAL_TOLERANCE_VIOLATED
    assert "elbow" in result.error_string and "0.05 s after the end" in result.error_string


def test_untimed_waypoints_pass_through_every_point_within_limits() -> None:
    engine = started()
    home = engine.state.position.copy()
    waypoints = [home + d for d in (np.full(6, 0.3), np.array([0.6, 0.1, 0.5, 0.2, -0.2, 0.8]), np.zeros(6))]
    rec = Recorder(engine)
    goal = {
        "trajectory": {"joint_names": list(engine.joints), "points": [{"positions": w.tolist()} for w in waypoints]}
    }
    result = run_until_result(rec, submit(engine, goal))
    assert result.status == "succeeded"
    desired, velocity = np.array(rec.desired), np.array(rec.velocity)
    limits = engine.limits
    assert (np.abs(velocity) <= limits.velocity * (1 + 1e-6)).all()
    assert (np.abs(np.diff(velocity, axis=0)) / engine.period <= limits.acceleration * 1.01 + 1e-6).all()
    for w in waypoints:  # passed within one cycle's travel of each waypoint
        closest = np.abs(desired - w).max(axis=1).min()
        assert closest <= float(limits.velocity.max()) * engine.period


def test_move_to_is_synchronized_and_duration_only_slows_it() -> None:
    engine = started()
    home = engine.state.position.copy()
    target = home + np.array([0.9, -0.2, 0.4, 0.1, 0.0, 0.6])
    rec = Recorder(engine)
    result = run_until_result(rec, submit(engine, {"positions": target.tolist()}))
    assert result.status == "succeeded"
    moving = np.abs(np.array(rec.velocity)) > 1e-9
    last_moving = [int(np.flatnonzero(moving[:, j])[-1]) for j in range(6) if moving[:, j].any()]
    assert max(last_moving) - min(last_moving) <= 1  # every moving joint arrives in the same cycle
    fast_cycles = max(last_moving)

    rec2 = Recorder(engine)
    result = run_until_result(rec2, submit(engine, {"positions": home.tolist(), "duration": 3.0}))
    assert result.status == "succeeded"
    slow_cycles = int(np.flatnonzero(np.abs(np.array(rec2.velocity)).max(axis=1) > 1e-9)[-1])
    assert slow_cycles >= 3.0 * engine.update_rate - 2
    assert fast_cycles < slow_cycles


def test_partial_goal_lets_the_other_joints_continue() -> None:
    engine = twin("arm6_twin.yaml")
    ctl = controller(engine)
    ctl.goal_context = ctl.goal_context.__class__(**{**ctl.goal_context.__dict__, "allow_partial": True})
    assert engine.switch([JTC], []).ok
    home = engine.state.position.copy()
    rec = Recorder(engine)
    first = submit(engine, {"positions": (home + 0.6).tolist()})
    rec.run(200)
    second = submit(engine, {"joint_names": ["wrist_3"], "positions": [home[5] - 0.2]})
    assert run_until_result(rec, second).status == "succeeded"
    rec.run(1500)
    np.testing.assert_allclose(engine.final.position[:5], home[:5] + 0.6, atol=1e-9)  # kept their motion
    assert abs(engine.final.position[5] - (home[5] - 0.2)) < 1e-9
    assert GoalEndpoint.of(controller(engine).action).result({"goal_id": first})["status"] == "preempted"


def test_deactivation_aborts_the_running_goal_and_the_joints_are_held() -> None:
    engine = started()
    rec = Recorder(engine)
    goal_id = submit(engine, {"positions": (engine.state.position + 0.5).tolist()})
    rec.run(300)
    assert engine.switch([], [JTC]).ok
    rec.run(5)
    result = results_of(engine)[goal_id]
    assert result.status == "aborted" and "deactivated" in result.error_string
    reply = GoalEndpoint.of(controller(engine).action).submit({"positions": engine.state.position.tolist()})
    assert not reply["ok"] and "not active" in reply["error"]


def test_feedback_reports_desired_actual_and_error_for_the_goal() -> None:
    engine = started()
    goal_id = submit(engine, {"positions": (engine.state.position + 0.3).tolist()})
    engine.run_cycles(100)
    messages = GoalEndpoint.of(controller(engine).action).feedback_messages()
    assert 4 <= len(messages) <= 6  # 25 Hz over 0.2 s
    last = messages[-1]
    assert last["goal_id"] == goal_id and last["joint_names"] == list(engine.joints)
    err = np.array(last["desired"]["positions"]) - np.array(last["actual"]["positions"])
    np.testing.assert_allclose(last["error"]["positions"], err)


def test_timed_first_point_at_time_zero_must_be_where_the_arm_is() -> None:
    engine = started()
    home = engine.state.position.copy()
    names = list(engine.joints)
    ok = {"trajectory": {"joint_names": names, "points": [
        {"positions": home.tolist(), "time_from_start": 0.0},
        {"positions": (home + 0.1).tolist(), "time_from_start": 1.0},
    ]}}  # fmt: skip
    rec = Recorder(engine)
    assert run_until_result(rec, submit(engine, ok)).status == "succeeded"
    far = {"trajectory": {"joint_names": names, "points": [
        {"positions": (home + 0.5).tolist(), "time_from_start": 0.0},
        {"positions": (home + 0.6).tolist(), "time_from_start": 1.0},
    ]}}  # fmt: skip
    result = run_until_result(rec, submit(engine, far))
    assert result.status == "aborted" and "time_from_start 0" in result.error_string


def _names(n: int = 6) -> list[str]:
    return ["shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3"][:n]


def _point(positions: list[float], t: float | None = 1.0, **extra: Any) -> dict[str, Any]:
    point: dict[str, Any] = {"positions": positions, **extra}
    if t is not None:
        point["time_from_start"] = t
    return point


HOME = [0.0, 1.0, -1.6, -0.9708, 1.5708, 0.0]
BAD_GOALS = [
    ("not an object", [1, 2], "expected a JSON object"),
    ("neither body", {"foo": 1}, "expected"),
    ("unknown goal key", {"trajectory": {"joint_names": _names(), "points": [_point(HOME)]}, "x": 1}, "unknown keys"),
    (
        "unknown joint",
        {"trajectory": {"joint_names": [*_names(5), "nope"], "points": [_point(HOME)]}},
        "unknown joints",
    ),
    (
        "duplicate joint",
        {"trajectory": {"joint_names": [*_names(5), "elbow"], "points": [_point(HOME)]}},
        "more than once",
    ),
    (
        "partial not allowed",
        {"trajectory": {"joint_names": _names(2), "points": [_point(HOME[:2])]}},
        "leaves out joints",
    ),
    ("no points", {"trajectory": {"joint_names": _names(), "points": []}}, "non-empty list"),
    ("length mismatch", {"trajectory": {"joint_names": _names(), "points": [_point(HOME[:5])]}}, "expected 6 values"),
    ("nan", {"trajectory": {"joint_names": _names(), "points": [_point([float("nan"), *HOME[1:]])]}}, "not finite"),
    ("string value", {"trajectory": {"joint_names": _names(), "points": [_point(["a", *HOME[1:]])]}}, "numbers"),
    (
        "non-increasing times",
        {"trajectory": {"joint_names": _names(), "points": [_point(HOME, 1.0), _point(HOME, 1.0)]}},
        "is not after point 0",
    ),
    ("negative time", {"trajectory": {"joint_names": _names(), "points": [_point(HOME, -1.0)]}}, "negative"),
    (
        "mixed timing",
        {"trajectory": {"joint_names": _names(), "points": [_point(HOME, 1.0), _point(HOME, None)]}},
        "give all points one or none",
    ),
    (
        "outside limits",
        {"trajectory": {"joint_names": _names(), "points": [_point([0.0, 3.2, *HOME[2:]])]}},
        "shoulder_lift is outside its limits",
    ),
    (
        "velocity beyond limit",
        {"trajectory": {"joint_names": _names(), "points": [_point(HOME, 1.0, velocities=[5.0, 0, 0, 0, 0, 0])]}},
        "velocity 5 of shoulder_pan exceeds",
    ),
    (
        "too fast between points",
        {"trajectory": {"joint_names": _names(), "points": [_point(HOME, 1.0), _point([2.0, *HOME[1:]], 1.1)]}},
        "need 20 rad/s on shoulder_pan",
    ),
    (
        "missing velocities on one point",
        {"trajectory": {"joint_names": _names(), "points": [_point(HOME, 1.0, velocities=[0] * 6), _point(HOME, 2.0)]}},
        "point 1 has no velocities",
    ),
    ("bad tolerance", {"positions": HOME, "goal_tolerance": [{"name": "elbow", "position": -3}]}, "must be > 0"),
    (
        "tolerance for another joint",
        {"joint_names": ["elbow"], "positions": [-1.6], "goal_tolerance": [{"name": "wrist_1"}]},
        "partial",
    ),
    ("move_to wrong length", {"positions": HOME[:3]}, "expected 6 values"),
    ("move_to out of limits", {"positions": [7.0, *HOME[1:]]}, "target: position 7 of shoulder_pan"),
    ("move_to bad duration", {"positions": HOME, "duration": 0}, "duration must be a positive"),
    ("move_to velocity too high", {"positions": HOME, "velocities": [9.0] * 6}, "velocity 9 of shoulder_pan exceeds"),
    (
        "single point at time 0",
        {"trajectory": {"joint_names": _names(), "points": [_point(HOME, 0.0)]}},
        "single point",
    ),
]


@pytest.mark.parametrize(("goal", "reason"), [(g, r) for _, g, r in BAD_GOALS], ids=[i for i, _, _ in BAD_GOALS])
def test_bad_goals_are_rejected_with_their_reason_and_nothing_moves(goal: Any, reason: str) -> None:
    engine = started()
    before = engine.final.position.copy()
    reply = GoalEndpoint.of(controller(engine).action).submit(goal)
    assert not reply["ok"]
    assert reason in reply["error"], reply["error"]
    assert len(controller(engine).action.requests) == 0
    engine.run_cycles(50)
    np.testing.assert_allclose(engine.final.position, before, atol=1e-9)


EFFORT_GAINS = {"joint1": {"p": 400.0, "d": 40.0, "i": 50.0, "i_clamp": 5.0}, "joint2": {"p": 200, "d": 15}}


def effort_jtc(engine: Engine) -> None:
    engine.manager.unload(JTC)
    engine.load_controller(
        JTC,
        "joint_trajectory",
        {
            "joints": ["joint1", "joint2"],
            "command_interfaces": ["effort"],
            "gains": EFFORT_GAINS,
            "constraints": {"goal_time": 2.0, "joints": {"joint1": {"goal": 0.02}, "joint2": {"goal": 0.02}}},
        },
    )
    assert engine.switch([JTC], []).ok


def test_effort_interface_tracks_a_move_with_pid() -> None:
    engine = twin("rrbot_twin.yaml")
    effort_jtc(engine)
    target = engine.state.position + np.array([0.4, -0.3])
    result = run_until_result(Recorder(engine), submit(engine, {"positions": target.tolist()}))
    assert result.status == "succeeded", result
    np.testing.assert_allclose(engine.state.position, target, atol=0.02)


def test_new_pid_gains_while_a_goal_runs_are_ramped_in_and_the_effort_never_steps() -> None:
    engine = twin("rrbot_twin.yaml")
    effort_jtc(engine)
    jtc = controller(engine)
    target = engine.state.position + np.array([0.6, -0.4])
    goal_id = submit(engine, {"positions": target.tolist()})
    efforts, errors = [], []

    def run(cycles: int) -> None:
        for _ in range(cycles):
            engine.run_cycles(1)
            efforts.append(engine.final.effort[:2].copy())
            errors.append(np.abs(jtc.pd - engine.state.position[:2]))

    run(150)  # mid-move: the PID works against a tracking error
    tripled = jtc.params.model_copy(
        update={"gains": {j: g.model_copy(update={"p": 3 * g.p}) for j, g in jtc.params.gains.items()}}
    )
    before = len(efforts)
    future = engine.request(SetParams(JTC, tripled, ("gains",)))
    run(400)
    assert future.result(0)["changed"] == ["gains"]
    steps = np.abs(np.diff(np.array(efforts), axis=0))
    error_then = errors[before - 1]
    unramped = 2 * 400.0 * error_then[0]  # the step a switch from p=400 to p=1200 would have made on joint1
    assert unramped > 5 * steps[: before - 1, 0].max()  # a step that size would stand out of the move's own …
    assert steps[before - 1 :, 0].max() < unramped / 5  # … and with the ramp, nothing does
    assert jtc._kp.tolist() == [1200.0, 600.0] and jtc._kd.tolist() == [40.0, 15.0]  # exactly the new gains
    result = run_until_result(Recorder(engine), goal_id)
    assert result.status == "succeeded", result
    assert any("parameters set" in e for e in events(engine))


def test_oversized_goals_are_refused_before_planning() -> None:
    engine = started()
    names = list(engine.joints)
    untimed = [{"positions": HOME} for _ in range(251)]
    reply = GoalEndpoint.of(controller(engine).action).submit({"trajectory": {"joint_names": names, "points": untimed}})
    assert not reply["ok"] and "at most 250 waypoints" in reply["error"]
    timed = [{"positions": HOME, "time_from_start": 1.0 + k} for k in range(10_001)]
    reply = GoalEndpoint.of(controller(engine).action).submit({"trajectory": {"joint_names": names, "points": timed}})
    assert not reply["ok"] and "at most 10000 are accepted" in reply["error"]


def test_a_fault_mid_goal_aborts_it_and_reset_resumes_without_a_jump() -> None:
    engine = started()
    rec = Recorder(engine)
    goal_id = submit(engine, {"positions": (engine.state.position + 0.6).tolist()})
    rec.run(150)
    engine.supervisor.trip(2, Fault.HARDWARE, "test fault")
    rec.run(2)
    result = results_of(engine)[goal_id]
    assert result.status == "aborted" and "joint elbow faulted" in result.error_string
    rec.run(500)
    assert engine.reset()["cleared"]
    rec.run(300)  # the jump guard holds across the reset: the controller resumed from the measured position
    assert [j["mode"] for j in engine.status()["joints"]] == ["controlled"] * 6
    np.testing.assert_allclose(engine.final.position, engine.state.position, atol=5e-3)
