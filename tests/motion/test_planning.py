"""Ruckig planning: moves, stops and untimed waypoint chains stay within limits and do what they promise."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hild.motion.limits import KinematicLimits
from hild.motion.planning import PlanningError, plan_move, plan_stop, plan_waypoints
from hild.motion.segments import HoldSegment, Segment
from hild.motion.trajectory import Trajectory
from tests.motion.sampling import assert_within_limits, sample_segment, state_at

PROPERTY = settings(derandomize=True, max_examples=80, deadline=None)
LIMITS3 = KinematicLimits(np.array([1.0, 2.0, 0.5]), np.array([4.0, 6.0, 2.0]), np.array([40.0, 50.0, 20.0]))
Z3 = np.zeros(3)


@st.composite
def limits_for(draw, joints: int) -> KinematicLimits:
    def vec(lo: float, hi: float) -> np.ndarray:
        return np.array([draw(st.floats(lo, hi)) for _ in range(joints)])

    return KinematicLimits(vec(0.2, 3.0), vec(0.5, 10.0), vec(2.0, 100.0))


@st.composite
def admissible_state(draw, limits: KinematicLimits) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A state from which the limits can be kept: bringing a to 0 at full jerk leaves |v| <= vmax."""
    j = limits.joints
    p = np.array([draw(st.floats(-2.0, 2.0)) for _ in range(j)])
    v = np.array([draw(st.floats(-1.0, 1.0)) for _ in range(j)]) * limits.velocity
    a = np.array([draw(st.floats(-1.0, 1.0)) for _ in range(j)]) * limits.acceleration
    # Ramping a to 0 at full jerk changes v by a|a| / 2j: keep the velocity reached that way within ±vmax.
    a_up = np.sqrt(2.0 * limits.jerk * np.maximum(limits.velocity - v, 0.0))
    a_down = np.sqrt(2.0 * limits.jerk * np.maximum(limits.velocity + v, 0.0))
    return p, v, np.clip(a, -a_down, a_up)


def assert_starts_and_ends(segment: Segment, start: tuple, end: tuple, joints: int) -> None:
    for got, want in zip(state_at(segment, 0.0, joints), start, strict=True):
        np.testing.assert_allclose(got, want, atol=1e-9)
    for got, want in zip(state_at(segment, segment.duration, joints), end, strict=True):
        np.testing.assert_allclose(got, want, atol=1e-8)


def assert_exact_bounds(segment: Segment, joints: int) -> None:
    """position_bounds enclose a dense sampling and are attained (tight to the sampling resolution)."""
    _, p, v, _ = sample_segment(segment, joints, steps=2000)
    lo, hi = segment.position_bounds()
    assert np.all(p >= lo - 1e-12) and np.all(p <= hi + 1e-12)
    step = segment.duration / 2000 * np.abs(v).max(axis=0) + 1e-12  # how far a sample can be from the extremum
    assert np.all(p.min(axis=0) <= lo + step) and np.all(p.max(axis=0) >= hi - step)


def test_bounds_catch_extrema_that_ruckigs_position_extrema_misses() -> None:
    """pantor/ruckig#215: on this leg joint 2 dips below its target inside a phase; position_extrema says 0."""
    limits = KinematicLimits(np.ones(3), np.array([1.0, 1.0, 0.5]), np.array([2.0, 2.0, 5.0]))
    waypoints = np.array([[0.03, 0.0, 0.01], [0.01, 0.0, 0.0]])
    velocities = np.array([[0.0, 0.0, -0.07979910714285715], [-0.05803571428571429, 0.0, -0.05803571428571429]])
    _, (leg,) = plan_waypoints(waypoints, limits, velocities)  # ruckig 0.19.4's position_extrema: min 0 for joint 2
    lo, _ = leg.position_bounds()
    assert lo[2] < -1e-4
    assert_exact_bounds(leg, 3)


