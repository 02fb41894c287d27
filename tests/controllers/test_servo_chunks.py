"""The servo's chunk input in lockstep: delay compensation, overlapping chunks without rest, limits, late chunks
slowing to a hold, bad chunks refused while the servo runs on, and the source it reports (policy / stream)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from hild.bench.chunks import ChunkSettings, figures, play
from hild.controllers.servo import Phase, ServoController
from hild.crossing.mailboxes import Shared
from hild.crossing.region import Region
from hild.crossing.requests import SetParams
from hild.cycle.engine import Engine
from hild.modes import Source
from hild.motion.chunks import (
    BLEND_FRACTION,
    MAX_BLEND,
    MAX_CHUNK_STEPS,
    ChunkPlayer,
    ChunkRecord,
    HandoffBlend,
    Verdict,
    parse_chunk,
)
from tests.controllers.test_servo import LimitProbe, servo_patch, started
from tests.test_engine import events

MakeEngine = Callable[..., Engine]
STEP = 0.02


def ramp(start: np.ndarray, slope: np.ndarray, steps: int = 50) -> list[list[float]]:
    return (start + slope * STEP * np.arange(steps)[:, None]).tolist()


def chunk(stamp: float, positions: list[list[float]], **more: Any) -> dict[str, Any]:
    return {"stamp": stamp, "dt": STEP, "positions": positions, **more}


def test_a_chunk_stamped_200_ms_ago_starts_200_ms_in(make_engine: MakeEngine) -> None:
    """A ramp from where the joints are, stamped 0.2 s before now: the servo follows ramp(t − stamp), not ramp(t −
    arrival) — 40 mrad apart at this slope."""
    engine, servo = started(make_engine, command_timeout=5.0)
    engine.run_cycles(10)
    start, slope = engine.state.position.copy(), np.array([0.2, -0.2, 0.1])
    stamp = engine.t - 0.2
    servo.accept_chunk(chunk(stamp, ramp(start, slope, 100)))
    probe = LimitProbe(engine, servo)
    probe.run(1)
    assert servo._chunks.stamp == stamp and servo.source == Source.POLICY
    assert servo._chunks.tau == pytest.approx(0.2 + 2 * engine.period, abs=1e-9)  # the past 0.2 s skipped
    probe.run(int(0.8 / engine.period))
    expected = start + slope * (engine.t - stamp)
    np.testing.assert_allclose(engine.command.position, expected, atol=2e-3)
    assert np.abs(engine.command.position - (expected - 0.2 * slope)).max() > 0.015


def test_overlapping_chunks_at_10_hz_never_rest_and_stay_within_the_limits() -> None:
    """The bench's synthetic policy on the arm6 twin: 10 Hz chunks of 50 steps, 50–300 ms jittered delay."""
    settings = ChunkSettings(seconds=4.0, seed=3)
    result = figures(play("servo", settings), settings)
    assert result["handoffs"] >= 15
    assert result["handoff_speed_min"] >= 0.9
    assert result["pauses"] == 0
    for peak in ("velocity_peak", "acceleration_peak", "jerk_peak"):
        assert result[peak] <= 1.0 + 1e-6, (peak, result)
    assert result["rms_error_mrad"] < 5.0


def test_chunks_beyond_the_limits_are_followed_within_them(make_engine: MakeEngine) -> None:
    """A policy asking for more than the joints can do: velocity, acceleration and jerk are held every cycle, and
    positions beyond the soft limits are clamped (one event)."""
    engine, servo = started(make_engine, command_timeout=5.0, velocity_scale=0.8, acceleration_scale=0.5)
    probe = LimitProbe(engine, servo, 0.8, 0.5)
    for _ in range(20):
        stamp = engine.t - 0.05
        times = stamp + STEP * np.arange(50)
        positions = 1.2 * np.sin(9.0 * times[:, None] + np.array([0.0, 1.0, 2.0]))  # beyond ±0.95, ~10 rad/s
        servo.accept_chunk(chunk(stamp, positions.tolist()))
        probe.run(int(0.1 / engine.period))
    assert probe.peak["acceleration"] > 0.9 and probe.peak["jerk"] > 0.9
    clamped = [e for e in events(engine) if "chunk clamped at step" in e]
    assert len(clamped) == 1, clamped  # 2 s of chunks clamped every 0.1 s: one clamping episode, one event


