"""The follow controller in lockstep (the mock robot, the sim clock): mapping with scale and offset, clamping, the
dead-man (release → hold within 2 cycles, silence → hold), degradation (gaps and lost samples slow it down),
stream stop → hold, invalid and reordered leader samples, and never a step beyond v_max·T. The leader is played
by calling the subscription's callable with joint_states messages, as the API hands them over."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hild.config import ConfigError, load_config
from hild.controllers.follow import FollowController, FollowParams
from hild.controllers.servo import Phase, stopping_distance
from hild.cycle.engine import Engine
from hild.modes import Source
from tests.conftest import merge, mock_robot
from tests.controllers.test_servo import ACCELERATION, JERK, SOFT, LimitProbe
from tests.test_engine import events, modes

MakeEngine = Callable[..., Engine]
RATE = 100.0  # Hz: the leader's stream; the mock robot cycles at 500 Hz, so a sample every 5 cycles
EVERY = 5


def follow_patch(**params: Any) -> dict[str, Any]:
    base: dict[str, Any] = {"joints": ["a", "b", "c"], "leader": "lead", "rate": RATE, "command_timeout": 0.25}
    return {
        "joints": {j: {"limits": {"acceleration": ACCELERATION, "jerk": JERK}} for j in "abc"},
        "controllers": {"follow": {"type": "follow", "params": {**base, **params}}},
    }


def started(make_engine: MakeEngine, **params: Any) -> tuple[Engine, FollowController]:
    engine = make_engine(follow_patch(**params))
    assert engine.switch(["follow"], []).ok
    events(engine)
    follow = engine.manager.records["follow"].instance
    assert isinstance(follow, FollowController)
    return engine, follow


class Leader:
    """A leader publishing joint_states every ``EVERY`` cycles: ``position(t)`` per leader joint, its velocity by
    difference; ``lost(seq)`` drops a sample (its seq is used all the same: a gap in seq)."""

    def __init__(
        self,
        engine: Engine,
        follow: FollowController,
        position: Callable[[float], list[float]],
        names: tuple[str, ...] = ("a", "b", "c"),
        every: int = EVERY,
        lost: Callable[[int], bool] = lambda seq: False,
    ) -> None:
        self.engine, self.follow, self.position, self.names = engine, follow, position, names
        self.every, self.lost, self.seq = every, lost, 0
        self.probe = LimitProbe(engine, follow)
        self.sent: list[list[float]] = []

    def message(self, t: float) -> dict[str, Any]:
        p, h = self.position(t), 1e-4
        v = [(b - a) / (2 * h) for a, b in zip(self.position(t - h), self.position(t + h), strict=True)]
        return {"stamp": t, "seq": self.seq, "name": list(self.names), "position": p, "velocity": v}

    def run(self, cycles: int, enable: bool | None = None) -> None:
        for k in range(cycles):
            if k % self.every == 0:
                self.seq += 1
                if not self.lost(self.seq):
                    message = self.message(self.engine.t)
                    self.follow.accept_leader(message)
                    self.sent.append(message["position"])
                if enable is not None:
                    self.follow.accept_enable({"enable": enable})
            self.probe.run(1)


def still(*values: float) -> Callable[[float], list[float]]:
    return lambda t: list(values)


# ---- params ---------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("params", "reason"),
    [
        ({"joints": ["a"], "leader": "l", "joint_map": {"z": {}}}, "not in joints: ['z']"),
        ({"joints": ["a"], "leader": "a/b"}, "a robot name"),
        ({"joints": ["a"], "leader": "l", "rate": 0}, "greater than 0"),
        ({"joints": ["a"], "leader": "l", "joint_map": {"a": {"scale": math.nan}}}, "finite"),
        ({"joints": ["a"]}, "leader"),
    ],
)
def test_bad_params_are_rejected_with_a_reason(params: dict[str, Any], reason: str) -> None:
    with pytest.raises(ValueError, match=None) as info:
        FollowParams.model_validate(params)
    assert reason in str(info.value)


def test_a_config_without_jerk_limits_is_refused(write_config: Callable[..., Path]) -> None:
    cfg = merge(mock_robot(), follow_patch())
    cfg["joints"]["b"]["limits"].pop("jerk")
    with pytest.raises(ConfigError, match="joint b"):
        load_config(write_config(cfg))


def test_it_subscribes_to_the_leaders_joint_states_and_takes_enable(make_engine: MakeEngine) -> None:
    _, follow = started(make_engine)
    assert list(follow.subscriptions()) == ["hild/lead/joint_states"]
    assert list(follow.inputs()) == ["enable"]
    assert follow.SOURCE == Source.LEADER


# ---- following ------------------------------------------------------------------------------------------------
def test_it_follows_the_mapped_leader_with_scale_and_offset(make_engine: MakeEngine) -> None:
    joint_map = {"a": {"joint": "x", "scale": -1.0, "offset": 0.1}, "b": {"joint": "y", "scale": 0.5}, "c": {}}
    engine, follow = started(make_engine, joint_map=joint_map, deadman={"required": False})
    leader = Leader(engine, follow, still(0.3, 0.4, -0.5, 9.0), names=("x", "y", "c", "other"))
    leader.run(1000)
    np.testing.assert_allclose(engine.command.position, [-0.2, 0.2, -0.5], atol=1e-6)
    assert modes(engine) == ["controlled"] * 3
    assert follow.invalid_samples == 0


def test_a_leader_beyond_the_soft_limits_is_clamped_and_reported_once(make_engine: MakeEngine) -> None:
    engine, follow = started(make_engine, deadman={"required": False})
    Leader(engine, follow, still(2.0, 0.0, 0.0)).run(1000)
    assert engine.command.position[0] == pytest.approx(SOFT, abs=1e-5)
    assert engine.command.position[0] <= SOFT
    clamps = [e for e in events(engine) if "target clamped" in e]
    assert len(clamps) == 1, clamps  # one per clamping episode, not one per sample


def test_a_far_first_sample_is_approached_jerk_limited(make_engine: MakeEngine) -> None:
    engine, follow = started(make_engine, deadman={"required": False})
    leader = Leader(engine, follow, still(-0.9, 0.9, -0.9))  # the joints start at 0.1, -0.2, 0.3
    leader.run(700)
    assert leader.probe.peak["velocity"] > 0.9  # it went as fast as allowed, and no faster (the probe checks)
    assert leader.probe.peak["jerk"] <= 1.0 + 1e-6
    np.testing.assert_allclose(engine.command.position, [-0.9, 0.9, -0.9], atol=1e-6)


def test_a_moving_leader_is_tracked_within_a_few_periods(make_engine: MakeEngine) -> None:
    engine, follow = started(make_engine, deadman={"required": False})
    wave = lambda t: [0.1 + 0.4 * math.sin(2.0 * t), -0.2 + 0.3 * math.sin(1.5 * t), 0.3]  # noqa: E731
    leader = Leader(engine, follow, wave)
    leader.run(1000)  # settle onto the wave
    errors = []
    for _ in range(500):
        leader.run(1)
        errors.append(np.abs(engine.command.position[:2] - wave(engine.t)[:2]).max())
    # Speeds up to 0.8 rad/s (8 mrad per 10 ms sample period): within two periods' travel.
    assert max(errors) < 0.016, max(errors)


# ---- the dead-man ---------------------------------------------------------------------------------------------
def test_without_enable_nothing_is_followed(make_engine: MakeEngine) -> None:
    engine, follow = started(make_engine)
    start = engine.state.position.copy()
    Leader(engine, follow, still(0.5, 0.5, 0.5)).run(300)
    assert modes(engine) == ["hold"] * 3
    np.testing.assert_allclose(engine.final.position, start)
    assert not follow.engaged
    assert follow.source == Source.HOLD  # the provenance: held, not moved by a human


def test_the_source_is_leader_while_engaged_and_hold_once_released(make_engine: MakeEngine) -> None:
    engine, follow = started(make_engine)
    leader = Leader(engine, follow, still(0.2, -0.1, 0.3))
    leader.run(50, enable=True)
    assert follow.source == Source.LEADER
    follow.accept_enable({"enable": False})
    leader.run(1)
    assert follow.source == Source.HOLD
    leader.run(50, enable=True)
    assert follow.source == Source.LEADER


def test_releasing_the_dead_man_holds_within_two_cycles(make_engine: MakeEngine) -> None:
    engine, follow = started(make_engine)
    leader = Leader(engine, follow, lambda t: [0.1 + 0.5 * math.sin(t), -0.2, 0.3])
    leader.run(600, enable=True)
    assert modes(engine) == ["controlled"] * 3
    assert events(engine) == ["info:follow:following lead"]
    assert abs(engine.command.velocity[0]) > 0.1  # moving when released
    follow.accept_enable({"enable": False})
    cycles = 0
    while modes(engine) != ["hold"] * 3:
        leader.run(1)
        cycles += 1
        assert cycles <= 2, f"still {modes(engine)} {cycles} cycles after the release"
    assert events(engine) == ["info:follow:dead-man released: the joints hold"]
    held = engine.final.position.copy()
    leader.run(200)  # the leader goes on; nothing follows it
    np.testing.assert_allclose(engine.final.position, held, atol=1e-9)


def test_a_silent_dead_man_holds_within_two_cycles_of_its_timeout(make_engine: MakeEngine) -> None:
    engine, follow = started(make_engine, deadman={"required": True, "timeout": 0.1})
    leader = Leader(engine, follow, lambda t: [0.1 + 0.5 * math.sin(t), -0.2, 0.3])
    leader.run(300, enable=True)
    last_enable = engine.t - (300 - 1) % EVERY * engine.period
    assert follow.engaged
    while modes(engine) != ["hold"] * 3:
        leader.run(1)
        assert engine.t < last_enable + 0.1 + 2.5 * engine.period, "not held within 2 cycles of the timeout"
    assert engine.t > last_enable + 0.1 - 1e-9  # and not before it


def test_re_enabling_starts_from_where_the_arm_is(make_engine: MakeEngine) -> None:
    engine, follow = started(make_engine)
    leader = Leader(engine, follow, still(0.1, -0.2, 0.3))
    leader.run(100, enable=True)
    follow.accept_enable({"enable": False})
    leader.position = still(-0.8, 0.8, -0.8)  # the leader moved far while released
    leader.run(100)
    leader.run(600, enable=True)  # the probe checks every cycle: no step, within jerk
    np.testing.assert_allclose(engine.command.position, [-0.8, 0.8, -0.8], atol=1e-6)


# ---- degradation and stop -------------------------------------------------------------------------------------
def test_a_gappy_lossy_stream_slows_the_follower_down(make_engine: MakeEngine) -> None:
    engine, follow = started(make_engine, deadman={"required": False})
    ramp = lambda t: [max(-0.9, 0.9 - 1.8 * t), 0.0, 0.0]  # noqa: E731  # 1.8 rad/s, near the limit
    healthy = Leader(engine, follow, ramp)
    healthy.run(200)
    assert follow.speed == 1.0
    fast = healthy.probe.peak["velocity"]

    engine2, follow2 = started(make_engine, deadman={"required": False})
    lossy = Leader(engine2, follow2, ramp, lost=lambda seq: seq % 10 != 0)  # 9 of 10 samples lost: 100 ms gaps
    lossy.run(200)
    assert follow2.speed < 0.85
    assert follow2.speed == pytest.approx(follow2.speed_for(10 / RATE), abs=0.03)
    assert lossy.probe.peak["velocity"] < fast
    assert abs(engine2.command.velocity[0]) <= follow2.speed * 2.0 + 1e-6


def test_the_speed_recovers_with_the_stream(make_engine: MakeEngine) -> None:
    engine, follow = started(make_engine, deadman={"required": False})
    leader = Leader(engine, follow, lambda t: [0.5 * math.sin(t), 0.0, 0.0], lost=lambda seq: seq % 10 != 0)
    leader.run(300)
    assert follow.speed < 0.85
    leader.lost = lambda seq: False
    leader.run(500)
    assert follow.speed == 1.0


def test_when_the_stream_stops_it_brakes_and_holds(make_engine: MakeEngine) -> None:
    engine, follow = started(make_engine, deadman={"required": False})
    leader = Leader(engine, follow, lambda t: [0.1 + 1.0 * t, -0.2, 0.3])
    leader.run(150)
    assert abs(engine.command.velocity[0]) > 0.5
    stop = engine.t
    while follow.phase != Phase.HOLD:
        leader.probe.run(1)
        assert engine.t < stop + 0.25 + 1.0, "never came to rest"
    assert engine.t > stop + 0.25 - 0.02  # it waited for command_timeout (it slowed down meanwhile)
    assert any("no target for 0.25 s" in e for e in events(engine))
    rest = engine.command.position.copy()
    leader.probe.run(100)
    np.testing.assert_array_equal(engine.command.position, rest)
    np.testing.assert_array_equal(engine.command.velocity, 0.0)


# ---- leader samples that cannot be followed -------------------------------------------------------------------
@pytest.mark.parametrize(
    ("bad", "reason"),
    [
        ({"name": ["a", "b"], "position": [0.5, 0.5]}, "leader joints missing: ['c']"),
        ({"position": [0.5, math.nan, 0.5]}, "b: non-finite"),
        ({"position": [0.5, "x", 0.5]}, "b: non-finite or not a number"),
        ({"fresh": [1, 1, 0]}, "c: reading not fresh"),
        ({"seq": None}, "no integer seq"),
        ({"position": [0.5]}, "one length"),
    ],
)
def test_invalid_samples_are_counted_reported_once_and_never_followed(
    make_engine: MakeEngine, bad: dict[str, Any], reason: str
) -> None:
    engine, follow = started(make_engine, deadman={"required": False})
    start = engine.state.position.copy()
    for seq in range(1, 51):
        message = {"stamp": 0.0, "seq": seq, "name": ["a", "b", "c"], "position": [0.5, 0.5, 0.5], **bad}
        follow.accept_leader(message)
        engine.run_cycles(EVERY)
    np.testing.assert_array_equal(engine.command.position, start)
    assert follow.invalid_samples == 50
    warnings = [e for e in events(engine) if "not followed" in e]
    assert len(warnings) == 1 and reason in warnings[0], warnings
    for seq in range(100, 220):  # valid again: followed (a single sample would time out before it is reached)
        follow.accept_leader({"stamp": 0.0, "seq": seq, "name": ["a", "b", "c"], "position": [0.5, 0.5, 0.5]})
        engine.run_cycles(EVERY)
    np.testing.assert_allclose(engine.command.position, 0.5, atol=1e-6)
    assert "info:follow:leader lead: valid samples again after 50 invalid" in events(engine)


def test_a_sample_older_than_one_followed_is_dropped(make_engine: MakeEngine) -> None:
    engine, follow = started(make_engine, deadman={"required": False})
    follow.accept_leader({"stamp": 0.1, "seq": 10, "name": ["a", "b", "c"], "position": [0.12, -0.18, 0.32]})
    follow.accept_leader({"stamp": 0.09, "seq": 9, "name": ["a", "b", "c"], "position": [-0.5, -0.5, -0.5]})
    engine.run_cycles(100)  # within command_timeout: the small move is done
    np.testing.assert_allclose(engine.command.position, [0.12, -0.18, 0.32], atol=1e-6)
    assert follow.stale_samples == 1
    follow.accept_leader({"stamp": 0.0, "seq": 1, "name": ["a", "b", "c"], "position": [0.0, 0.0, 0.0]})
    assert follow.stale_samples == 2  # 9 behind, the same clock: late, not a restart


def test_a_leader_that_restarted_is_followed_again(make_engine: MakeEngine) -> None:
    engine, follow = started(make_engine, deadman={"required": False})
    names = ["a", "b", "c"]
    follow.accept_leader({"stamp": 50.0, "seq": 5000, "name": names, "position": [0.1, -0.2, 0.3]})
    engine.run_cycles(10)
    follow.accept_leader({"stamp": 0.01, "seq": 1, "name": names, "position": [0.12, -0.18, 0.32]})  # its clock at 0
    engine.run_cycles(100)
    np.testing.assert_allclose(engine.command.position, [0.12, -0.18, 0.32], atol=1e-6)
    assert follow.stale_samples == 0


def test_inactive_it_ignores_the_leader_and_refuses_enable(make_engine: MakeEngine) -> None:
    engine = make_engine(follow_patch())
    follow = engine.manager.records["follow"].instance
    assert isinstance(follow, FollowController)
    follow.accept_leader({"stamp": 0.0, "seq": 1, "name": ["a", "b", "c"], "position": [0.5, 0.5, 0.5]})
    assert follow.invalid_samples == 0
    with pytest.raises(ValueError, match="not active"):
        follow.accept_enable({"enable": True})


@pytest.mark.parametrize(
    ("payload", "reason"),
    [([], "expected an object"), ({"enable": 1}, "true or false"), ({"enable": True, "x": 1}, "unknown keys")],
)
def test_a_bad_enable_is_refused(make_engine: MakeEngine, payload: Any, reason: str) -> None:
    _, follow = started(make_engine)
    with pytest.raises(ValueError, match=reason):
        follow.accept_enable(payload)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_whatever_the_stream_and_the_dead_man_do_the_command_stays_within_the_limits(
    make_engine: MakeEngine, seed: int
) -> None:
    """A leader that jumps anywhere, loses samples in bursts, arrives late; a dead-man pressed and released at
    random: every written command stays within the velocity, acceleration and jerk limits (the probe), and the
    supervisor's final command never steps beyond v_max·T (its JumpGuard)."""
    rng = np.random.default_rng(seed)
    engine, follow = started(make_engine, deadman={"required": True, "timeout": 0.1})
    state = {"target": [0.0, 0.0, 0.0]}

    def jumpy(t: float) -> list[float]:
        if rng.random() < 0.02:
            state["target"] = rng.uniform(-1.2, 1.2, 3).tolist()  # beyond the soft limits too: clamped
        return state["target"]

    leader = Leader(engine, follow, jumpy, every=int(rng.integers(2, 12)), lost=lambda seq: rng.random() < 0.2)
    for _ in range(40):
        leader.every = int(rng.integers(2, 40))  # 4 to 80 ms between samples: degradation comes and goes
        leader.run(int(rng.integers(20, 200)), enable=bool(rng.random() < 0.7))
    assert follow.released_at > 0.0  # it did engage and release
    assert leader.probe.peak["velocity"] > 0.3  # and moved meanwhile