# ---- plan_move --------------------------------------------------------------------------------------------------
@st.composite
def move_problem(draw):
    j = draw(st.integers(1, 6))
    limits = draw(limits_for(j))
    p, v, a = draw(admissible_state(limits))
    target = np.array([draw(st.floats(-2.0, 2.0)) for _ in range(j)])
    target_v = None
    if draw(st.booleans()):
        target_v = np.array([draw(st.floats(-1.0, 1.0)) for _ in range(j)]) * limits.velocity
    return limits, (p, v, a), target, target_v


@PROPERTY
@given(move_problem())
def test_move_respects_limits_and_reaches_the_target(problem) -> None:
    limits, (p, v, a), target, target_v = problem
    seg = plan_move(p, v, a, target, target_v, limits)
    end_v = np.zeros(limits.joints) if target_v is None else target_v
    assert_starts_and_ends(seg, (p, v, a), (target, end_v, np.zeros(limits.joints)), limits.joints)
    assert_within_limits(seg, limits, steps=1000)
    assert_exact_bounds(seg, limits.joints)


def test_move_is_synchronized_and_time_optimal() -> None:
    target = np.array([1.0, 0.2, -0.1])
    seg = plan_move(Z3, Z3, Z3, target, None, LIMITS3)
    alone = [
        plan_move(Z3[:1], Z3[:1], Z3[:1], target[j : j + 1], None, LIMITS3.subset(np.array([j]))).duration
        for j in range(3)
    ]
    assert seg.duration == pytest.approx(max(alone), rel=1e-9), "as fast as the slowest joint allows"
    assert min(alone) < 0.5 * seg.duration, "the test needs joints that could finish much earlier"
    p, v, _ = state_at(seg, 0.97 * seg.duration, 3)
    assert np.all(np.abs(target - p) > 1e-6) and np.all(np.abs(v) > 1e-6), "every joint still moving near the end"


def test_min_duration_stretches_but_never_speeds_up() -> None:
    target = np.array([0.5, -0.5, 0.2])
    fastest = plan_move(Z3, Z3, Z3, target, None, LIMITS3).duration
    stretched = plan_move(Z3, Z3, Z3, target, None, LIMITS3, min_duration=3.0 * fastest)
    assert stretched.duration == pytest.approx(3.0 * fastest, rel=1e-9)
    assert_starts_and_ends(stretched, (Z3, Z3, Z3), (target, Z3, Z3), 3)
    assert_within_limits(stretched, LIMITS3)
    assert plan_move(Z3, Z3, Z3, target, None, LIMITS3, min_duration=0.1 * fastest).duration == pytest.approx(fastest)


def test_move_reaches_a_target_velocity() -> None:
    target_v = np.array([0.5, -1.0, 0.0])
    seg = plan_move(Z3, np.array([0.2, 0.0, 0.1]), Z3, np.array([1.0, -1.0, 0.3]), target_v, LIMITS3)
    np.testing.assert_allclose(state_at(seg, seg.duration, 3)[1], target_v, atol=1e-9)


def test_move_rejects_what_cannot_be_done() -> None:
    with pytest.raises(PlanningError, match=r"target_v exceeds its limit \(joint 1: \|2.5\| > 2"):
        plan_move(Z3, Z3, Z3, Z3, np.array([0.0, 2.5, 0.0]), LIMITS3)
    with pytest.raises(PlanningError, match=r"p must be finite; joints \[2\]"):
        plan_move(np.array([0.0, 0.0, np.nan]), Z3, Z3, Z3, None, LIMITS3)
    with pytest.raises(PlanningError, match="target_p must be finite"):
        plan_move(Z3, Z3, Z3, np.array([np.inf, 0.0, 0.0]), None, LIMITS3)
    with pytest.raises(PlanningError, match="shape"):
        plan_move(np.zeros(2), Z3, Z3, Z3, None, LIMITS3)
    with pytest.raises(PlanningError, match="min_duration"):
        plan_move(Z3, Z3, Z3, Z3, None, LIMITS3, min_duration=-1.0)
    assert issubclass(PlanningError, ValueError)


