"""Issue [trust]: a glitching sensor never moves the arm, a faulted joint gets no more torque than its weight, and a
late cycle never catches up in one step. Each finding of the issue is reproduced here in lockstep (the CAN
versions are in the fault-injection suite, tests/faults)."""

from __future__ import annotations

import itertools
import time
import weakref
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hild.arrays import ServoCommand
from hild.cycle.engine import MAX_STEP_PERIODS, Engine
from hild.cycle.supervisor import Fault
from tests.faults.rigs import JTC, TwinRig

MakeEngine = Callable[..., Engine]
# Keyed by the engine itself, weakly: an id() is reused by a later test's engine once this one is collected, which
# handed that engine the old one's events (a failure seen once in CI).
_seen: weakref.WeakKeyDictionary[Engine, list[str]] = weakref.WeakKeyDictionary()


def messages(engine: Engine) -> list[str]:
    """Every event message the engine emitted so far (the log is drained into a per-engine list)."""
    seen = _seen.setdefault(engine, [])
    seen.extend(e.message for e in engine.events.drain())
    return seen


def rejections(engine: Engine) -> list[str]:
    return [m for m in messages(engine) if "reading rejected" in m]


def test_finding_1_a_glitch_beyond_the_hard_limit_never_moves_the_arm(make_engine: MakeEngine) -> None:
    """Three readings of +7 rad (beyond ±1 rad) on a held joint: nothing faults, the hold target and the shaft
    stay exactly where they were, and the episode is reported once."""
    engine = make_engine()
    mock = engine.hardware[0].component
    engine.run_cycles(10)
    held, shaft = engine.final.position.copy(), mock.position.copy()
    mock.glitch.set(0, value=7.0, replies=3)
    toward = 0.0
    for _ in range(500):
        engine.run_cycles(1)
        toward = max(toward, engine.final.position[0] - held[0])
        assert engine.state.position[0] == held[0]  # controllers and the broadcaster see the last accepted one
    assert toward == 0.0
    np.testing.assert_array_equal(mock.position, shaft)
    assert engine.status()["mode"] == "hold"
    (event,) = rejections(engine)
    assert "joint a: reading rejected: position 7 rad outside the hard limits" in event
    assert any("readings plausible again" in m and "after 3 rejected" in m for m in messages(engine))


def test_a_persistent_glitch_faults_within_the_stale_bound_and_is_damped_not_chased(make_engine: MakeEngine) -> None:
    engine = make_engine()
    mock = engine.hardware[0].component
    engine.run_cycles(10)
    held, shaft = engine.final.position[0], mock.position[0]
    mock.glitch.set(0, offset=0.5)  # a persistent jump: every reading from now on is 0.5 rad off
    stale = engine.supervisor.safety.stale_feedback_cycles
    engine.run_cycles(stale - 1)
    assert engine.supervisor.fault[0] == Fault.NONE
    engine.run_cycles(1)
    assert engine.supervisor.fault[0] == Fault.INVALID_FEEDBACK
    assert engine.status()["joints"][0]["fault"].startswith(f"implausible feedback for {stale} cycles: jump of +0.5")
    engine.run_cycles(200)
    assert engine.final.kp[0] == 0.0 and engine.final.kd[0] == engine.supervisor.gains.hold_kd[0]  # damping only
    assert engine.supervisor.latched[0] == held  # the last accepted position, never the glitch
    assert mock.position[0] == shaft


def test_reset_refuses_while_readings_still_glitch_and_resumes_once_fixed(make_engine: MakeEngine) -> None:
    engine = make_engine()
    mock = engine.hardware[0].component
    engine.run_cycles(10)
    held, shaft = engine.final.position[0], mock.position[0]
    mock.glitch.set(0, value=7.0)  # every reading a spike beyond the limits
    engine.run_cycles(50)
    assert engine.supervisor.fault[0] == Fault.POSITION_LIMIT
    reply = engine.reset()
    assert reply["error"].startswith("readings still implausible on a (position 7 rad outside the hard limits")
    assert engine.supervisor.fault[0] == Fault.POSITION_LIMIT  # nothing was cleared
    mock.glitch.clear()  # the sensor is fixed
    engine.run_cycles(1)
    assert "error" not in engine.reset()
    engine.run_cycles(50)
    assert engine.status()["mode"] == "hold" and engine.final.position[0] == held and mock.position[0] == shaft