def test_a_late_chunk_slows_down_then_holds_at_its_last_point(make_engine: MakeEngine) -> None:
    engine, servo = started(make_engine, command_timeout=5.0, chunk_slowdown=0.3)
    probe = LimitProbe(engine, servo)
    start, slope = engine.state.position.copy(), np.array([0.3, -0.3, 0.2])
    positions = ramp(start, slope)  # 0.98 s
    servo.accept_chunk(chunk(engine.t, positions))
    speeds, scale = [], []
    for _ in range(int(2.0 / engine.period)):
        probe.run(1)
        speeds.append(float(np.linalg.norm(engine.command.velocity[:3])))
        scale.append(servo._chunks.speed)
    speeds_a = np.array(speeds)
    full = float(np.linalg.norm(slope))
    cruise = int(0.5 / engine.period)
    assert speeds_a[cruise] == pytest.approx(full, rel=0.02)  # at full speed before the slow-down
    assert min(scale) < 0.2  # playback slowed near the end …
    slowing = speeds_a[cruise:]
    rises = np.diff(slowing)
    assert (rises <= 1e-3).all(), (np.argmax(rises), rises.max())  # … the speed only decreases (no stop-and-go) …
    np.testing.assert_allclose(engine.command.position, positions[-1], atol=1e-6)  # … to rest at the last point
    assert speeds_a[-1] < 1e-12
    assert servo.phase == Phase.TRACK and not servo._chunks.playing
    assert [e for e in events(engine) if "no target" in e] == []  # no timeout: the chunk truly ended


def test_the_command_timeout_still_stops_a_policy_that_went_silent(make_engine: MakeEngine) -> None:
    engine, servo = started(make_engine, command_timeout=0.3)
    start = engine.state.position.copy()
    servo.accept_chunk(chunk(engine.t, ramp(start, np.array([0.3, 0.3, 0.3]))))
    LimitProbe(engine, servo).run(int(0.9 / engine.period))
    assert any("no target for 0.3 s: stopping" in e for e in events(engine))
    assert servo.phase == Phase.HOLD and not servo._chunks.playing
    assert engine.command.position[0] < start[0] + 0.3 * 0.6  # stopped well before the chunk's end


@pytest.mark.parametrize(
    ("payload", "reason"),
    [
        ([1, 2], "expected an object"),
        ({"dt": 0.02, "positions": [[0.0] * 3] * 2}, "missing stamp"),
        ({"stamp": 0.0, "dt": 0.02, "positions": [[0.0] * 3] * 2, "speed": 1}, "unknown keys ['speed']"),
        ({"stamp": "now", "dt": 0.02, "positions": [[0.0] * 3] * 2}, "stamp must be a number"),
        ({"stamp": 0.0, "dt": 0.0, "positions": [[0.0] * 3] * 2}, "dt must be within"),
        ({"stamp": 0.0, "dt": 0.02, "positions": [[0.0] * 3]}, "a chunk has 2 to 100 steps; positions has 1"),
        ({"stamp": 0.0, "dt": 0.02, "positions": [[0.0] * 3] * (MAX_CHUNK_STEPS + 1)}, "2 to 100 steps"),
        ({"stamp": 0.0, "dt": 0.02, "positions": [[0.0] * 3, [0.0] * 2]}, "positions[1] must be a list of 3"),
        ({"stamp": 0.0, "dt": 0.02, "positions": [[0.0] * 3, [0.0, float("nan"), 0.0]]}, "positions[1][1] (b)"),
        ({"stamp": 0.0, "dt": 0.02, "positions": [[0.0] * 3, [0.0, True, 0.0]]}, "is not a number: True"),
        (
            {"stamp": 0.0, "dt": 0.02, "positions": [[0.0] * 3] * 3, "velocities": [[0.0] * 3] * 2},
            "velocities has 2 steps; positions has 3",
        ),
    ],
)
def test_a_malformed_chunk_is_refused_with_its_reason_and_the_running_one_plays_on(
    make_engine: MakeEngine, payload: Any, reason: str
) -> None:
    engine, servo = started(make_engine, command_timeout=5.0)
    start = engine.state.position.copy()
    servo.accept_chunk(chunk(engine.t, ramp(start, np.array([0.2, 0.2, 0.2]))))
    engine.run_cycles(50)
    with pytest.raises(ValueError) as info:
        servo.accept_chunk(payload)
    assert reason in str(info.value)
    before = engine.command.position.copy()
    engine.run_cycles(50)
    assert servo._chunks.playing and (engine.command.position > before + 0.01).all()


