"""The supervisor on its own (issue [trust], deliverable 10): hypothesis drives it with random sequences of readings
(glitches included), claims, controller commands and operator actions, and checks on every cycle what it promises:

* a stiff command never steps more than ``velocity_limit · dt`` (from the last stiff command, or from the accepted
  reading when there was none);
* no feed-forward beyond the effort limit, nothing non-finite, ever;
* a rejected reading is never in the state and never a target: an unclaimed joint's command only goes on toward
  its latch (an accepted position) while its readings are rejected;
* an unclaimed joint with plausible readings holds its latch;
* with ``applies_gains`` False the trim never reacts to kp/kd;
* a faulted joint gets no more feed-forward than gravity at its last accepted pose (the arm is pushed away from
  its latch at times, so the trim has a real spring to act on).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hild.arrays import JointState, ServoCommand
from hild.controller import JointLimitArrays
from hild.crossing.events import EventLog
from hild.cycle.supervisor import LIMIT_EFFORT, Action, Fault, JointGains, SafetySettings, Supervisor
from hild.interfaces import ClaimMasks
from hild.modes import JointMode

N = 3
DT = 0.002
LOWER, UPPER, VMAX, EMAX = -1.0, 1.0, 2.0, 20.0
WEIGHT = np.array([8.0, 3.0, 0.0])  # gravity torque amplitude per joint: g_i = WEIGHT_i · cos(q_i)
READINGS = ("true", "true", "true", "push", "push", "spike", "jump", "nan", "missing", "frozen", "flip")
CLAIMS = ("none", "position", "velocity", "effort", "effort+gravity")
OPS = ("none", "none", "none", "none", "trip", "estop", "reset")


def gravity(q: np.ndarray, out: np.ndarray) -> None:
    np.multiply(WEIGHT, np.cos(q), out=out)


def make(applies_gains: bool, action: str) -> Supervisor:
    full = np.full(N, 1.0)
    limits = JointLimitArrays(
        lower=full * LOWER,
        upper=full * UPPER,
        soft_lower=full * (LOWER + 0.05),
        soft_upper=full * (UPPER - 0.05),
        velocity=full * VMAX,
        effort=full * EMAX,
        acceleration=full * np.nan,
        jerk=full * np.nan,
    )
    gains = JointGains(full * 100.0, full * 5.0, full * 100.0, full * 5.0, full * 5.0)
    safety = SafetySettings(10, 1.5, Action[action.upper()], Action.HOLD)
    return Supervisor(
        tuple(f"j{i}" for i in range(N)), limits, gains, safety, EventLog(), gravity, None, np.full(N, applies_gains)
    )


def masks(claims: list[str]) -> ClaimMasks:
    m = ClaimMasks.empty(N)
    for i, claim in enumerate(claims):
        if claim != "none":
            m.owner[i] = 0
            for field in claim.split("+"):  # effort+gravity: the controller's effort with the gravity torque added
                getattr(m, field)[i] = True
    return m


@dataclass
class Cycle:
    readings: list[str]
    command: list[float]
    op: str
    joint: int


finite_or_not = st.one_of(
    st.floats(-3.0, 3.0), st.sampled_from([math.nan, math.inf, -math.inf, 1e9, -1e9]), st.floats(-0.9, 0.9)
)
cycles = st.lists(
    st.builds(
        Cycle,
        st.lists(st.sampled_from(READINGS), min_size=N, max_size=N),
        st.lists(finite_or_not, min_size=N, max_size=N),
        st.sampled_from(OPS),
        st.integers(0, N - 1),
    ),
    min_size=20,
    max_size=120,
)


@settings(
    max_examples=150, deadline=None, derandomize=True, database=None, suppress_health_check=[HealthCheck.too_slow]
)
@given(
    claims=st.lists(st.sampled_from(CLAIMS), min_size=N, max_size=N),
    start=st.lists(st.floats(-0.8, 0.8), min_size=N, max_size=N),
    script=cycles,
    applies_gains=st.booleans(),
    action=st.sampled_from(["hold", "damp", "disable"]),
)
def test_the_supervisor_keeps_its_promises(
    claims: list[str], start: list[float], script: list[Cycle], applies_gains: bool, action: str
) -> None:
    sup = make(applies_gains, action)
    true_q = np.array(start)
    state, ctrl, out = JointState.zeros(N), ServoCommand.zeros(N), ServoCommand.zeros(N)
    state.position[:] = true_q
    sup.start(state)
    sup.set_claims(masks(claims))
    out.position[:] = sup.latched
    out.kp[:] = 100.0
    frozen = true_q.copy()
    pushed = np.zeros(N)  # someone leans on the arm: it sits this far from where its drive holds it
    pushing = [0] * N  # cycles the push goes on
    g_accepted = np.zeros(N)
    for step in script:
        if step.op == "trip":
            sup.trip(step.joint, Fault.HARDWARE, "test")
        elif step.op == "estop":
            sup.engage_estop()
        elif step.op == "reset" and sup.refusal() is None:
            sup.reset()
        # What the drives report this cycle.
        rejected_value = np.full(N, np.nan)
        for i, kind in enumerate(step.readings):
            if kind == "push":
                pushing[i] = 40
            if pushing[i]:  # a plausible step each cycle, up to 0.5 rad from where the drive holds it
                pushing[i] -= 1
                pushed[i] = min(0.5, pushed[i] + 0.012)
            q = true_q[i] + pushed[i] + 1e-5 * math.sin(len(script) + i)
            state.fresh[i] = kind != "missing"
            bad = {"spike": 7.0, "jump": q + 0.5, "nan": math.nan, "frozen": frozen[i], "flip": -q}.get(kind)
            state.position[i] = q if bad is None else bad
            state.velocity[i] = 0.5 if kind == "frozen" else 0.0
            if bad is not None and not (kind == "flip" and abs(2 * q) < 0.02) and kind != "frozen":
                rejected_value[i] = bad
        prev_p, prev_kp = out.position.copy(), out.kp.copy()
        sup.check(state, DT)
        # 5. Nothing rejected or missing is in the state: the last accepted reading stands in.
        stand_in = ~state.fresh
        np.testing.assert_array_equal(state.position[stand_in], sup.gate.accepted_position[stand_in])
        for i, value in enumerate(rejected_value):
            if not math.isnan(value):
                assert state.position[i] != value or sup.gate.accepted_position[i] == value
        ctrl.position[:], ctrl.velocity[:], ctrl.effort[:] = step.command, step.command, step.command
        ctrl.kp[:], ctrl.kd[:] = 50.0, 2.0
        ctrl.written[:] = [c != "none" for c in claims]
        sup.command(DT, state, ctrl, out)
        finals = (out.position, out.velocity, out.effort, out.kp, out.kd)
        # 2. Everything finite, feed-forward within the effort limit (gravity on top of an effort included).
        assert all(np.isfinite(a).all() for a in finals), finals
        assert (np.abs(out.effort) <= EMAX + 1e-9).all(), out.effort
        gravity(np.nan_to_num(sup.gate.accepted_position), g_accepted)
        for i in range(N):
            stiff = out.kp[i] > 0.0
            # 1. No jump: from the last stiff command, or from the accepted reading when nothing held the joint.
            origin = prev_p[i] if prev_kp[i] > 0.0 else state.position[i]
            if stiff and not math.isnan(origin):
                assert abs(out.position[i] - origin) <= VMAX * DT + 1e-9, (i, out.position[i], origin)
            unclaimed = claims[i] == "none" or sup.mode[i] >= JointMode.FAULT
            # 3. An unclaimed joint never targets a rejected reading: it only goes on toward its latch, an accepted
            #    position (with a glitch from a still arm, that is: it does not move at all — test_trust.py).
            if unclaimed and not math.isnan(rejected_value[i]) and stiff and prev_kp[i] > 0.0 and step.op == "none":
                assert sup.latched[i] != rejected_value[i]
                assert abs(out.position[i] - sup.latched[i]) <= abs(prev_p[i] - sup.latched[i]) + 1e-12, i
            # 4. Holding with plausible readings: the command goes to the latch (slewed) and stays there.
            if sup.mode[i] == JointMode.HOLD and state.fresh[i] and step.op == "none" and prev_kp[i] > 0.0:
                assert abs(out.position[i] - sup.latched[i]) <= abs(prev_p[i] - sup.latched[i]) + 1e-12
            # 7. A faulted joint: no more feed-forward than its weight at the last accepted pose.
            if sup.mode[i] >= JointMode.FAULT:
                assert abs(out.effort[i]) <= abs(g_accepted[i]) + 1e-9, (i, out.effort[i], g_accepted[i])
            # 6. A drive that does not apply our gains: the trim never reacts to kp/kd.
            if not applies_gains and claims[i] == "none" and sup.mode[i] == JointMode.HOLD:
                assert out.effort[i] == min(EMAX, max(-EMAX, g_accepted[i]))
        # The world: a stiff drive goes where it is told (within the slew), a limp one stays.
        moving = out.kp > 0.0
        true_q[moving] = np.clip(out.position[moving], LOWER, UPPER)


def test_frozen_detection_is_bounded_by_the_claimed_travel() -> None:
    sup = make(True, "hold")
    state = JointState.zeros(N)
    sup.start(state)
    state.velocity[:] = [1.0, 0.0, 0.0]  # the drive claims 1 rad/s on j0, its position never changes
    cycles = 0
    while not sup.gate.rejected[0]:
        sup.check(state, DT)
        cycles += 1
        assert cycles < 100
    assert cycles <= math.floor(0.02 / (1.0 * DT)) + 1  # FROZEN_TRAVEL / claimed speed (+1 for rounding)


def test_the_jump_bound_grows_only_over_cycles_without_a_reading() -> None:
    sup = make(True, "hold")
    state = JointState.zeros(N)
    sup.start(state)
    state.fresh[:] = False
    for _ in range(50):  # 0.1 s of silence: the joint may have moved 3 · 2 rad/s · 0.1 s = 0.6 rad
        sup.check(state, DT)
    state.fresh[:] = True
    state.position[0] = 0.55
    sup.check(state, DT)
    assert not sup.gate.rejected[0] and sup.gate.accepted_position[0] == 0.55
    # A reading that arrives every cycle and is rejected never ages into an acceptable one.
    sup2 = make(True, "hold")
    s2 = JointState.zeros(N)
    sup2.start(s2)
    for _ in range(200):
        s2.position[2], s2.fresh[:] = 0.3, True  # what the drive reports (the gate writes stand-ins over it)
        sup2.check(s2, DT)
        assert sup2.gate.rejected[2] and s2.position[2] == 0.0


def test_set_zero_accepts_the_frame_jump_and_latches_the_new_reading() -> None:
    sup = make(True, "hold")
    state, ctrl, out = JointState.zeros(N), ServoCommand.zeros(N), ServoCommand.zeros(N)
    state.position[:] = [0.7, 0.0, 0.0]
    sup.start(state)
    sup.follow_measured(0, 5, new_frame=True)
    state.position[0] = 0.0  # the drive's new frame
    for _ in range(6):
        sup.check(state, DT)
        sup.command(DT, state, ctrl, out)
    assert not sup.gate.rejected[0] and sup.latched[0] == 0.0 and out.position[0] == 0.0


def test_the_trim_takes_torque_away_from_a_faulted_joint_and_never_adds_any() -> None:
    """A faulted joint held at its latch and pushed 0.5 rad away (plausible readings, a real spring of 50 N·m):
    the trim may only remove feed-forward, never add torque of the other sign (finding 10's −125 N·m
    "compensation"); the limit it cannot keep is reported. On a drive that does not apply our gains there is no
    spring to see."""
    for applies_gains in (True, False):
        sup = make(applies_gains, "hold")
        state, ctrl, out = JointState.zeros(N), ServoCommand.zeros(N), ServoCommand.zeros(N)
        sup.start(state)
        sup.trip(1, Fault.HARDWARE, "test")
        g = np.zeros(N)
        for k in range(60):
            state.position[:] = [0.0, min(0.5, 0.012 * (k + 1)), 0.0]
            state.fresh[:] = True
            sup.check(state, DT)
            sup.command(DT, state, ctrl, out)
            gravity(state.position, g)
            assert 0.0 <= out.effort[1] <= g[1] + 1e-12, (applies_gains, k, out.effort[1], g[1])
        assert out.kp[1] > 0.0  # still held: the reading is trusted, only the torque is bounded
        # The spring alone exceeds the limit: reported (not silently "compensated"); an ODrive-like drive has none.
        assert bool(sup.limit_flags[1] & LIMIT_EFFORT) is applies_gains


def test_gravity_on_top_of_an_effort_claim_is_added_and_stays_within_the_effort_limit() -> None:
    """An effort claim replaces the feed-forward; with gravity asked for on top (``ClaimMasks.gravity``), the drive
    gets the controller's effort plus the model's gravity torque at the accepted pose, clamped to ±effort."""
    sup = make(True, "hold")
    state, ctrl, out = JointState.zeros(N), ServoCommand.zeros(N), ServoCommand.zeros(N)
    state.position[:] = [0.3, 0.3, 0.3]
    sup.start(state)
    sup.set_claims(masks(["effort", "effort+gravity", "effort+gravity"]))
    g = np.zeros(N)
    gravity(state.position, g)
    for effort, expected in ((1.5, [1.5, 1.5 + g[1], 1.5]), (19.0, [19.0, EMAX, 19.0])):
        ctrl.effort[:], ctrl.written[:] = effort, True
        sup.check(state, DT)
        sup.command(DT, state, ctrl, out)
        np.testing.assert_allclose(out.effort, expected)  # j2 weighs nothing: gravity adds 0
        assert (out.kp == 0.0).all() and (out.kd == 0.0).all()
    assert sup.limit_flags[1] & LIMIT_EFFORT and not sup.limit_flags[0] & LIMIT_EFFORT