def test_reset_re_anchors_a_joint_whose_drive_is_off_and_whose_frame_moved(make_engine: MakeEngine) -> None:
    """A rebooted drive reports a fault (it is off) and may come back in another frame: reset accepts its reading."""
    engine = make_engine()
    mock = engine.hardware[0].component
    engine.run_cycles(10)
    mock.fault_codes[0] = 0x7  # off…
    mock.position[0] += 0.5  # …and back in a frame 0.5 rad away (the mock's position is its drive's frame)
    engine.run_cycles(20)
    assert engine.supervisor.fault[0] == Fault.DRIVE
    reply = engine.reset()
    assert any(
        line.startswith("a: re-anchored at its next reading (rejected: jump of +0.5") for line in reply["cleared"]
    )
    shaft = mock.position[0]
    engine.run_cycles(50)
    assert engine.supervisor.fault[0] == Fault.NONE
    assert engine.supervisor.latched[0] == shaft == mock.position[0]  # held where its encoder says: no motion


def test_finding_3_a_step_no_joint_could_make_is_rejected_and_reported(make_engine: MakeEngine) -> None:
    """0.3 rad in one 2 ms cycle is 150 rad/s against a 2 rad/s limit: rejected, named, never taken as the truth."""
    engine = make_engine()
    mock = engine.hardware[0].component
    engine.run_cycles(10)
    before = engine.state.position[1]
    mock.glitch.set(1, offset=0.3, replies=1)
    engine.run_cycles(1)
    assert engine.state.position[1] == before and not engine.state.fresh[1]
    (event,) = rejections(engine)
    assert "joint b: reading rejected: jump of +0.3 rad in 2 ms (150 rad/s implied)" in event


def test_a_joint_may_rest_within_the_margin_of_its_hard_limit(make_engine: MakeEngine) -> None:
    engine = make_engine({"hardware": {"bus": {"params": {"initial_positions": {"a": 1.0 + 1e-6}}}}})
    engine.run_cycles(50)
    assert engine.status()["mode"] == "hold" and engine.final.kp[0] > 0.0


def test_a_real_move_near_the_velocity_limit_is_never_rejected(make_engine: MakeEngine) -> None:
    engine = make_engine()
    engine.switch(["fwd"], [])
    mock = engine.hardware[0].component
    target = np.array([0.9, -0.9, 0.9])
    fwd = engine.manager.records["fwd"].instance
    for _ in range(600):
        fwd.accept({"values": target.tolist()})
        engine.run_cycles(1)
    np.testing.assert_allclose(mock.position, target)
    assert rejections(engine) == [] and engine.status()["mode"] != "fault"


# ---- on the twin, with gravity ---------------------------------------------------------------------------------
def test_finding_2_gravity_is_never_computed_at_a_bogus_reading() -> None:
    rig = TwinRig()
    engine = rig.engine
    twin = engine.hardware[0].component
    lift = engine.joints.index("shoulder_lift")
    rig.seconds(0.2)
    gravity = engine.final.effort[lift]
    assert abs(gravity) > 1.0  # the joint carries the arm's weight
    twin.glitch.set(lift, value=7.0)  # persistent: the joint faults on implausible feedback
    rig.seconds(1.0)
    assert engine.supervisor.fault[lift] == Fault.POSITION_LIMIT
    assert engine.final.kp[lift] == 0.0  # no spring toward any position: damping only…
    assert engine.final.effort[lift] == pytest.approx(gravity, rel=0.05)  # …and the weight at the last accepted pose
    assert abs(engine.final.effort[lift]) <= engine.limits.effort[lift]