def test_stale_past_and_future_chunks_are_dropped_with_an_event(make_engine: MakeEngine) -> None:
    engine, servo = started(make_engine, command_timeout=5.0)
    start = engine.state.position.copy()
    positions = ramp(start, np.array([0.1, 0.1, 0.1]))
    engine.run_cycles(200)
    servo.accept_chunk(chunk(engine.t - 0.1, positions))
    engine.run_cycles(1)
    running = servo._chunks.stamp
    servo.accept_chunk(chunk(running - 0.05, positions))  # an older observation, overtaken
    engine.run_cycles(1)
    assert servo._chunks.stamp == running and servo._chunks.dropped == 1
    (dropped,) = [e for e in events(engine) if "chunk dropped" in e]
    assert f"before the running chunk's {running:.4f} s" in dropped and "1 dropped since activation" in dropped
    engine.run_cycles(int(1.1 / engine.period))  # quiet, so the next refusal is reported
    servo.accept_chunk(chunk(engine.t - 0.5, positions[:3]))  # newer than the running one, but over
    engine.run_cycles(1)
    assert any("all of it is in the past" in e for e in events(engine))
    engine.run_cycles(int(1.1 / engine.period))
    servo.accept_chunk(chunk(engine.t + 1.0, positions))
    engine.run_cycles(1)
    assert any("ahead of the control clock" in e for e in events(engine))
    assert servo._chunks.stamp == running and servo._chunks.refused == 2


def test_the_source_is_policy_while_chunks_drive_and_stream_once_a_target_arrives(make_engine: MakeEngine) -> None:
    engine, servo = started(make_engine, command_timeout=5.0)
    assert servo.source == Source.STREAM
    start = engine.state.position.copy()
    probe = LimitProbe(engine, servo)
    servo.accept_chunk(chunk(engine.t, ramp(start, np.array([0.3, 0.3, 0.3]))))
    probe.run(100)
    assert servo.source == Source.POLICY and servo._chunks.playing
    servo.accept({"positions": start.tolist()})
    probe.run(1)
    assert servo.source == Source.STREAM and not servo._chunks.playing
    assert servo._inp.minimum_duration is None  # plain targets are reached time-optimally again
    probe.run(400)
    np.testing.assert_allclose(engine.command.position, start, atol=1e-9)
    servo.accept_chunk(chunk(engine.t, ramp(start, np.array([-0.3, 0.3, -0.3]))))
    probe.run(1)
    assert servo.source == Source.POLICY


