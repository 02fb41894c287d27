"""The servo under a target every cycle, in lockstep at 1 kHz: each joint planned on its own while the stream is
fast, every commanded step within the velocity, acceleration and jerk limits, back to time synchronization for a
slow stream or after a gap, and a repeated target neither re-planned nor timed out."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from ruckig import Synchronization

from hild.controllers.servo import Phase, ServoController
from hild.cycle.engine import Engine
from tests.controllers.test_servo import LimitProbe, limit_events, servo_of, servo_patch
from tests.test_engine import events

MakeEngine = Callable[..., Engine]
RATE = 1000.0
AMPLITUDE = np.array([0.4, 0.1, 0.02])  # rad: the joints move unlike one another, so synchronizing would matter
FREQUENCY = np.array([0.5, 1.0, 2.0])  # Hz; speed ≤ 63 %, acceleration ≤ 49 %, jerk ≤ 50 % of the limits


def started(make_engine: MakeEngine, **params: float) -> tuple[Engine, ServoController]:
    engine = make_engine({**servo_patch(**params), "update_rate": RATE})
    assert engine.switch(["servo"], []).ok
    events(engine)
    return engine, servo_of(engine)


def sine(start: np.ndarray, t: float) -> tuple[list[float], list[float]]:
    """Positions and velocities of a path that leaves ``start`` at rest (t = 0) and swings back to it."""
    w = 2 * math.pi * FREQUENCY
    return (start - AMPLITUDE * (1.0 - np.cos(w * t))).tolist(), (-AMPLITUDE * w * np.sin(w * t)).tolist()


def test_a_1khz_stream_is_planned_per_joint_followed_closely_and_within_every_limit(make_engine: MakeEngine) -> None:
    engine, servo = started(make_engine, command_timeout=0.05)
    probe = LimitProbe(engine, servo)
    start = engine.state.position.copy()
    syncs, errors = [], []
    for k in range(3000):
        positions, velocities = sine(start, engine.t + engine.period)  # the target for the cycle about to run
        servo.accept({"positions": positions, "velocities": velocities})
        probe.run(1)
        syncs.append(servo._inp.synchronization)
        if k >= 500:  # past the start, from rest onto a moving target
            errors.append(np.abs(engine.command.position - sine(start, engine.t)[0]))
    assert syncs[0] == Synchronization.Time and set(syncs[1:]) == {Synchronization.No}  # the first one together
    assert probe.peak["velocity"] > 0.6  # the stream was fast, and followed within the limits all along
    # Each target is planned to be reached at rest in acceleration (ruckig's target acceleration is 0), so a curved
    # path is followed with some lag: here ≤ 0.1 rad on the fastest joint (0.081 measured). Planned together in
    # time (as before), the joints lagged 0.43, 0.11 and 0.033 rad: each re-plan slowed the joints that were not
    # the slowest, and only its first cycle ever ran.
    assert (np.max(errors, axis=0) < [0.1, 0.06, 0.02]).all(), np.max(errors, axis=0)
    probe.run(100)  # the stream stops: brake within the limits, then hold
    assert servo.phase == Phase.HOLD
    assert limit_events(engine) == []


def test_a_slow_stream_and_a_target_after_a_gap_keep_the_joints_synchronized(make_engine: MakeEngine) -> None:
    engine, servo = started(make_engine, command_timeout=0.2)
    probe = LimitProbe(engine, servo)
    start = engine.state.position.copy()
    for _ in range(100):  # 100 Hz: every target plans the joints together in time
        positions, velocities = sine(start, engine.t + engine.period)
        servo.accept({"positions": positions, "velocities": velocities})
        probe.run(1)
        assert servo._inp.synchronization == Synchronization.Time
        probe.run(9)
    # Cycles since the last target: 10 (the slow stream's), then fast, still fast (a jittery 1 kHz stream), a gap.
    for since in (10, 1, 1, 2, 3, 1):
        probe.run(since - 1 if since < 10 else 0)
        positions, velocities = sine(start, engine.t + engine.period)
        servo.accept({"positions": positions, "velocities": velocities})
        probe.run(1)
        expected = Synchronization.No if since <= 2 else Synchronization.Time
        assert servo._inp.synchronization == expected, since
    assert limit_events(engine) == []


def test_the_same_target_again_is_not_replanned_and_keeps_the_stream_alive(make_engine: MakeEngine) -> None:
    engine, servo = started(make_engine, command_timeout=0.05)
    target = {"positions": [0.4, -0.3, 0.2]}
    servo.accept(target)
    engine.run_cycles(1)
    tracked = servo._target_p
    for _ in range(800):  # 16 × the timeout, a target every cycle, always the same: long enough to arrive
        servo.accept(target)
        engine.run_cycles(1)
        assert servo._target_p is tracked  # not handed to ruckig again
    assert servo.phase == Phase.TRACK and events(engine) == []  # no timeout: the stream never stopped
    np.testing.assert_allclose(engine.command.position, target["positions"], atol=1e-9)
    servo.accept({"positions": [0.4, -0.3, 0.25]})  # a new one is planned at once
    engine.run_cycles(1)
    assert servo._target_p == [0.4, -0.3, 0.25]
    for _ in range(400):
        servo.accept({"positions": [0.4, -0.3, 0.25]})
        engine.run_cycles(1)
    np.testing.assert_allclose(engine.command.position, [0.4, -0.3, 0.25], atol=1e-9)


def test_the_same_target_after_a_stop_is_planned_again(make_engine: MakeEngine) -> None:
    engine, servo = started(make_engine, command_timeout=0.05)
    target = {"positions": [0.4, -0.3, 0.2]}
    servo.accept(target)
    engine.run_cycles(300)  # silence past the timeout: stopped short of the target, holding
    assert servo.phase == Phase.HOLD and servo._target_p == target["positions"]
    stopped = engine.command.position.copy()
    assert np.abs(stopped - target["positions"]).max() > 0.1
    for _ in range(800):
        servo.accept(target)
        engine.run_cycles(1)
        assert servo.phase == Phase.TRACK
    np.testing.assert_allclose(engine.command.position, target["positions"], atol=1e-9)