@pytest.mark.parametrize("stall", [0.3, 0.05])
def test_finding_8_a_stalled_cycle_resumes_where_it_was(stall: float) -> None:
    """SIGSTOP for 0.3 s mid-move used to step the desired position 61 mrad in one cycle and end `succeeded`: now
    the control clock advances by at most MAX_STEP_PERIODS, the gap is an event, and the goal runs on."""
    rig = TwinRig()
    engine = rig.engine
    rig.switch([JTC])
    goal = rig.move(0.4)
    rig.seconds(0.4)
    before = engine.final.position.copy()
    engine.step(engine.t + stall, stall)  # the cycle thread was stopped for `stall` seconds
    step = np.abs(engine.final.position - before)
    assert (step <= engine.limits.velocity * MAX_STEP_PERIODS * engine.period + 1e-12).all(), step
    rig.collect_events()
    assert any("cycle gap of" in e.message for _, e in rig.events)
    rig.guard.prev[:] = engine.final.position  # the guard's own bound is per nominal cycle
    assert rig.finish(goal).status == "succeeded"
    assert engine.status()["mode"] != "fault"


def test_a_stall_longer_than_max_cycle_gap_is_a_latched_fault() -> None:
    rig = TwinRig()
    engine = rig.engine
    rig.switch([JTC])
    goal = rig.move(0.4)
    rig.seconds(0.4)
    engine.step(engine.t + 2.0, 2.0)
    assert all(f == Fault.OVERRUN for f in engine.supervisor.fault)
    assert engine.status()["joints"][0]["fault"] == "the cycle stalled for 2000 ms (max_cycle_gap 500 ms)"
    rig.guard.prev[:] = engine.final.position
    rig.seconds(0.2)
    result = rig.result(goal)
    assert result is not None and result.status == "aborted"


def test_stopping_with_a_descent_lowers_the_arm_and_never_drops_it() -> None:
    """stop_descent: kd only, gravity feed-forward fading to zero, then release; no hold spring on the way."""
    rig = TwinRig(safety={"stop_descent": 1.0})
    engine = rig.engine
    lift = engine.joints.index("shoulder_lift")
    rig.seconds(0.2)
    gravity = engine.final.effort[lift]
    assert engine.begin_stop()
    rig.cycle(1)
    assert engine.final.kp[lift] == 0.0 and engine.final.effort[lift] == pytest.approx(gravity, rel=0.05)
    rig.seconds(0.5)
    assert engine.final.kp[lift] == 0.0 and abs(engine.final.effort[lift]) < 0.6 * abs(gravity)
    rig.seconds(0.5)
    assert engine.stopping_done and engine.final.effort[lift] == pytest.approx(0.0, abs=0.02 * abs(gravity))
    engine.stop()
    assert not engine.started


def test_the_cycle_thread_runs_the_descent_before_it_releases_the_hardware() -> None:
    from hild.config.model import RealtimeSection
    from hild.cycle.pacing import CycleThread

    rig = TwinRig(safety={"stop_descent": 0.5})
    engine = rig.engine
    twin = engine.hardware[0].component
    written: list[tuple[float, float]] = []
    write = twin.write

    def record(t: float, dt: float, command: ServoCommand) -> None:
        written.append((float(command.kp[1]), float(command.effort[1])))
        write(t, dt, command)

    twin.write = record  # type: ignore[method-assign]
    cycle = CycleThread(engine, "sim", 0.0, RealtimeSection())
    cycle.start()
    while len(written) < 100:
        time.sleep(0.001)
    cycle.stop()
    cycle.join(10.0)
    assert not cycle.is_alive() and not engine.started
    stiff = [k for k, (kp, _) in enumerate(written) if kp > 0.0]
    descent = written[stiff[-1] + 1 :]
    assert len(descent) == round(0.5 * engine.update_rate)  # every cycle of it ran, at the cycle's pace
    assert all(kp == 0.0 for kp, _ in descent)
    efforts = [abs(e) for _, e in descent]
    assert efforts[0] > 1.0 and efforts[-1] < 0.02 * efforts[0]  # the weight fades out, not dropped at once
    assert all(b <= a + 0.05 * efforts[0] for a, b in itertools.pairwise(efforts))