def test_move_clips_a_target_velocity_beyond_the_limit_by_rounding_only() -> None:
    target_v = LIMITS3.velocity * (1.0 + 1e-12)
    seg = plan_move(Z3, Z3, Z3, np.ones(3), target_v, LIMITS3)
    np.testing.assert_allclose(state_at(seg, seg.duration, 3)[1], LIMITS3.velocity, rtol=1e-12)


def test_move_from_beyond_the_limits_brakes_back_inside() -> None:
    """A goal accepted with slower limits while moving fast: ruckig first brakes, it does not refuse."""
    slow = LIMITS3.scaled(0.25, 0.25)
    v0 = np.array([0.9, -1.5, 0.4])  # within the full limits, far beyond the scaled ones
    seg = plan_move(Z3, v0, Z3, np.array([2.0, -2.0, 1.0]), None, slow)
    _, _, v, _ = sample_segment(seg, 3)
    np.testing.assert_allclose(v[0], v0)
    inside = np.all(np.abs(v) <= slow.velocity * (1 + 1e-6), axis=1)
    assert inside[-1] and np.all(inside[np.argmax(inside) :]), "once braked inside the limits it stays inside"
    np.testing.assert_allclose(state_at(seg, seg.duration, 3)[0], [2.0, -2.0, 1.0], atol=1e-9)


# ---- plan_stop --------------------------------------------------------------------------------------------------
@st.composite
def stop_problem(draw):
    limits = draw(limits_for(draw(st.integers(1, 6))))
    return limits, draw(admissible_state(limits))


@PROPERTY
@given(stop_problem())
def test_stop_comes_to_rest_within_limits(problem) -> None:
    limits, (p, v, a) = problem
    seg = plan_stop(p, v, a, limits)
    j = limits.joints
    for got, want in zip(state_at(seg, 0.0, j), (p, v, a), strict=True):
        np.testing.assert_allclose(got, want, atol=1e-9)
    _, v_end, a_end = state_at(seg, seg.duration, j)
    np.testing.assert_allclose(v_end, 0.0, atol=1e-9)
    np.testing.assert_allclose(a_end, 0.0, atol=1e-9)
    assert_within_limits(seg, limits, steps=1000)
    assert_exact_bounds(seg, j)


def test_stop_brakes_each_joint_as_hard_as_it_alone_could() -> None:
    p0, v0, a0 = np.array([0.1, 0.2, 0.3]), np.array([0.8, -1.5, 0.1]), np.array([1.0, 2.0, -1.0])
    seg = plan_stop(p0, v0, a0, LIMITS3)
    alone = [plan_stop(p0[j : j + 1], v0[j : j + 1], a0[j : j + 1], LIMITS3.subset(np.array([j]))) for j in range(3)]
    assert seg.duration == pytest.approx(max(s.duration for s in alone), rel=1e-12)
    for t in np.linspace(0.0, seg.duration, 50):
        state = state_at(seg, float(t), 3)
        for j, single in enumerate(alone):
            for got, want in zip(state, state_at(single, float(t), 1), strict=True):
                assert got[j] == pytest.approx(want[0], abs=1e-12)


def test_stop_from_beyond_the_limits_still_stops() -> None:
    seg = plan_stop(Z3, LIMITS3.velocity * 3.0, -LIMITS3.acceleration * 2.0, LIMITS3)
    _, v, a = state_at(seg, seg.duration, 3)
    np.testing.assert_allclose(v, 0.0, atol=1e-9)
    np.testing.assert_allclose(a, 0.0, atol=1e-9)


def test_stop_at_rest_takes_no_time() -> None:
    seg = plan_stop(np.ones(3), Z3, Z3, LIMITS3)
    assert seg.duration == 0.0
    np.testing.assert_allclose(state_at(seg, 0.0, 3)[0], np.ones(3))


