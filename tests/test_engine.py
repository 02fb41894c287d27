"""The cycle, supervisor and controller manager on the mock driver, in lockstep (deterministic, no sleeps)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from hild.arrays import JointState, ServoCommand
from hild.controller import Controller
from hild.cycle.engine import Engine
from hild.cycle.supervisor import Fault

MakeEngine = Callable[..., Engine]


class JumpGuard:
    """Asserts, cycle by cycle, that a stiff joint's commanded position never steps faster than its velocity limit.

    Only joints commanded with kp > 0 are checked: with kp = 0 (velocity, effort, damp) the position field
    carries no command. Transitions into hold are checked, since hold is stiff: from the last stiff command, or
    from the accepted reading when the joint had no stiffness before (nothing held it anywhere else).
    """

    def __init__(self, engine: Engine) -> None:
        self.engine = engine
        self.prev = engine.final.position.copy()
        self.prev_stiff = np.ones(len(engine.joints), dtype=bool)  # the start-up latch counts as a stiff command
        self.max_step = engine.limits.velocity * engine.period + 1e-9

    def check(self) -> None:
        final = self.engine.final
        origin = np.where(self.prev_stiff, self.prev, self.engine.state.position)
        step = np.abs(final.position - origin) * (final.kp > 0.0)
        assert (step <= self.max_step).all(), f"command stepped by {step} at t={self.engine.t}"
        self.prev[:] = final.position
        self.prev_stiff[:] = final.kp > 0.0

    def run(self, cycles: int) -> None:
        for _ in range(cycles):
            self.engine.run_cycles(1)
            self.check()


def send(engine: Engine, controller: str, values: list[float]) -> None:
    engine.manager.records[controller].instance.accept({"values": values})


def modes(engine: Engine) -> list[str]:
    return [j["mode"] for j in engine.status()["joints"]]


def events(engine: Engine) -> list[str]:
    return [f"{e.level}:{e.source}:{e.message}" for e in engine.events.drain()]


def test_start_holds_where_the_arm_is(make_engine: MakeEngine) -> None:
    engine = make_engine()
    start = engine.state.position.copy()
    np.testing.assert_allclose(start, [0.1, -0.2, 0.3])
    JumpGuard(engine).run(500)
    np.testing.assert_allclose(engine.state.position, start)
    np.testing.assert_allclose(engine.final.kp, 100.0)
    assert modes(engine) == ["hold"] * 3
    assert engine.status()["mode"] == "hold"


def test_forward_command_tracks_then_times_out_to_hold(make_engine: MakeEngine) -> None:
    engine = make_engine()
    assert engine.switch(["fwd"], []).ok
    assert engine.status()["mode"] == "active"
    guard = JumpGuard(engine)
    guard.run(5)
    np.testing.assert_allclose(engine.state.position, [0.1, -0.2, 0.3])  # nothing moves before a command
    send(engine, "fwd", [0.5, 0.4, -0.3])
    for _ in range(300):  # stream faster than the 0.2 s timeout; 0.6 s at ≤ 2 rad/s covers the move
        guard.run(1)
        send(engine, "fwd", [0.5, 0.4, -0.3])
    assert modes(engine) == ["controlled"] * 3
    np.testing.assert_allclose(engine.state.position, [0.5, 0.4, -0.3])
    events(engine)
    guard.run(200)  # silence longer than command_timeout
    assert modes(engine) == ["hold"] * 3
    assert any("no command for 0.2 s" in e for e in events(engine))
    np.testing.assert_allclose(engine.final.position, [0.5, 0.4, -0.3])


def test_deactivate_mid_motion_holds_without_a_step(make_engine: MakeEngine) -> None:
    engine = make_engine()
    engine.switch(["fwd"], [])
    guard = JumpGuard(engine)
    for _ in range(50):
        send(engine, "fwd", [0.9, -0.9, 0.9])  # far away: the slew limit is engaged
        guard.run(1)
    moving = engine.state.position.copy()
    assert not np.allclose(moving, [0.9, -0.9, 0.9])
    assert engine.switch([], ["fwd"]).ok
    guard.run(300)
    np.testing.assert_allclose(engine.state.position, moving, atol=2 * 2.0 * engine.period)
    assert modes(engine) == ["hold"] * 3


def test_switch_between_controllers_mid_motion_has_no_step(make_engine: MakeEngine) -> None:
    engine = make_engine({"controllers": {"fwd2": {"type": "forward_command", "params": {"joints": ["a", "b", "c"]}}}})
    engine.switch(["fwd"], [])
    guard = JumpGuard(engine)
    for _ in range(30):
        send(engine, "fwd", [0.8, 0.8, 0.8])
        guard.run(1)
    result = engine.switch(["fwd2"], ["fwd"])
    assert result.ok and result.activated == ["fwd2"] and result.deactivated == ["fwd"]
    guard.run(20)
    for _ in range(400):
        send(engine, "fwd2", [-0.5, -0.5, -0.5])
        guard.run(1)
    np.testing.assert_allclose(engine.state.position, -0.5)


class Exploding(Controller):
    """Commands its joint for a while, then raises: a plugin bug in update()."""

    def __init__(self, context, joints: list[str], explode_at: float) -> None:
        super().__init__(context, Controller.Params())
        self.joints = joints
        self.index = context.index_of(joints)
        self.explode_at = explode_at

    def claims(self) -> list[str]:
        return [f"{j}/position" for j in self.joints]

    def update(self, t: float, dt: float, state: JointState, command: ServoCommand) -> None:
        if t >= self.explode_at:
            raise ZeroDivisionError("bug")
        command.position[self.index] = state.position[self.index] + 0.5 * dt
        command.written[self.index] = True


def test_controller_exception_holds_joints_and_starts_fallback(make_engine: MakeEngine) -> None:
    engine = make_engine({"controllers": {"safe": {"type": "forward_command", "params": {"joints": ["a"]}}}})
    engine.add_controller("boom", "test", Exploding(engine.controller_context("boom"), ["a"], 0.1), ["safe"])
    assert engine.switch(["boom"], []).ok
    guard = JumpGuard(engine)
    guard.run(40)
    assert modes(engine)[0] == "controlled"
    guard.run(30)  # it explodes at t = 0.1
    status = engine.status()
    boom = next(c for c in status["controllers"] if c["name"] == "boom")
    assert boom["state"] == "failed" and "ZeroDivisionError: bug" in boom["error"]
    assert next(c for c in status["controllers"] if c["name"] == "safe")["state"] == "active"
    assert modes(engine)[0] == "hold"  # the fallback has no command yet: held
    text = "\n".join(events(engine))
    assert "update raised ZeroDivisionError: bug; deactivated, joints ['a'] held" in text
    assert "fallbacks of boom ('safe',): activated" in text
    held = engine.state.position[0]
    guard.run(100)
    assert engine.state.position[0] == pytest.approx(held, abs=1e-3)


def test_non_finite_command_never_reaches_the_drive(make_engine: MakeEngine) -> None:
    engine = make_engine()

    class NaNController(Exploding):
        def update(self, t, dt, state, command):
            command.position[self.index] = np.nan
            command.written[self.index] = True

    engine.add_controller("nan", "test", NaNController(engine.controller_context("nan"), ["b"], 0.0))
    engine.switch(["nan"], [])
    JumpGuard(engine).run(10)
    assert np.isfinite(engine.hardware[0].component.last_command.position).all()
    assert engine.manager.records["nan"].state == "failed"
    assert modes(engine)[1] == "hold"


def test_strict_switch_refuses_conflicts_and_unknowns(make_engine: MakeEngine) -> None:
    engine = make_engine({"controllers": {"fwd_a": {"type": "forward_command", "params": {"joints": ["a"]}}}})
    result = engine.switch(["fwd", "fwd_a"], [])
    assert not result.ok and "claimed by both" in result.error
    assert engine.manager.records["fwd"].state == "inactive"
    result = engine.switch(["ghost"], [])
    assert not result.ok and "unknown controller 'ghost'" in result.error
    result = engine.switch([], ["fwd"])
    assert not result.ok and "fwd is not active" in result.error
    best = engine.switch(["fwd", "fwd_a", "ghost"], [], strict=False)
    assert best.ok and best.activated == ["fwd"] and "fwd_a" in best.error and "ghost" in best.error


def test_failed_activation_rolls_the_whole_switch_back(make_engine: MakeEngine) -> None:
    engine = make_engine(
        {
            "controllers": {
                "fwd_a": {"type": "forward_command", "params": {"joints": ["a"]}},
                "fwd_ab": {"type": "forward_command", "params": {"joints": ["a", "b"]}},
            }
        }
    )
    engine.switch(["fwd_a"], [])

    class Refuses(Exploding):
        def on_activate(self, state, last_command):
            raise RuntimeError("drive not homed")

    engine.add_controller("refuses", "test", Refuses(engine.controller_context("refuses"), ["c"], 1e9))
    result = engine.switch(["fwd_ab", "refuses"], ["fwd_a"])
    assert not result.ok and "drive not homed" in result.error and "rolled back" in result.error
    states = {c["name"]: c["state"] for c in engine.status()["controllers"]}
    assert states == {
        "jsb": "active",
        "fwd": "inactive",
        "fwd_a": "active",
        "fwd_ab": "inactive",
        "refuses": "inactive",
    }
    assert engine.status()["joints"][0]["owner"] == "fwd_a"


def test_soft_position_limit_clamps_and_reports(make_engine: MakeEngine) -> None:
    engine = make_engine()
    engine.switch(["fwd"], [])
    events(engine)
    for _ in range(600):
        send(engine, "fwd", [1.0, 0.0, 0.0])  # the hard limit; soft limit is 0.95
        engine.run_cycles(1)
    assert engine.final.position[0] == pytest.approx(0.95)
    assert engine.status()["joints"][0]["limits"] == ["position"]
    assert any("joint a: position limit engaged" in e for e in events(engine))


def test_effort_limit_trims_the_predicted_torque(make_engine: MakeEngine) -> None:
    engine = make_engine({"joints": {"a": {"limits": {"effort": 0.2}}}})
    engine.switch(["fwd"], [])
    events(engine)
    send(engine, "fwd", [0.9, -0.2, 0.3])
    engine.run_cycles(1)
    cmd, q = engine.final, engine.state
    tau = cmd.kp * (cmd.position - q.position) + cmd.kd * (cmd.velocity - q.velocity) + cmd.effort
    assert abs(tau[0]) == pytest.approx(0.2)
    assert any("joint a: effort limit engaged" in e for e in events(engine))


def test_stale_feedback_faults_after_the_configured_cycles(make_engine: MakeEngine) -> None:
    engine = make_engine({"safety": {"stale_feedback_cycles": 5}})
    mock = engine.hardware[0].component
    mock.silent[1] = True
    engine.run_cycles(4)
    assert modes(engine)[1] == "hold"
    engine.run_cycles(1)
    assert modes(engine)[1] == "fault"
    assert engine.status()["mode"] == "fault"
    assert "no feedback for 5 cycles" in engine.status()["joints"][1]["fault"]
    mock.silent[1] = False
    engine.run_cycles(10)
    assert modes(engine)[1] == "fault"  # latched until reset
    engine.reset()
    engine.run_cycles(1)
    assert modes(engine) == ["hold"] * 3


def test_drive_fault_and_read_failure(make_engine: MakeEngine) -> None:
    engine = make_engine()
    mock = engine.hardware[0].component
    mock.fault_codes[2] = 0x0D
    engine.run_cycles(1)
    assert engine.status()["joints"][2]["fault"] == "bus: drive fault code 0xd"
    mock.read_error = "CAN bus off"
    engine.run_cycles(1)
    status = engine.status()
    assert status["hardware"][0]["state"] == "fault"
    assert all(j["mode"] == "fault" for j in status["joints"])
    mock.read_error = None
    mock.health_problem = "still off"
    assert "still faulted" in engine.reset()["error"]
    mock.health_problem = None
    assert engine.reset()["cleared"]
    engine.run_cycles(1)
    assert engine.status()["mode"] == "hold"


def test_estop_stops_controllers_and_only_reset_leaves_it(make_engine: MakeEngine) -> None:
    engine = make_engine()
    engine.switch(["fwd"], [])
    guard = JumpGuard(engine)
    for _ in range(20):
        send(engine, "fwd", [0.6, 0.6, 0.6])
        guard.run(1)
    assert engine.estop() == {"deactivated": ["fwd"]}
    guard.run(1)
    assert engine.status()["mode"] == "estop"
    assert modes(engine) == ["estop"] * 3
    stopped_at = engine.state.position.copy()
    refused = engine.switch(["fwd"], [])
    assert not refused.ok and "e-stop is engaged" in refused.error
    guard.run(100)
    np.testing.assert_allclose(engine.state.position, stopped_at, atol=0.01)
    assert engine.reset()["cleared"] == ["e-stop"]
    guard.run(1)
    assert engine.status()["mode"] == "hold"
    assert engine.switch(["fwd"], []).ok


def test_estop_damp_action(make_engine: MakeEngine) -> None:
    engine = make_engine({"safety": {"estop_action": "damp"}})
    engine.estop()
    engine.run_cycles(1)
    np.testing.assert_allclose(engine.final.kp, 0.0)
    np.testing.assert_allclose(engine.final.kd, 5.0)


def test_position_beyond_hard_limits_faults(make_engine: MakeEngine) -> None:
    """A reading beyond the hard limits (and their margin) is rejected like a missing one: the joint has no
    trusted position, so it is damped — pulled neither in nor toward the reading — and faults after the stale
    bound with a text that names the limits."""
    engine = make_engine({"hardware": {"bus": {"params": {"initial_positions": {"a": 1.2}}}}})
    stale = engine.supervisor.safety.stale_feedback_cycles
    engine.run_cycles(stale - 1)
    assert engine.status()["joints"][0]["fault"] is None
    assert engine.final.kp[0] == 0.0 and engine.final.kd[0] > 0.0  # damped from the first cycle
    engine.run_cycles(1)
    fault = engine.status()["joints"][0]["fault"]
    assert fault.startswith(f"implausible feedback for {stale} cycles: position 1.2 rad outside the hard limits")
    assert engine.supervisor.fault[0] == Fault.POSITION_LIMIT
    assert engine.final.kp[0] == 0.0  # still no spring toward any position


def test_transmissions_map_joint_and_actuator_space(make_engine: MakeEngine) -> None:
    engine = make_engine({"hardware": {"bus": {"joints": {"b": {"reduction": 4.0, "direction": -1, "offset": 0.1}}}}})
    mock = engine.hardware[0].component
    # actuator -0.2 → joint -(-0.2)/4 + 0.1 = 0.15
    assert engine.state.position[1] == pytest.approx(0.15)
    engine.run_cycles(1)
    assert mock.last_command.position[1] == pytest.approx(-0.2)
    assert mock.last_command.kp[1] == pytest.approx(100.0 / 16)


def test_broadcaster_publishes_at_its_rate(make_engine: MakeEngine) -> None:
    from hild.crossing.ring import RingReader

    engine = make_engine()
    reader = RingReader(engine.manager.records["jsb"].instance.ring, start_at_head=False)
    engine.run_cycles(500)  # 1 s at 500 Hz, 100 Hz publish rate
    samples = reader.read()
    assert len(samples) in (100, 101)
    stamps = [s[1] for s in samples]
    assert np.allclose(np.diff(stamps), 0.01)
    assert samples[-1][2]["position"] == pytest.approx([0.1, -0.2, 0.3])


def test_forward_command_rejects_bad_input(make_engine: MakeEngine) -> None:
    engine = make_engine()
    fwd = engine.manager.records["fwd"].instance
    with pytest.raises(ValueError, match="not active"):
        fwd.accept({"values": [0, 0, 0]})
    engine.switch(["fwd"], [])
    for payload, reason in [
        ([0, 0, 0], "expected an object"),
        ({"values": [0, 0]}, "expected 3 values"),
        ({"values": [0, 0, "x"]}, "must be numbers"),
        ({"values": [0, 0, float("nan")]}, "finite"),
        ({"values": [0, 0, 7.0]}, "outside"),
        ({"values": [0, 0, 0], "extra": 1}, "expected an object"),
    ]:
        with pytest.raises(ValueError, match=reason):
            fwd.accept(payload)
    engine.run_cycles(10)
    assert modes(engine) == ["hold"] * 3


def test_estop_is_never_refused_even_with_a_full_request_queue(make_engine: MakeEngine) -> None:
    from hild.crossing.requests import Refused
    from hild.cycle.engine import REQUEST_QUEUE

    engine = make_engine()
    engine.switch(["fwd"], [])
    queued = [engine.submit(lambda: None) for _ in range(REQUEST_QUEUE)]
    with pytest.raises(Refused):
        engine.submit(lambda: None).result(timeout=0)
    stop = engine.request_estop()
    assert not stop.done()
    engine.run_cycles(1)
    assert stop.result(timeout=0) == {"deactivated": ["fwd"]}
    assert engine.status()["mode"] == "estop"
    assert all(f.done() for f in queued)


def test_a_reset_sent_before_an_estop_took_effect_never_clears_it(make_engine: MakeEngine) -> None:
    """Found when the two crossed processes: resets already queued when an e-stop arrives were applied right after
    it, in the same cycle, and cleared it."""
    from hild.crossing.requests import Refused, Reset

    engine = make_engine()
    engine.switch(["fwd"], [])
    resets = [engine.request(Reset()) for _ in range(3)]
    stop = engine.request_estop()
    engine.run_cycles(1)
    assert stop.result(timeout=0) == {"deactivated": ["fwd"]}
    for reset in resets:
        with pytest.raises(Refused, match="an e-stop took effect after this reset was sent"):
            reset.result(timeout=0)
    engine.run_cycles(5)
    assert engine.status()["mode"] == "estop"
    later = engine.request(Reset())  # sent after: it clears the e-stop
    engine.run_cycles(1)
    assert later.result(timeout=0)["cleared"] == ["e-stop"]


def test_a_reset_sent_once_the_estop_was_answered_is_applied(make_engine: MakeEngine) -> None:
    """Found beside two busy processes (tests/api/test_teach.py::test_refusals): the operator's reset, sent once the
    e-stop's reply came, was refused as "an e-stop took effect after this reset was sent". The e-stop was answered
    before the requests of its own cycle were taken, so a reset that arrived in between was taken for one sent
    before it. A done-callback sends the reset the moment the e-stop is answered, as a fast client would."""
    from hild.crossing.requests import Reset

    engine = make_engine()
    engine.switch(["fwd"], [])
    resets: list[Any] = []
    stop = engine.request_estop()
    stop.add_done_callback(lambda _: resets.append(engine.request(Reset())))
    engine.run_cycles(1)
    assert stop.result(timeout=0) == {"deactivated": ["fwd"]} and len(resets) == 1
    engine.run_cycles(1)
    assert resets[0].result(timeout=0)["cleared"] == ["e-stop"]
    assert engine.status()["mode"] == "hold"


def test_a_reset_waiting_for_its_drives_is_refused_by_an_estop(make_engine: MakeEngine) -> None:
    from hild.crossing.requests import Refused
    from hild.cycle.engine import Deferred

    engine = make_engine()
    waiting = engine.submit(lambda: Deferred(lambda: None), clears_estop=True)  # its drives never confirm
    engine.run_cycles(1)  # applied: it now waits for its drives
    assert not waiting.done()
    engine.request_estop()
    engine.run_cycles(1)
    with pytest.raises(Refused, match="an e-stop took effect after this reset was sent"):
        waiting.result(timeout=0)
    assert engine.status()["mode"] == "estop"


def test_take_inputs_runs_first_in_every_cycle_and_a_failing_one_is_switched_off(make_engine: MakeEngine) -> None:
    engine = make_engine()
    assert engine.switch(["fwd"], []).ok
    taken: list[int] = []

    def take_inputs() -> None:  # as the API's does: hand a streamed command over before the controllers run
        taken.append(engine.cycle)
        send(engine, "fwd", [0.2, -0.2, 0.3])

    engine.take_inputs = take_inputs
    engine.run_cycles(1)
    assert modes(engine) == ["controlled"] * 3  # the controller used it in the cycle that took it
    engine.run_cycles(2)
    assert taken == [engine.cycle - 2, engine.cycle - 1, engine.cycle]

    def broken() -> None:
        raise RuntimeError("bug")

    events(engine)
    engine.take_inputs = broken
    engine.run_cycles(2)  # the cycle goes on
    assert engine.take_inputs is None
    assert [e for e in events(engine) if "taking the inputs failed, and is off: RuntimeError: bug" in e]