def test_the_streamed_target_sent_before_a_chunk_is_followed_again_after_it(make_engine: MakeEngine) -> None:
    """A stream target, a chunk moving elsewhere, then the very same target: the servo goes back to it (an unchanged
    target is not re-planned — but ruckig was aimed at the chunk meanwhile), planned per joint like the stream."""
    engine, servo = started(make_engine, command_timeout=5.0)
    start = engine.state.position.copy()
    target = (start + 0.05).tolist()
    probe = LimitProbe(engine, servo)
    servo.accept({"positions": target})
    probe.run(1)
    servo.accept({"positions": target})
    probe.run(300)
    np.testing.assert_allclose(engine.command.position, target, atol=1e-9)
    servo.accept_chunk(chunk(engine.t, ramp(np.array(target), np.array([0.3, -0.3, 0.3]))))
    probe.run(300)
    assert np.abs(engine.command.position - target).max() > 0.05  # the chunk took it away
    for _ in range(400):  # the same target, streamed every cycle
        servo.accept({"positions": target})
        probe.run(1)
    assert servo._inp.synchronization == servo._sync  # what ruckig holds is what the servo thinks it holds
    np.testing.assert_allclose(engine.command.position, target, atol=1e-6)


def test_a_chunk_for_an_inactive_servo_is_refused(make_engine: MakeEngine) -> None:
    engine = make_engine(servo_patch())
    servo = engine.manager.records["servo"].instance
    assert isinstance(servo, ServoController)
    with pytest.raises(ValueError, match="controller servo is not active"):
        servo.accept_chunk(chunk(0.0, [[0.0] * 3] * 2))


def test_a_chunk_crosses_the_shared_region_as_one_record_and_plays_through_its_points() -> None:
    """The client domain's half puts a parsed chunk into a cell of the shared region; the cycle's half, attached to
    the same region, takes it whole and its samples pass through the chunk's steps with their velocities."""
    size = 4 << 20
    region = Region(size)
    n = 6
    writer = ChunkRecord(Shared(region, create=True).latest_numbers("chunk", ChunkRecord.width(n)), n)
    reader_door = Shared(Region.attach(region.fd, size), create=False).latest_numbers("chunk", ChunkRecord.width(n))
    player = ChunkPlayer(reader_door, n)
    positions = np.sin(0.3 * np.arange(MAX_CHUNK_STEPS)[:, None] + np.arange(n)).tolist()
    writer.put(parse_chunk({"stamp": 2.0, "dt": STEP, "positions": positions}, list("abcdef"), lambda p, v: ()))
    assert player.record.take()
    assert player.start(2.0) == Verdict.STARTED
    assert player.end == pytest.approx(STEP * (MAX_CHUNK_STEPS - 1))
    for k in (0, 17, MAX_CHUNK_STEPS - 2):
        player._sample(0, k * STEP, 1.0, player.target)
        np.testing.assert_allclose(player.target_p, positions[k], atol=1e-12)
        slope = (np.array(positions[k + 1]) - np.array(positions[max(k - 1, 0)])) / (STEP * (2 if k else 1))
        np.testing.assert_allclose(player.target_v, slope, atol=1e-9)


def test_a_fault_drops_the_chunk_and_reset_resumes_without_a_jump() -> None:
    """Chunks keep coming while a joint is faulted: dropped, the servo rests where the arm is; after the reset it
    stays there until a new chunk arrives, and that one starts from where the arm is."""
    from hild.cycle.supervisor import Fault
    from tests.test_engine import JumpGuard
    from tests.test_twin_engine import twin

    engine = twin("arm6_twin.yaml")
    engine.load_controller("policy", "servo", {"joints": list(engine.joints), "command_timeout": 5.0})
    assert engine.switch(["policy"], []).ok
    servo = engine.manager.records["policy"].instance
    assert isinstance(servo, ServoController)
    guard = JumpGuard(engine)
    start = engine.state.position.copy()
    slope = np.full(len(start), 0.2)

    def send() -> None:
        servo.accept_chunk(chunk(engine.t, ramp(start + slope * engine.t, slope)))

    for _ in range(10):
        send()
        guard.run(50)
    engine.supervisor.trip(1, Fault.HARDWARE, "test fault")
    for _ in range(6):
        send()  # dropped while faulted
        guard.run(50)
    assert not servo._chunks.playing
    held = engine.state.position.copy()
    assert engine.reset()["cleared"]
    guard.run(300)  # no chunk since the reset: it rests where the arm was
    np.testing.assert_allclose(engine.final.position, held, atol=5e-3)
    send()
    guard.run(100)  # a new chunk far from the arm: reached within the limits, no jump (the guard checks)
    assert servo.source == Source.POLICY and servo._chunks.playing