def fitted_lag(times: np.ndarray, leader: np.ndarray, command: np.ndarray) -> float:
    """The time shift τ (s, 0.1 ms steps) minimising the RMS of command(t) − leader(t − τ), as the bench fits it."""
    shifts = np.arange(-0.02, 0.05, 1e-4)
    rms = [np.sqrt(np.mean((command - np.interp(times - tau, times, leader)) ** 2)) for tau in shifts]
    return float(shifts[int(np.argmin(rms))])


@pytest.mark.parametrize("every", [1, EVERY])
def test_a_wave_streamed_at_the_control_rate_is_followed_within_two_periods(
    make_engine: MakeEngine, every: int
) -> None:
    """The [teleop] target: joint lag ≤ 2 control periods (+ the network's delay, none here) for a leader streaming
    at the control rate, and no step beyond the limits on the way (the probe checks every cycle)."""
    rate = 500.0 / every
    engine, follow = started(make_engine, deadman={"required": False}, rate=rate)
    wave = lambda t: [0.1 + 0.4 * math.sin(2.0 * t), -0.2 + 0.3 * math.sin(1.5 * t), 0.3]  # noqa: E731
    leader = Leader(engine, follow, wave, every=every)
    leader.run(1000)  # settle onto the wave
    times, lead, command = [], [], []
    for _ in range(1500):
        leader.run(1)
        times.append(engine.t)
        lead.append(wave(engine.t)[:2])
        command.append(engine.command.position[:2].copy())
    t, p, c = np.array(times), np.array(lead), np.array(command)
    lags = [fitted_lag(t, p[:, j], c[:, j]) for j in range(2)]
    errors = [float(np.abs(c[:, j] - np.interp(t - lags[j], t, p[:, j])).max()) for j in range(2)]
    assert max(abs(x) for x in lags) <= 2 * engine.period, lags
    assert max(errors) < 0.002, errors
    assert not [e for e in events(engine) if e.startswith(("error", "warning"))]  # never fell back nor stopped


