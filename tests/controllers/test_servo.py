"""The servo controller in lockstep: hold on activation, limits under a jittery stream, clamping, timeout, dead
reckoning at the soft limits, planning errors and every rejection reason. Mock robot and the arm6 twin."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from ruckig import ControlInterface, InputParameter, OutputParameter, Result, Ruckig, RuckigError, Synchronization

from hild.config import ConfigError, load_config
from hild.controllers.servo import (
    CLAMP_EVENT_QUIET,
    POSITION_MARGIN,
    Phase,
    ServoController,
    ServoParams,
    ServoTarget,
    speed_to_stop_within,
    stopping_distance,
)
from hild.crossing.requests import SetParams
from hild.cycle.engine import Engine
from tests.conftest import merge, mock_robot
from tests.test_engine import JumpGuard, events, modes
from tests.test_twin_engine import twin

MakeEngine = Callable[..., Engine]

ACCELERATION, JERK = 8.0, 80.0  # the mock joints' new limits; velocity 2, soft range [-0.95, 0.95]
SOFT = 0.95


def servo_patch(**params: Any) -> dict[str, Any]:
    return {
        "joints": {j: {"limits": {"acceleration": ACCELERATION, "jerk": JERK}} for j in "abc"},
        "controllers": {"servo": {"type": "servo", "params": {"joints": ["a", "b", "c"], **params}}},
    }


def servo_of(engine: Engine, name: str = "servo") -> ServoController:
    instance = engine.manager.records[name].instance
    assert isinstance(instance, ServoController)
    return instance


def started(make_engine: MakeEngine, **params: Any) -> tuple[Engine, ServoController]:
    engine = make_engine(servo_patch(**params))
    assert engine.switch(["servo"], []).ok
    events(engine)  # start-up and switch events are not what these tests look at
    return engine, servo_of(engine)


class LimitProbe:
    """Runs cycles (under a JumpGuard) and checks every commanded sample of the servo's joints against the limits.

    Velocity is the commanded feed-forward and the first difference of the commanded position; acceleration and
    jerk are the second and third differences, which for a jerk-limited trajectory are weighted averages of the
    true acceleration and jerk, so they obey the same bounds.
    """

    SLACK = 1e-6

    def __init__(self, engine: Engine, servo: ServoController, scale_v: float = 1.0, scale_a: float = 1.0) -> None:
        self.engine = engine
        self.index = servo._index
        lim = engine.limits
        self.vmax = lim.velocity[self.index] * scale_v
        self.amax = lim.acceleration[self.index] * scale_a
        self.jmax = lim.jerk[self.index] * scale_a
        self.guard = JumpGuard(engine)
        self.history: list[np.ndarray] = []
        self.peak = {"velocity": 0.0, "acceleration": 0.0, "jerk": 0.0}  # fraction of the limit reached

    def run(self, cycles: int) -> None:
        dt = self.engine.period
        for _ in range(cycles):
            self.guard.run(1)
            cmd = self.engine.command
            if not cmd.written[self.index].all():
                self.history.clear()
                continue
            p = cmd.position[self.index].copy()
            h = self.history
            self._check("velocity", np.abs(cmd.velocity[self.index]), self.vmax)
            if h:
                self._check("velocity", np.abs(p - h[-1]) / dt, self.vmax)
            if len(h) >= 2:
                self._check("acceleration", np.abs(p - 2 * h[-1] + h[-2]) / dt**2, self.amax)
            if len(h) >= 3:
                self._check("jerk", np.abs(p - 3 * h[-1] + 3 * h[-2] - h[-3]) / dt**3, self.jmax)
            h.append(p)
            del h[:-3]

    def _check(self, what: str, value: np.ndarray, limit: np.ndarray) -> None:
        ratio = float((value / limit).max())
        assert ratio <= 1.0 + self.SLACK, f"{what} {value} beyond {limit} at t={self.engine.t}"
        self.peak[what] = max(self.peak[what], ratio)


def limit_events(engine: Engine) -> list[str]:
    return [e for e in events(engine) if "limit engaged" in e]


# ---- config ---------------------------------------------------------------------------------------------------
def test_config_without_acceleration_or_jerk_names_each_joint(write_config: Callable[..., Path]) -> None:
    cfg = merge(mock_robot(), servo_patch())
    cfg["joints"]["b"]["limits"].pop("jerk")
    cfg["joints"]["c"]["limits"].pop("acceleration")
    with pytest.raises(ConfigError) as info:
        load_config(write_config(cfg))
    text = str(info.value)
    assert "servo needs limits.acceleration and limits.jerk for joint b to plan its motion" in text
    assert "servo needs limits.acceleration and limits.jerk for joint c to plan its motion" in text
    assert "joint a" not in text


def test_config_with_the_limits_loads_and_claims_position_and_velocity(write_config: Callable[..., Path]) -> None:
    loaded = load_config(write_config(merge(mock_robot(), servo_patch())))
    params = loaded.controller_params["servo"]
    assert isinstance(params, ServoParams) and params.command_timeout == 0.5
    assert ServoController.claims_for(params) == [f"{j}/{f}" for j in "abc" for f in ("position", "velocity")]
    position_only = ServoParams(joints=["a"], command_interfaces=["position"])
    assert ServoController.claims_for(position_only) == ["a/position"]


@pytest.mark.parametrize(
    ("params", "reason"),
    [
        ({"joints": []}, "at least 1 item"),
        ({"joints": ["a", "a"]}, "joints listed twice"),
        ({"joints": ["a"], "command_interfaces": ["velocity"]}, "[position, velocity] or [position]"),
        ({"joints": ["a"], "command_interfaces": ["position", "position"]}, "[position, velocity] or [position]"),
        ({"joints": ["a"], "command_interfaces": ["effort"]}, "'position' or 'velocity'"),
        ({"joints": ["a"], "velocity_scale": 0.0}, "greater than 0"),
        ({"joints": ["a"], "acceleration_scale": 1.5}, "less than or equal to 1"),
        ({"joints": ["a"], "command_timeout": 0.0}, "greater than 0"),
    ],
)
def test_bad_params_are_rejected_with_a_reason(params: dict[str, Any], reason: str) -> None:
    with pytest.raises(ValueError) as info:
        ServoParams.model_validate(params)
    assert reason in str(info.value)


def test_built_at_run_time_without_the_limits_it_refuses(make_engine: MakeEngine) -> None:
    engine = make_engine()  # the plain mock robot: no acceleration or jerk limits
    with pytest.raises(ValueError, match=r"needs limits.acceleration and limits.jerk for joints \['a'\]"):
        engine.load_controller("servo", "servo", {"joints": ["a"]})


# ---- the braking formulas -------------------------------------------------------------------------------------
@pytest.mark.parametrize("speed", [0.05, 0.3, 0.8, 1.5, 3.0])
def test_stopping_distance_is_what_ruckig_needs_to_stop(speed: float) -> None:
    otg, inp, out = Ruckig(1, 0.001), InputParameter(1), OutputParameter(1)
    inp.control_interface = ControlInterface.Velocity
    inp.current_position, inp.current_velocity, inp.current_acceleration = [0.0], [speed], [0.0]
    inp.target_velocity, inp.target_acceleration = [0.0], [0.0]
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = [10.0], [ACCELERATION], [JERK]
    assert otg.update(inp, out) == Result.Working
    travelled = out.trajectory.at_time(out.trajectory.duration)[0][0]
    assert stopping_distance(speed, ACCELERATION, JERK) == pytest.approx(travelled, rel=1e-9)
    assert speed_to_stop_within(travelled, ACCELERATION, JERK) == pytest.approx(speed, rel=1e-9)


def test_speed_to_stop_within_is_zero_without_room() -> None:
    assert speed_to_stop_within(0.0, ACCELERATION, JERK) == 0.0
    assert speed_to_stop_within(-0.1, ACCELERATION, JERK) == 0.0


# ---- activation -----------------------------------------------------------------------------------------------
def test_it_reports_reading_the_position_of_its_joints_only(make_engine: MakeEngine) -> None:
    """What list_controllers reports as its required state interfaces: the measured position it starts from and
    follows, never velocity (it does not read it)."""
    engine = make_engine(servo_patch(joints=["a", "c"]))
    assert servo_of(engine).state_interfaces() == ["a/position", "c/position"]
    (entry,) = [c for c in engine.snapshot().controllers if c["name"] == "servo"]
    assert entry["state_interfaces"] == ["a/position", "c/position"]


def test_activation_holds_where_the_joints_are(make_engine: MakeEngine) -> None:
    engine, servo = started(make_engine)
    start = engine.state.position.copy()
    JumpGuard(engine).run(300)  # longer than command_timeout: no target, so nothing to time out either
    np.testing.assert_array_equal(engine.command.position, start)
    np.testing.assert_array_equal(engine.command.velocity, 0.0)
    np.testing.assert_array_equal(engine.state.position, start)
    assert servo.phase == Phase.HOLD
    assert modes(engine) == ["controlled"] * 3
    assert events(engine) == []


def test_a_target_sent_before_activation_is_refused_and_never_applied(make_engine: MakeEngine) -> None:
    engine = make_engine(servo_patch())
    servo = servo_of(engine)
    with pytest.raises(ValueError, match="controller servo is not active"):
        servo.accept({"positions": [0.5, 0.5, 0.5]})
    servo._slot.put(ServoTarget([0.5, 0.5, 0.5], [0.0] * 3, False, ""))  # one that slipped in before a switch
    assert engine.switch(["servo"], []).ok
    start = engine.state.position.copy()
    engine.run_cycles(100)
    np.testing.assert_array_equal(engine.command.position, start)


# ---- streaming ------------------------------------------------------------------------------------------------
def jittery_stream(
    engine: Engine,
    servo: ServoController,
    probe: LimitProbe,
    path: Callable[[float], np.ndarray],
    seconds: float,
    rng: np.random.Generator,
    noise: float,
    rate: Callable[[float], np.ndarray] | None = None,
) -> None:
    """Targets from ``path`` plus noise (and velocities from ``rate``), with random gaps of 0–60 ms (0: several
    targets in one cycle, of which the cycle sees the last)."""
    end, n = engine.t + seconds, len(servo._index)
    while engine.t < end:
        for _ in range(int(rng.integers(1, 3))):
            target = {"positions": (path(engine.t) + rng.normal(0.0, noise, n)).tolist()}
            if rate is not None:
                target["velocities"] = (rate(engine.t) + rng.normal(0.0, 10 * noise, n)).tolist()
            servo.accept(target)
        probe.run(int(rng.integers(0, 31)) or 1)


def test_jittery_stream_stays_within_the_scaled_limits_and_converges(make_engine: MakeEngine) -> None:
    engine, servo = started(make_engine, velocity_scale=0.8, acceleration_scale=0.5, command_timeout=0.2)
    probe = LimitProbe(engine, servo, 0.8, 0.5)
    rng = np.random.default_rng(7)
    start = engine.state.position.copy()
    phase = np.array([0.0, 1.0, 2.0])

    def path(t: float) -> np.ndarray:
        return start + 0.5 * np.sin(4.0 * t + phase)

    jittery_stream(engine, servo, probe, path, 3.0, rng, noise=0.01)
    final = np.array([0.6, -0.6, 0.2])
    for _ in range(100):  # the stream ends on a fixed target, still with gaps
        servo.accept({"positions": final.tolist()})
        probe.run(int(rng.integers(1, 31)))
    assert probe.peak["velocity"] > 0.5 and probe.peak["acceleration"] > 0.5 and probe.peak["jerk"] > 0.5
    np.testing.assert_allclose(engine.command.position, final, atol=1e-9)
    np.testing.assert_allclose(engine.state.position, final, atol=1e-9)
    assert limit_events(engine) == []  # the supervisor never had to step in


def test_arm6_twin_follows_a_jittery_stream_within_limits_and_settles_on_the_target() -> None:
    engine = twin("arm6_twin.yaml")
    engine.load_controller("stream", "servo", {"joints": list(engine.joints), "velocity_scale": 0.5})
    assert engine.switch(["stream"], []).ok
    servo = servo_of(engine, "stream")
    probe = LimitProbe(engine, servo, 0.5, 1.0)
    rng = np.random.default_rng(11)
    start = engine.state.position.copy()
    amplitude = np.array([0.6, 0.3, 0.4, 0.5, 0.5, 0.8])

    def path(t: float) -> np.ndarray:
        return start + amplitude * np.sin(2.0 * t + np.arange(6))

    def rate(t: float) -> np.ndarray:
        return 2.0 * amplitude * np.cos(2.0 * t + np.arange(6))

    jittery_stream(engine, servo, probe, path, 4.0, rng, noise=0.005, rate=rate)
    final = start + np.array([0.3, -0.2, 0.25, 0.2, -0.3, 0.4])
    for _ in range(60):
        servo.accept({"positions": final.tolist()})
        probe.run(int(rng.integers(1, 31)))
    probe.run(250)  # silence: timeout, already at rest, then hold
    assert probe.peak["velocity"] > 0.5
    np.testing.assert_allclose(engine.command.position, final, atol=1e-9)
    assert np.abs(engine.state.position - final).max() < 3e-3
    assert modes(engine) == ["controlled"] * 6
    assert limit_events(engine) == []


def test_full_speed_moves_never_trip_the_supervisors_limits(make_engine: MakeEngine) -> None:
    engine, servo = started(make_engine)
    probe = LimitProbe(engine, servo)
    for target in ([0.94, -0.94, -0.94], [-0.94, 0.94, 0.94], [0.0, 0.0, 0.0]):
        for _ in range(80):
            servo.accept({"positions": target})
            probe.run(10)
        np.testing.assert_allclose(engine.command.position, target, atol=1e-12)
    assert probe.peak["velocity"] == pytest.approx(1.0, abs=1e-5)  # cruised at the velocity limit
    assert probe.peak["acceleration"] == pytest.approx(1.0, abs=1e-3)
    assert limit_events(engine) == [] and engine.status()["joints"][0]["limits"] == []


def test_targets_outside_the_soft_limits_are_clamped_with_one_event_per_episode(make_engine: MakeEngine) -> None:
    engine, servo = started(make_engine, command_timeout=1.0)
    probe = LimitProbe(engine, servo)
    for _ in range(300):  # 1.8 s: c has 1.25 rad to go
        servo.accept({"positions": [3.0, -0.2, -7.0]})
        probe.run(3)
    np.testing.assert_allclose(engine.command.position, [SOFT - POSITION_MARGIN, -0.2, -SOFT + POSITION_MARGIN])
    clamped = [e for e in events(engine) if "target clamped" in e]
    assert clamped == [
        "warning:servo:target clamped: a position 3 → 0.95 (soft limit); c position -7 → -0.95 (soft limit)"
    ]
    for _ in range(int(CLAMP_EVENT_QUIET / (3 * engine.period)) + 5):  # back in range for longer than the quiet time
        servo.accept({"positions": [0.5, -0.2, 0.0]})
        probe.run(3)
    assert events(engine) == []
    for _ in range(10):  # a new episode: reported once more
        servo.accept({"positions": [0.5, 1.5, 0.0]})
        probe.run(3)
    assert [e for e in events(engine) if "target clamped" in e] == [
        "warning:servo:target clamped: b position 1.5 → 0.95 (soft limit)"
    ]
    assert limit_events(engine) == []


def test_targets_right_at_the_limits_are_not_reported(make_engine: MakeEngine) -> None:
    engine, servo = started(make_engine, velocity_scale=0.5)
    servo.accept({"positions": [SOFT, -SOFT, 0.0], "velocities": [0.0, 0.0, 1.0]})  # 1.0 = 0.5 × 2 rad/s
    servo.accept({"positions": [SOFT, -SOFT, 0.0], "velocities": [0.0, 0.0, -1.0]})
    engine.run_cycles(1)
    assert events(engine) == []
    assert servo._inp.target_position == pytest.approx([SOFT, -SOFT, 0.0], abs=2 * POSITION_MARGIN)


def test_velocities_beyond_the_scaled_limit_are_clamped(make_engine: MakeEngine) -> None:
    engine, servo = started(make_engine, velocity_scale=0.5)
    servo.accept({"positions": [0.0, 0.0, 0.0], "velocities": [5.0, -0.2, 0.0]})
    LimitProbe(engine, servo, 0.5).run(1)
    (event,) = events(engine)
    assert "a velocity 5 → 1 (velocity limit)" in event
    assert servo._inp.target_velocity[0] == pytest.approx(1.0, rel=1e-5)
    assert servo._inp.target_velocity[1] == -0.2


def test_a_velocity_toward_a_near_soft_limit_is_reduced_so_the_joint_can_still_stop(make_engine: MakeEngine) -> None:
    engine, servo = started(make_engine, command_timeout=2.0)
    servo.accept({"positions": [0.9, -0.2, 0.3], "velocities": [2.0, 0.0, 0.0]})
    probe = LimitProbe(engine, servo)
    probe.run(1)
    (event,) = events(engine)
    assert "a velocity 2 → " in event and "(to stop before the soft limit)" in event
    reduced = servo._inp.target_velocity[0]
    assert 0.0 < reduced < 2.0
    assert stopping_distance(reduced, ACCELERATION, JERK) < SOFT - 0.9
    for _ in range(500):
        probe.run(1)
        assert engine.command.position[0] <= SOFT
    assert engine.command.position[0] > 0.9 and engine.command.velocity[0] == 0.0
    assert limit_events(engine) == []


# ---- dead reckoning -------------------------------------------------------------------------------------------
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_a_reached_velocity_target_keeps_moving_then_brakes_before_the_soft_limit(
    make_engine: MakeEngine, sign: float
) -> None:
    engine, servo = started(make_engine, command_timeout=3.0)
    probe = LimitProbe(engine, servo)
    servo.accept({"positions": [0.0, -0.2, 0.3], "velocities": [sign * 1.0, 0.0, 0.0]})
    probe.run(1)
    while servo.phase == Phase.TRACK:
        probe.run(1)
    assert servo.phase == Phase.CRUISE
    reached = engine.command.position[0]
    assert sign * reached >= 0.0 and engine.command.velocity[0] == pytest.approx(sign * 1.0, rel=1e-5)
    probe.run(100)  # 0.2 s later: still going at the target's velocity
    assert engine.command.position[0] == pytest.approx(reached + sign * 0.2, abs=1e-6)
    np.testing.assert_allclose(engine.command.position[1:], [-0.2, 0.3])  # the others hold their target
    trace = []
    for _ in range(1000):  # 2 s: the limit is 0.75 rad away at 1 rad/s
        probe.run(1)
        trace.append(engine.command.position[0])
    assert max(sign * np.array(trace)) <= SOFT  # never past the soft limit …
    assert sign * trace[-1] > SOFT - 0.01  # … but right up to it, braking in time
    assert engine.command.velocity[0] == 0.0 and trace[-1] == trace[-2]  # and at rest there
    assert servo.phase == Phase.CRUISE and limit_events(engine) == []


def test_dead_reckoning_lasts_no_longer_than_the_command_timeout(make_engine: MakeEngine) -> None:
    engine, servo = started(make_engine, command_timeout=0.3)
    probe = LimitProbe(engine, servo)
    servo.accept({"positions": [0.15, -0.2, 0.3], "velocities": [0.5, 0.0, 0.0]})
    probe.run(1)
    sent = engine.t
    while servo.phase == Phase.TRACK:
        probe.run(1)
    assert servo.phase == Phase.CRUISE and engine.t < sent + 0.2
    while servo.phase == Phase.CRUISE:
        probe.run(1)
    assert servo.phase == Phase.STOP
    assert sent + 0.3 < engine.t <= sent + 0.3 + 1.5 * engine.period
    assert [e for e in events(engine) if "no target" in e] == [
        "warning:servo:no target for 0.3 s: stopping, then holding"
    ]


# ---- timeout --------------------------------------------------------------------------------------------------
def test_timeout_stops_within_the_jerk_limited_time_holds_then_resumes_without_a_jump(make_engine: MakeEngine) -> None:
    timeout = 0.5
    engine, servo = started(make_engine, command_timeout=timeout)
    probe = LimitProbe(engine, servo)
    velocities = np.array([0.8, -0.5, 0.2])
    servo.accept({"positions": [0.25, -0.25, 0.32], "velocities": velocities.tolist()})
    probe.run(1)
    sent = engine.t
    while servo.phase == Phase.TRACK:  # the joints reach the target …
        probe.run(1)
    while engine.t < sent + timeout - 1e-9:  # … and cruise on through the silence
        probe.run(1)
    assert servo.phase == Phase.CRUISE
    np.testing.assert_allclose(engine.command.velocity, velocities, rtol=1e-5)
    assert events(engine) == []
    probe.run(1)
    assert servo.phase == Phase.STOP
    assert events(engine) == [f"warning:servo:no target for {timeout:g} s: stopping, then holding"]
    # Jerk-limited stop from cruise (a = 0): 2·sqrt(v/j) below a²/j, else v/a + a/j.
    bound = max(
        2 * math.sqrt(v / JERK) if v * JERK <= ACCELERATION**2 else v / ACCELERATION + ACCELERATION / JERK
        for v in np.abs(velocities)
    )
    cycles = 0
    while servo.phase == Phase.STOP:
        probe.run(1)
        cycles += 1
    assert (cycles - 1) * engine.period <= bound
    assert servo.phase == Phase.HOLD
    stopped = engine.command.position.copy()
    np.testing.assert_array_equal(engine.command.velocity, 0.0)
    probe.run(500)
    np.testing.assert_array_equal(engine.command.position, stopped)
    assert events(engine) == []  # one event per timeout
    for _ in range(60):  # a new stream: resumes from rest, smoothly (the probe checks every sample)
        servo.accept({"positions": [0.5, 0.5, -0.5]})
        probe.run(10)
    np.testing.assert_allclose(engine.command.position, [0.5, 0.5, -0.5], atol=1e-12)


def test_timeout_mid_motion_decelerates_smoothly_from_full_speed(make_engine: MakeEngine) -> None:
    engine, servo = started(make_engine, command_timeout=0.3)
    probe = LimitProbe(engine, servo)
    servo.accept({"positions": [0.9, -0.9, 0.9]})  # far: still accelerating or cruising at the timeout
    while servo.phase != Phase.STOP:
        probe.run(1)
    assert engine.t == pytest.approx(0.3 + 2 * engine.period)
    moving = np.abs(engine.command.velocity).max()
    assert moving > 1.0
    while servo.phase == Phase.STOP:
        probe.run(1)
    assert servo.phase == Phase.HOLD and not np.allclose(engine.command.position, [0.9, -0.9, 0.9], atol=0.05)
    assert probe.peak["jerk"] > 0.5 and limit_events(engine) == []


def test_a_new_target_while_stopping_resumes_from_the_current_state(make_engine: MakeEngine) -> None:
    engine, servo = started(make_engine, command_timeout=0.2)
    probe = LimitProbe(engine, servo)
    servo.accept({"positions": [0.9, 0.9, -0.9]})
    probe.run(110)
    assert servo.phase == Phase.STOP
    servo.accept({"positions": [-0.5, 0.0, 0.0]})  # reverses mid-stop: the probe checks a, j stay bounded
    probe.run(1)
    assert servo.phase == Phase.TRACK
    probe.run(80)
    for _ in range(20):
        servo.accept({"positions": [-0.5, 0.0, 0.0]})
        probe.run(20)
    np.testing.assert_allclose(engine.command.position, [-0.5, 0.0, 0.0], atol=1e-12)


# ---- interfaces, deactivation ---------------------------------------------------------------------------------
def test_position_only_leaves_velocity_to_the_mode_defaults(make_engine: MakeEngine) -> None:
    engine, servo = started(make_engine, command_interfaces=["position"])
    probe = LimitProbe(engine, servo)
    servo.accept({"positions": [0.5, 0.0, 0.0]})
    probe.run(100)
    assert abs(engine.state.velocity[0]) > 0.5  # moving …
    np.testing.assert_array_equal(engine.final.velocity, 0.0)  # … with no velocity feed-forward
    claimed = {i["name"]: i["claimed_by"] for i in engine.interfaces()}
    assert claimed["a/position"] == "servo" and claimed["a/velocity"] is None


def test_deactivate_mid_motion_holds_and_reactivation_starts_from_the_measured_state(make_engine: MakeEngine) -> None:
    engine, servo = started(make_engine)
    probe = LimitProbe(engine, servo)
    servo.accept({"positions": [0.9, 0.9, -0.9]})
    probe.run(100)
    assert engine.switch([], ["servo"]).ok
    probe.run(50)
    assert modes(engine) == ["hold"] * 3
    with pytest.raises(ValueError, match="not active"):
        servo.accept({"positions": [0.0, 0.0, 0.0]})
    here = engine.state.position.copy()
    assert engine.switch(["servo"], []).ok
    probe.run(50)
    assert servo.phase == Phase.HOLD
    np.testing.assert_array_equal(engine.command.position, here)


def test_the_plan_advances_with_the_cycle_clocks_real_period(make_engine: MakeEngine) -> None:
    """A slightly late or early wall-clock cycle advances the plan by the time that really passed; a cycle later
    than MAX_STEP_PERIODS advances it by that much only (the stream resumes where it was, no catch-up step)."""
    from hild.cycle.engine import MAX_STEP_PERIODS

    engine, servo = started(make_engine, command_timeout=2.0)
    servo.accept({"positions": [0.1, -0.2, 0.3], "velocities": [0.5, 0.0, 0.0]})
    while servo.phase != Phase.CRUISE:
        engine.run_cycles(1)
    engine.run_cycles(5)
    before = engine.command.position[0]
    engine.step(engine.t + 0.003, 0.003)  # a late wall-clock cycle: 1.5 periods at 500 Hz
    assert engine.command.position[0] - before == pytest.approx(0.5 * 0.003, rel=1e-6)
    before = engine.command.position[0]
    engine.step(engine.t + 0.001, 0.001)
    assert engine.command.position[0] - before == pytest.approx(0.5 * 0.001, rel=1e-6)
    before = engine.command.position[0]
    engine.step(engine.t + 0.05, 0.05)  # a stall of 25 periods
    assert engine.command.position[0] - before == pytest.approx(0.5 * MAX_STEP_PERIODS * engine.period, rel=1e-6)


def test_activation_without_a_reading_starts_at_the_last_command(make_engine: MakeEngine) -> None:
    engine = make_engine(servo_patch())
    servo = servo_of(engine)
    state = engine.state
    state.position[1] = math.nan
    last = engine.final
    last.position[:] = [0.11, 0.22, 0.33]
    servo.on_activate(state, last)
    assert servo._p == [state.position[0], 0.22, state.position[2]]
    assert servo._v == [0.0, 0.0, 0.0]


# ---- planning errors ------------------------------------------------------------------------------------------
def test_a_planning_error_stops_with_an_event_and_never_writes_nan(make_engine: MakeEngine) -> None:
    engine, servo = started(make_engine)
    probe = LimitProbe(engine, servo)
    servo.accept({"positions": [0.9, 0.9, -0.9]})
    probe.run(100)
    moving = np.abs(engine.command.velocity).max()
    assert moving > 1.0
    servo._slot.put(ServoTarget([0.0, 0.0, 0.0], [50.0, 0.0, 0.0], True, ""))  # infeasible: past validation
    probe.run(1)
    (event,) = events(engine)
    assert event.startswith("error:servo:ruckig could not plan (") and "exceeds its maximum velocity" in event
    assert servo.phase == Phase.STOP
    while servo.phase == Phase.STOP:
        probe.run(1)
        assert np.isfinite(engine.command.position).all() and np.isfinite(engine.command.velocity).all()
    stopped = engine.command.position.copy()
    probe.run(100)
    np.testing.assert_array_equal(engine.command.position, stopped)
    assert modes(engine) == ["controlled"] * 3  # a planning error is not a controller failure


class BrokenRuckig:
    """Stands in for ruckig when even the stop cannot be planned."""

    delta_time = 0.002

    def update(self, inp: InputParameter, out: OutputParameter) -> Result:
        raise RuckigError("[ruckig] something impossible")

    def reset(self) -> None:
        pass


def test_when_even_the_stop_cannot_be_planned_it_holds_the_last_command(make_engine: MakeEngine) -> None:
    engine, servo = started(make_engine)
    guard = JumpGuard(engine)
    servo.accept({"positions": [0.9, 0.9, -0.9]})
    guard.run(50)
    last = engine.command.position.copy()
    servo._otg = BrokenRuckig()  # type: ignore[assignment]
    guard.run(1)
    assert events(engine) == [
        "error:servo:ruckig could not plan (something impossible): stopping, then holding",
        "error:servo:ruckig could not plan the stop (something impossible): holding",
    ]
    np.testing.assert_array_equal(engine.command.position, last)
    np.testing.assert_array_equal(engine.command.velocity, 0.0)
    guard.run(100)
    np.testing.assert_array_equal(engine.command.position, last)
    assert servo.phase == Phase.HOLD and modes(engine) == ["controlled"] * 3


class NanRuckig(BrokenRuckig):
    """A plan that 'works' but yields a NaN: the output check must catch it."""

    def update(self, inp: InputParameter, out: Any) -> Result:
        return Result.Working


class NanOutput:
    def __init__(self) -> None:
        self.new_position = [math.nan, 0.0, 0.0]
        self.new_velocity = [0.0, 0.0, 0.0]

    def pass_to_input(self, inp: InputParameter) -> None:
        raise AssertionError("a non-finite output must never become the next state")


def test_a_non_finite_plan_output_is_never_written(make_engine: MakeEngine) -> None:
    engine, servo = started(make_engine)
    guard = JumpGuard(engine)
    servo.accept({"positions": [0.9, 0.9, -0.9]})
    guard.run(50)
    last = engine.command.position.copy()
    servo._otg, servo._out = NanRuckig(), NanOutput()  # type: ignore[assignment]
    guard.run(5)
    assert events(engine) == [
        "error:servo:ruckig could not plan (non-finite output): stopping, then holding",
        "error:servo:ruckig could not plan the stop (non-finite output): holding",
    ]
    np.testing.assert_array_equal(engine.command.position, last)
    assert modes(engine) == ["controlled"] * 3


def test_planning_uses_time_synchronised_position_control_then_unsynchronised_stops(make_engine: MakeEngine) -> None:
    engine, servo = started(make_engine, command_timeout=0.1)
    servo.accept({"positions": [0.5, 0.5, 0.5]})
    engine.run_cycles(1)
    assert servo._inp.control_interface == ControlInterface.Position
    assert servo._inp.synchronization == Synchronization.Time
    engine.run_cycles(60)
    assert servo._inp.control_interface == ControlInterface.Velocity
    assert servo._inp.synchronization == Synchronization.No


# ---- bad targets ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("payload", "reason"),
    [
        ([0.1, 0.2, 0.3], 'expected an object {"positions": [...], "velocities"?: [...]}'),
        ("go", 'expected an object {"positions": [...], "velocities"?: [...]}'),
        ({"positions": [0, 0, 0], "speed": 1}, "unknown keys ['speed']; expected positions and optional velocities"),
        ({"velocities": [0, 0, 0]}, "missing positions"),
        ({"positions": None}, "positions must be a list of 3 numbers, not NoneType"),
        ({"positions": {"a": 1}}, "positions must be a list of 3 numbers, not dict"),
        ({"positions": [0.1, 0.2]}, "expected 3 positions for ['a', 'b', 'c']; found 2"),
        ({"positions": [0, 0, 0, 0]}, "expected 3 positions for ['a', 'b', 'c']; found 4"),
        ({"positions": [0.1, "0.2", 0.3]}, "positions[1] (b) is not a number: '0.2'"),
        ({"positions": [0.1, 0.2, [0.3]]}, "positions[2] (c) is not a number: [0.3]"),
        ({"positions": [True, 0.2, 0.3]}, "positions[0] (a) is a boolean; expected a number"),
        ({"positions": [0.1, math.nan, 0.3]}, "positions[1] (b) must be finite, not nan"),
        ({"positions": [0.1, 0.2, -math.inf]}, "positions[2] (c) must be finite, not -inf"),
        ({"positions": [10**400, 0.2, 0.3]}, "positions[0] (a) must be finite, not an integer beyond the float range"),
        ({"positions": [0, 0, 0], "velocities": [0, 0]}, "expected 3 velocities for ['a', 'b', 'c']; found 2"),
        ({"positions": [0, 0, 0], "velocities": "fast"}, "velocities must be a list of 3 numbers, not str"),
        ({"positions": [0, 0, 0], "velocities": [0, False, 0]}, "velocities[1] (b) is a boolean; expected a number"),
        ({"positions": [0, 0, 0], "velocities": [0, 0, math.inf]}, "velocities[2] (c) must be finite, not inf"),
    ],
)
def test_each_bad_target_is_rejected_with_its_reason_and_nothing_moves(
    make_engine: MakeEngine, payload: Any, reason: str
) -> None:
    engine, servo = started(make_engine)
    engine.run_cycles(1)
    start = engine.command.position.copy()
    with pytest.raises(ValueError) as info:
        servo.accept(payload)
    assert str(info.value) == reason
    JumpGuard(engine).run(50)
    np.testing.assert_array_equal(engine.command.position, start)
    assert servo.phase == Phase.HOLD


def test_null_velocities_mean_none_given(make_engine: MakeEngine) -> None:
    engine, servo = started(make_engine, command_timeout=2.0)
    servo.accept({"positions": [0.2, 0.0, 0.0], "velocities": None})
    LimitProbe(engine, servo).run(400)
    np.testing.assert_allclose(engine.command.position, [0.2, 0.0, 0.0], atol=1e-12)
    assert servo.phase == Phase.TRACK  # reached with v = 0: no dead reckoning


def test_a_fault_makes_servo_follow_the_arm_and_reset_resumes_without_a_jump() -> None:
    from hild.cycle.supervisor import Fault
    from tests.test_twin_engine import twin

    engine = twin("arm6_twin.yaml")
    assert engine.switch(["servo"], []).ok
    servo = engine.manager.records["servo"].instance
    guard = JumpGuard(engine)
    target = (engine.state.position + 0.5).tolist()
    for _ in range(100):
        servo.accept({"positions": target})
        guard.run(1)
    engine.supervisor.trip(1, Fault.HARDWARE, "test fault")
    for _ in range(300):
        servo.accept({"positions": target})  # the stream goes on; while faulted it is dropped
        guard.run(1)
    held = engine.state.position.copy()
    assert engine.reset()["cleared"]
    guard.run(300)  # no target since the reset: it rests where the arm was, no jump, no resumed motion
    np.testing.assert_allclose(engine.final.position, held, atol=5e-3)
    assert [j["mode"] for j in engine.status()["joints"]] == ["controlled"] * 6


# ---- parameters at runtime --------------------------------------------------------------------------------------
def _set(probe: LimitProbe, servo: ServoController, **values: float) -> None:
    """Set servo parameters as the client domain does: validated whole, applied between two cycles."""
    future = probe.engine.request(SetParams("servo", servo.params.model_copy(update=values), ("scales",)))
    probe.run(1)
    assert future.result(0)["changed"] == ["scales"]


@pytest.mark.parametrize("phase", [Phase.TRACK, Phase.CRUISE])
def test_lowering_the_scales_while_moving_brakes_to_the_new_limits_without_a_step(
    make_engine: MakeEngine, phase: Phase
) -> None:
    engine, servo = started(make_engine, command_timeout=3.0)
    probe = LimitProbe(engine, servo)  # the old limits bound every step: a step would break acceleration or jerk
    velocity = 1.8 if phase == Phase.CRUISE else 0.0
    servo.accept({"positions": [-0.6, 0.0, 0.0], "velocities": [velocity, 0.0, 0.0]})
    while not (servo.phase == phase and abs(engine.command.velocity[0]) > 1.5):
        probe.run(1)
    _set(probe, servo, velocity_scale=0.25, acceleration_scale=0.5)
    probe.run(400)  # 0.8 s: down from 1.8 rad/s to 0.5 at 4 rad/s² takes 0.3 s and some jerk
    slowed = LimitProbe(engine, servo, scale_v=0.25, scale_a=0.5)
    slowed.run(200)  # from here on, the new limits hold
    assert slowed.peak["velocity"] > 0.9  # still moving, at the new limit
    assert not [e for e in events(engine) if "could not plan" in e or "limit engaged" in e]
    assert servo._inp.max_jerk == servo._jmax  # the lowered jerk was taken once it could be
    assert servo._vlimit[0] == pytest.approx(0.5)  # what clients' targets are now clamped to