# ---- finding 6: stopping an unbraked arm on Damiao drives (the emulator with the arm6 twin behind it) -----------
def _stop_an_unbraked_arm(write_config: Callable[..., Path], descent: float) -> tuple[float, float]:
    """Hold arm6 on emulated Damiao drives (no brakes, gravity from the twin), stop the daemon's engine the way the
    cycle thread does, and watch the shoulder for 0.5 s after the drives are released. Returns (peak speed of
    shoulder_lift from the stop on, how far it fell in the 0.5 s after release), in joint space."""
    from drivers.can.emulator.runtime import RuntimeOptions
    from tests.drivers.can.test_emulate_runtime import CanRig as EmulatedArm
    from tests.drivers.can.test_emulate_runtime import arm6

    config = arm6(safety={"stop_descent": descent})
    arm = EmulatedArm(write_config(config), RuntimeOptions(max_step=0.001, brakes=False)).start()
    try:
        twin = arm.runtime.twin
        lift = list(twin.joints).index("shoulder_lift")
        arm.cycle(200)
        peak = 0.0
        if arm.engine.begin_stop():
            while not arm.engine.stopping_done:
                arm.cycle(1)
                peak = max(peak, abs(float(arm.engine.state.velocity[lift])))
        arm.engine.stop()
        released = float(twin.joint_positions()[lift])
        lowest = released
        for _ in range(500):  # 0.5 s of the arm on its own
            arm.now += 0.001
            arm.runtime.service(arm.now)
            q = float(twin.joint_positions()[lift])
            lowest = q if abs(q - released) > abs(lowest - released) else lowest
            peak = max(peak, abs(float(twin.data.qvel[twin._dofadr[lift]])))
        return peak, abs(lowest - released)
    finally:
        arm.close()


def test_finding_6_stopping_never_drops_an_unbraked_arm(write_config: Callable[..., Path]) -> None:
    dropped_peak, dropped = _stop_an_unbraked_arm(write_config, 0.0)
    lowered_peak, fell_after = _stop_an_unbraked_arm(write_config, 2.0)
    assert dropped > 0.5 and dropped_peak > 3.0  # reproduces the finding: released limp, the shoulder falls
    assert lowered_peak < 0.25 * dropped_peak, (lowered_peak, dropped_peak)
    assert fell_after < 0.5 * dropped, (fell_after, dropped)


# ---- finding 10: the effort trim on a drive that does not apply hild's gains (ODrive) ----------------------------
@pytest.mark.parametrize("glitch", [{"offset": 7.0, "replies": 3}, {"offset": 7.0}])
def test_finding_10_no_feed_forward_a_drive_cannot_take_back(glitch: dict[str, float]) -> None:
    """An ODrive never applies hild's kp/kd: a glitch used to make the trim "compensate" a −125 N·m spring with
    torque_ff 0x7FFF on every fault-hold frame. Now the prediction is the feed-forward alone, a stand-in reading is
    never a spring, and what the drive receives stays at the joint's weight (none on this rig)."""
    from tests.faults.rigs import CanRig

    rig = CanRig("odrive", 2)
    try:
        assert rig.engine.hardware[0].component.APPLIES_GAINS is False
        fw = rig.firmware("j2")
        rig.seconds(0.1)
        fw.glitch.set(0, **glitch)
        worst = 0.0
        for _ in range(500):
            rig.cycle()
            worst = max(worst, abs(fw.input_torque), abs(float(rig.engine.final.effort[1])))
        assert worst == 0.0
        assert rig.driver._ff.clamped == [0, 0]  # nothing ever reached the field's end
        persistent = glitch.get("replies", -1) < 0
        assert rig.engine.supervisor.fault[1] == (Fault.POSITION_LIMIT if persistent else Fault.NONE)
    finally:
        rig.close()