def test_disagreeing_chunks_blend_in_without_a_step_a_pause_or_leaving_the_limits(make_engine: MakeEngine) -> None:
    """Overlapping chunks at 10 Hz, each off the truth by its own 5–10 mrad, alternating in sign (so where two meet they
    differ by 10–20 mrad), and drifting on by N(0, 10 mrad/s): the target moves on without a jump at any handoff, the
    command keeps within the velocity, acceleration and jerk limits every cycle (position, velocity and acceleration
    never step), never slows to rest while the truth moves, and stays within the chunks' own disagreement of it."""
    engine, servo = started(make_engine, command_timeout=5.0)
    probe = LimitProbe(engine, servo)
    dt, home = engine.period, engine.state.position.copy()
    amplitude, w = np.array([0.2, -0.15, 0.1]), 2.0

    def truth(t: np.ndarray) -> np.ndarray:
        return home + amplitude * np.sin(w * t[..., None])

    rng = np.random.default_rng(5)
    jumps, speeds, truth_speeds, errors, blending = [], [], [], [], []
    for i in range(40):
        stamp = engine.t - 0.1  # the inference delay
        offset = (-1) ** i * rng.uniform(0.005, 0.010, 3)
        times = stamp + STEP * np.arange(50)
        positions = truth(times) + offset + rng.normal(0.0, 0.01, 3) * (times - stamp)[:, None]
        servo.accept_chunk(chunk(stamp, positions.tolist()))
        for _ in range(round(0.1 / dt)):
            before = servo._chunks.target_p.copy()
            probe.run(1)
            if i >= 10:  # after a second: the start from rest caught up
                jumps.append(np.abs(servo._chunks.target_p - before).max())
                speeds.append(np.linalg.norm(engine.command.velocity[:3]))
                truth_speeds.append(np.linalg.norm(amplitude * w * np.cos(w * engine.t)))
                errors.append(np.abs(engine.command.position[:3] - truth(np.array(engine.t))).max())
                blending.append(servo._chunks.blend.active)
    assert servo._chunks.dropped == 0 and servo.source == Source.POLICY
    assert np.mean(blending) > 0.5  # most of the time a handoff's offset is being absorbed …
    assert max(jumps) < 0.005 / 2  # … so the target never jumps by the 10–20 mrad between two chunks
    ratio = np.array(speeds) / np.array(truth_speeds)
    moving = np.array(truth_speeds) >= 0.25 * max(truth_speeds)
    assert ratio[moving].min() > 0.8  # no pause, no slowing down at a handoff
    assert max(errors) < 0.02 and float(np.sqrt(np.mean(np.square(errors)))) < 0.01  # 5–10 mrad off, drifting