# ---- plan_waypoints ---------------------------------------------------------------------------------------------
def stop_at_every_waypoint(waypoints: np.ndarray, limits: KinematicLimits) -> float:
    zero = np.zeros(limits.joints)
    return sum(plan_move(w0, zero, zero, w1, None, limits).duration for w0, w1 in itertools.pairwise(waypoints))


def assert_valid_chain(waypoints: np.ndarray, limits: KinematicLimits, velocities: np.ndarray, legs: list) -> None:
    n, j = waypoints.shape
    assert velocities.shape == (n, j)
    assert len(legs) == n - 1
    for i, leg in enumerate(legs):
        w0, w1 = waypoints[i], waypoints[i + 1]
        # Through both waypoints with the reported velocities and a = 0: so v and a are continuous at each one.
        assert_starts_and_ends(leg, (w0, velocities[i], np.zeros(j)), (w1, velocities[i + 1], np.zeros(j)), j)
        tol = 1e-9 + 1e-6 * np.abs(w1 - w0)
        lo, hi = leg.position_bounds()
        assert np.all(lo >= np.minimum(w0, w1) - tol), f"leg {i} undershoots: {lo} vs {w0} → {w1}"
        assert np.all(hi <= np.maximum(w0, w1) + tol), f"leg {i} overshoots: {hi} vs {w0} → {w1}"
        if leg.duration > 0.0:
            _, p, _, _ = sample_segment(leg, j, steps=300)
            assert np.all(p >= np.minimum(w0, w1) - tol) and np.all(p <= np.maximum(w0, w1) + tol)
        assert_within_limits(leg, limits, steps=300)
    traj = Trajectory(legs, j)
    for start, point in zip(traj.start_times(), waypoints, strict=False):
        if traj.finished(start):
            continue
        np.testing.assert_allclose(state_at(traj, float(start), j)[0], point, atol=1e-8)
    np.testing.assert_allclose(traj.final_position(), waypoints[-1], atol=1e-8)


@st.composite
def waypoint_problem(draw):
    j = draw(st.integers(1, 6))
    n = draw(st.integers(2, 12))
    if draw(st.booleans()):  # a coarse grid: repeated waypoints, joints standing still, reversals
        step = draw(st.sampled_from([0.01, 0.2, 1.0]))
        waypoints = np.array([[draw(st.integers(-3, 3)) * step for _ in range(j)] for _ in range(n)])
    else:
        waypoints = np.array([[draw(st.floats(-2.0, 2.0)) for _ in range(j)] for _ in range(n)])
    return waypoints, draw(limits_for(j))


@PROPERTY
@given(waypoint_problem())
def test_waypoint_chain_passes_through_every_waypoint_within_limits_and_boxes(problem) -> None:
    waypoints, limits = problem
    velocities, legs = plan_waypoints(waypoints, limits)
    assert_valid_chain(waypoints, limits, velocities, legs)
    assert not velocities[0].any() and not velocities[-1].any()
    d = np.diff(waypoints, axis=0)
    turning = d[:-1] * d[1:] <= 0.0  # a joint that reverses or stands still next to an interior waypoint
    assert not velocities[1:-1][turning].any()
    chain = sum(leg.duration for leg in legs)
    assert chain <= stop_at_every_waypoint(waypoints, limits) * (1 + 1e-9) + 1e-12


def line(points: int) -> np.ndarray:
    return np.linspace([0.0, 0.0, 0.0], [1.5, -0.8, 0.4], points)


def arc(points: int) -> np.ndarray:
    s = np.linspace(0.0, np.pi, points)
    return np.c_[np.cos(s), np.sin(s), 0.3 * s]


@pytest.mark.parametrize("waypoints", [line(8), line(40), arc(15), arc(40)], ids=["line8", "line40", "arc15", "arc40"])
def test_smooth_paths_are_much_faster_than_stopping_at_every_waypoint(waypoints: np.ndarray) -> None:
    velocities, legs = plan_waypoints(waypoints, LIMITS3)
    assert_valid_chain(waypoints, LIMITS3, velocities, legs)
    chain = sum(leg.duration for leg in legs)
    assert chain < 0.6 * stop_at_every_waypoint(waypoints, LIMITS3)
    assert np.all(np.abs(velocities[1:-1]).max(axis=1) > 0.0), "it passes every interior waypoint without stopping"