def test_a_leader_that_stops_dead_is_overshot_by_no_more_than_the_braking_distance(make_engine: MakeEngine) -> None:
    """Aiming a lead ahead costs this much and no more: at a hard stop the follower brakes from the leader's speed
    (jerk-limited: the probe checks every cycle) and comes back to where the leader stopped."""
    engine, follow = started(make_engine, deadman={"required": False}, rate=500.0)
    stop, speed, rise = 0.8, 1.0, 0.3  # the joints start at 0.1, -0.2, 0.3; the leader speeds up smoothly …

    def ramp(t: float) -> list[float]:  # … to 1 rad/s in 0.3 s (a cosine), goes on, and stops dead at 0.8 s
        t = min(t, stop)
        up = min(t, rise)
        travel = speed * (up - rise / math.pi * math.sin(math.pi * up / rise)) / 2 + speed * max(t - rise, 0.0)
        return [0.1 + travel, -0.2, 0.3]

    leader = Leader(engine, follow, ramp, every=1)
    furthest = -math.inf
    for _ in range(int(stop / engine.period) + 600):
        leader.run(1)
        furthest = max(furthest, float(engine.command.position[0]))
    final = ramp(stop)
    np.testing.assert_allclose(engine.command.position, final, atol=1e-6)
    assert furthest > final[0]  # it did overshoot: it was ahead of the leader's path, not behind it
    assert furthest - final[0] <= stopping_distance(speed, ACCELERATION, JERK) + 1e-3, furthest - final[0]