def test_a_handoff_offset_decays_from_the_difference_to_zero_within_the_limits() -> None:
    """The blend starts at the difference in position, velocity and acceleration (the target stays continuous) and
    reaches zero at rest within its blend time; its own velocity, acceleration and jerk stay within three times
    BLEND_FRACTION of the limits (one share per term)."""
    vmax, amax, jmax = np.array([2.0, 2.0]), np.array([8.0, 8.0]), np.array([80.0, 80.0])
    blend = HandoffBlend(2)
    blend.limits(vmax.tolist(), amax.tolist(), jmax.tolist())
    difference = np.array([[0.008, -0.03], [0.05, 0.2], [-0.4, 1.0]])  # rows p, v, a; joint 1 far more than joint 0
    blend.start(difference)
    assert blend.duration[0] < blend.duration[1] <= MAX_BLEND  # each joint its own blend time
    dt, samples = 0.001, []
    for _ in range(round(1.2 / dt)):
        target = np.zeros((3, 2))
        blend.add_to(target, dt)
        samples.append(target)
    offset = np.array(samples)
    np.testing.assert_allclose(offset[0], difference, atol=1e-12)
    assert not blend.active and (offset[-1] == 0.0).all()
    jerk = np.abs(np.diff(offset[:, 2], axis=0)) / dt
    peaks = ((vmax, np.abs(offset[:, 1]).max(0)), (amax, np.abs(offset[:, 2]).max(0)), (jmax, jerk.max(0)))
    for limit, peak in peaks:
        assert (peak <= 3 * BLEND_FRACTION * limit * (1 + 1e-3)).all(), (peak, limit)


def test_older_chunks_are_ensembled_with_exponential_weights_by_age() -> None:
    """Two constant chunks 0.1 s apart in stamp, 10 mrad apart: once the handoff is blended out, the target is their
    average weighted 1 : exp(−0.1/ensemble); with ensemble 0 it is the newer chunk alone."""
    size, n = 4 << 20, 2
    for ensemble, expected in ((0.3, 0.01 / (1.0 + np.exp(-0.1 / 0.3))), (0.0, 0.01)):
        region = Region(size)
        door = Shared(region, create=True).latest_numbers("chunk", ChunkRecord.width(n))
        player = ChunkPlayer(door, n)
        player.ensemble = ensemble
        player.blend.limits([2.0] * n, [8.0] * n, [80.0] * n)
        for stamp, value in ((0.0, 0.0), (0.1, 0.01)):
            player.record.put(
                parse_chunk({"stamp": stamp, "dt": STEP, "positions": [[value] * n] * 50}, "ab", lambda p, v: ())
            )
            assert player.record.take() and player.start(0.1) == Verdict.STARTED
            player.aim(0.002, 0.3, 0.08)
        for _ in range(400):
            player.aim(0.002, 0.3, 0.08)
        assert not player.blend.active
        np.testing.assert_allclose(player.target_p, expected, atol=1e-12)


def test_chunk_ensemble_and_lowered_scales_apply_while_chunks_play(make_engine: MakeEngine) -> None:
    """Set at runtime between two cycles: ``chunk_ensemble`` 0 plays the newest chunk alone from the next cycle, and
    lowered scales bound both the tracking and the blend time computed at the next handoff; every step stays within
    the new limits."""
    engine, servo = started(make_engine, command_timeout=5.0)
    probe = LimitProbe(engine, servo)
    assert servo._chunks.ensemble == 0.3
    start, slope = engine.state.position.copy(), np.array([0.2, -0.2, 0.1])

    def send(offset: float) -> None:
        stamp = engine.t - 0.05
        servo.accept_chunk(chunk(stamp, ramp(start + slope * stamp + offset, slope)))
        probe.run(round(0.1 / engine.period))

    for i in range(10):
        send(0.008 * (-1) ** i)
    limits_before = list(servo._chunks.blend.jmax)
    changes = {"chunk_ensemble": 0.0, "acceleration_scale": 0.5}
    future = engine.request(SetParams("servo", servo.params.model_copy(update=changes), tuple(changes)))
    probe.run(1)
    assert future.result(0)["changed"] == list(changes)
    assert servo._chunks.ensemble == 0.0
    assert servo._chunks.blend.jmax == pytest.approx([0.5 * j for j in limits_before])
    for i in range(20):
        send(0.008 * (-1) ** i)
    probe = LimitProbe(engine, servo, scale_a=0.5)  # from here on, every step within the lowered limits
    for i in range(10):
        send(0.008 * (-1) ** i)
    assert servo._chunks.playing and not servo._chunks._mixed  # the newest chunk alone
    assert probe.peak["jerk"] > 0.5