def test_a_line_takes_about_as_long_as_one_move() -> None:
    waypoints = line(8)
    _, legs = plan_waypoints(waypoints, LIMITS3)
    direct = plan_move(waypoints[0], Z3, Z3, waypoints[-1], None, LIMITS3).duration
    assert sum(leg.duration for leg in legs) < 1.1 * direct


def test_one_waypoint_gives_no_legs() -> None:
    velocities, legs = plan_waypoints(np.array([[0.1, 0.2, 0.3]]), LIMITS3)
    assert legs == [] and velocities.shape == (1, 3) and not velocities.any()


def test_repeated_waypoints_give_zero_length_legs() -> None:
    a, b, c = np.array([0.0, 0.0, 0.0]), np.array([0.5, 0.1, -0.2]), np.array([1.0, 0.3, -0.2])
    waypoints = np.array([a, a, b, b, b, c])
    velocities, legs = plan_waypoints(waypoints, LIMITS3)
    assert_valid_chain(waypoints, LIMITS3, velocities, legs)
    assert [leg.duration == 0.0 for leg in legs] == [True, False, True, True, False]
    assert all(isinstance(legs[i], HoldSegment) for i in (0, 2, 3))


def test_a_joint_that_does_not_move_stays_exactly_put() -> None:
    waypoints = np.c_[np.linspace(0.0, 1.0, 6), np.full(6, 0.3), np.linspace(0.0, -0.5, 6)]
    velocities, legs = plan_waypoints(waypoints, LIMITS3)
    assert_valid_chain(waypoints, LIMITS3, velocities, legs)
    assert not velocities[:, 1].any()
    for leg in legs:
        _, p, v, _ = sample_segment(leg, 3, steps=200)
        np.testing.assert_allclose(p[:, 1], 0.3, atol=1e-12)
        np.testing.assert_allclose(v[:, 1], 0.0, atol=1e-12)


def test_given_velocities_are_used_as_they_are() -> None:
    waypoints = np.array([[0.0, 0.0, 0.0], [0.5, 0.5, 0.1], [1.0, 0.0, 0.2]])
    given = np.array([[0.0, 0.0, 0.0], [0.8, 0.0, 0.1], [0.2, -0.5, 0.0]])  # the last one need not be 0
    velocities, legs = plan_waypoints(waypoints, LIMITS3, given)
    np.testing.assert_array_equal(velocities, given)
    for i, leg in enumerate(legs):
        assert_starts_and_ends(leg, (waypoints[i], given[i], Z3), (waypoints[i + 1], given[i + 1], Z3), 3)
        assert_within_limits(leg, LIMITS3)


def test_given_velocities_beyond_the_limits_are_refused() -> None:
    waypoints = np.zeros((3, 3))
    given = np.zeros((3, 3))
    given[2, 1] = 2.5
    with pytest.raises(PlanningError, match=r"velocity at waypoint 2 exceeds its limit \(joint 1"):
        plan_waypoints(waypoints, LIMITS3, given)
    with pytest.raises(PlanningError, match="velocities: expected shape"):
        plan_waypoints(waypoints, LIMITS3, np.zeros((2, 3)))


def test_waypoints_are_validated() -> None:
    with pytest.raises(PlanningError, match="finite"):
        plan_waypoints(np.array([[0.0, 0.0, 0.0], [0.0, np.nan, 0.0]]), LIMITS3)
    with pytest.raises(PlanningError, match=r"expected shape \(N, 3\)"):
        plan_waypoints(np.zeros((4, 2)), LIMITS3)
    with pytest.raises(PlanningError, match="N >= 1"):
        plan_waypoints(np.zeros((0, 3)), LIMITS3)