def test_a_feed_forward_beyond_the_drive_field_is_clamped_and_reported_once() -> None:
    from tests.faults.rigs import CanRig

    rig = CanRig("odrive", 2)
    try:
        driver = rig.driver
        emitted: list[str] = []
        driver._ff.emit = lambda level, text: emitted.append(f"{level}: {text}")
        assert driver._ff(1, 40.0) == pytest.approx(32.767)
        assert driver._ff(1, -50.0) == pytest.approx(-32.767)
        assert driver._ff(1, 1.0) == 1.0
        assert driver._ff.clamped == [0, 2]
        assert emitted == [
            "warning: j2: feed-forward 40 N·m beyond the drive's Set_Input_Pos torque_ff (±32.767 N·m): "
            "clamped to 32.767",
            "info: j2: feed-forward back inside the drive's Set_Input_Pos torque_ff",
        ]
    finally:
        rig.close()


# ---- findings 4 and 5: drive errors that persist stay named; state changes are confirmed --------------------------
def test_finding_4_a_drive_error_that_persists_through_reset_stays_named() -> None:
    """A Damiao drive that stays hot keeps its over-temperature after clear-error: reset refuses naming it, the
    joint's fault and enable say the same, and once the drive cools one reset and one enable bring it back."""
    from tests.faults.rigs import CanRig

    rig = CanRig("damiao")
    try:
        fw = rig.firmware("j2")
        rig.seconds(0.1)
        limit = fw.over_temperature
        fw.over_temperature = fw.temperature_rotor - 5.0  # hot, and it stays hot
        rig.seconds(0.1)
        words = "damiao fault 0xc: rotor over-temperature, still present after clear-error (5 tries)"
        for _ in range(2):  # the operator tries again: the same answer, never a relabelled one
            reply = rig.reset()
            assert reply == {"cleared": [], "error": f"arm: j2: {words}"}, reply
            assert rig.engine.supervisor.fault_text[1] == f"arm: {words}"
            assert words in rig.enable()["error"]
            rig.seconds(0.2)
            assert rig.engine.supervisor.fault_text[1] == f"arm: {words}"
        fw.over_temperature = limit  # it cooled down
        assert "error" not in rig.reset()
        rig.seconds(0.1)
        assert "error" not in rig.enable()
        rig.seconds(0.2)
        assert not rig.any_fault() and fw.enabled
    finally:
        rig.close()


def _deaf_to(fw: Any, kind: str, frames: int) -> list[int]:
    """Make ``fw`` ignore its next ``frames`` frames of ``kind`` (lost on the bus); returns a live count of all."""
    from drivers.can.protocol.mit import special_kind

    heard, seen = fw.handle, [0]

    def handle(msg: Any, now: float) -> Any:
        if special_kind(msg.data) == kind:
            seen[0] += 1
            if seen[0] <= frames:
                return []
        return heard(msg, now)

    fw.handle = handle
    return seen


def test_finding_5_enable_and_disable_are_repeated_until_the_drive_confirms() -> None:
    from tests.faults.rigs import CanRig

    rig = CanRig("damiao")
    try:
        fw = rig.firmware("j2")
        rig.seconds(0.1)
        fw.reboot()  # off
        rig.seconds(0.05)
        assert "error" not in rig.reset()
        enables = _deaf_to(fw, "enable", 2)  # the first two enable frames are lost
        assert "error" not in rig.enable()
        rig.seconds(0.2)
        assert fw.enabled and enables[0] == 3 and not rig.any_fault()
        disables = _deaf_to(fw, "disable", 2)
        rig.engine.stop()  # shutdown: disable, confirmed before the bus is closed
        assert not fw.enabled and disables[0] == 3
    finally:
        rig.bus.shutdown()
        rig._dir.cleanup()


# ---- finding 7: stale detection in missed replies and in time --------------------------------------------------
def test_stale_detection_needs_both_the_missed_replies_and_the_time(make_engine: MakeEngine) -> None:
    """stale_feedback_cycles counts cycles without an accepted reading, stale_feedback_time the wall time: a joint
    faults only when both have passed, so a late daemon (few cycles, much time: its drive's replies wait in the
    buffer) and a fast rate (many cycles, little time) are both told from a drive that went silent."""
    engine = make_engine({"safety": {"stale_feedback_cycles": 5, "stale_feedback_time": 0.05}})
    mock = engine.hardware[0].component
    mock.silent[1] = True
    for _ in range(10):  # 10 missed replies, but only 20 ms: a fast rate's missed replies are not yet a fault
        engine.run_cycles(1)
    assert engine.supervisor.fault[1] == Fault.NONE
    for _ in range(2):  # two cycles 30 ms late each (a stalled host): the time passes, and they were missed too
        engine.step(engine.t + 0.03, 0.03)
    assert engine.supervisor.fault[1] == Fault.STALE_FEEDBACK
    assert engine.status()["joints"][1]["fault"] == "no feedback for 11 cycles"  # 20 + 30 ms: both passed
    assert engine.status()["joints"][1]["longest_silence_ms"] == pytest.approx(80.0)
    # Time alone is not enough either: one long late cycle is one missed reply.
    other = make_engine({"safety": {"stale_feedback_cycles": 5, "stale_feedback_time": 0.05}})
    other.hardware[0].component.silent[0] = True
    other.step(other.t + 0.2, 0.2)
    assert other.supervisor.fault[0] == Fault.NONE


def test_at_a_fast_rate_the_time_bound_holds_the_fault_back(make_engine: MakeEngine) -> None:
    """At 1 kHz, 10 missed replies are 10 ms: within what a loaded loopback rig's emulator goes quiet for. With
    ``stale_feedback_time`` the joint faults when the time has passed, on the cycle after, not before."""
    engine = make_engine({"update_rate": 1000, "safety": {"stale_feedback_cycles": 10, "stale_feedback_time": 0.05}})
    engine.hardware[0].component.silent[2] = True
    engine.run_cycles(49)  # 49 missed replies, 49 ms: the cycle bound long passed, the time bound not yet
    assert engine.supervisor.fault[2] == Fault.NONE
    engine.run_cycles(2)  # 50 ms reached on the 50th (or, with float sums, the 51st)
    assert engine.supervisor.fault[2] == Fault.STALE_FEEDBACK
    assert engine.supervisor.fault[0] == engine.supervisor.fault[1] == Fault.NONE


def test_one_accepted_reading_restarts_both_the_count_and_the_clock(make_engine: MakeEngine) -> None:
    """A drive that answers now and then is not silent: a single accepted reading restarts the missed replies and
    the time, so two silences that each stay under the bounds never add up to a fault."""
    engine = make_engine({"safety": {"stale_feedback_cycles": 5, "stale_feedback_time": 0.05}})
    mock = engine.hardware[0].component
    for _ in range(2):
        mock.silent[0] = True
        for _ in range(4):  # 4 missed replies in 80 ms: the time passed, the count not
            engine.step(engine.t + 0.02, 0.02)
        mock.silent[0] = False
        engine.run_cycles(1)
        assert engine.supervisor.fault[0] == Fault.NONE
    mock.silent[0] = True
    for _ in range(5):  # now both pass within one silence: 5 missed replies, 100 ms
        engine.step(engine.t + 0.02, 0.02)
    assert engine.supervisor.fault[0] == Fault.STALE_FEEDBACK
    assert engine.status()["joints"][0]["longest_silence_ms"] == pytest.approx(100.0)
