"""Segments: boundary conditions of each polynomial kind, sampling semantics, exact position bounds."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from hild.motion.segments import HoldSegment, PolynomialSegment, RuckigSegment
from tests.motion.sampling import sample_segment, state_at

finite = st.floats(-5.0, 5.0, allow_nan=False)
durations = st.floats(0.01, 10.0)


def vectors(joints: int):
    return arrays(np.float64, joints, elements=finite)


@st.composite
def boundary_problem(draw):
    j = draw(st.integers(1, 6))
    return [draw(vectors(j)) for _ in range(6)], draw(durations)


def assert_state(actual: tuple[np.ndarray, ...], expected: tuple[np.ndarray, ...], scale: float) -> None:
    for got, want in zip(actual, expected, strict=True):
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * scale)


@settings(derandomize=True, max_examples=100, deadline=None)
@given(boundary_problem())
def test_quintic_matches_position_velocity_acceleration_at_both_ends(problem) -> None:
    (p0, v0, a0, p1, v1, a1), duration = problem
    seg = PolynomialSegment.quintic(p0, v0, a0, p1, v1, a1, duration)
    scale = 1.0 + max(1.0, 1.0 / duration) ** 2 * 10
    assert_state(state_at(seg, 0.0, len(p0)), (p0, v0, a0), scale)
    assert_state(state_at(seg, duration, len(p0)), (p1, v1, a1), scale)


@settings(derandomize=True, max_examples=100, deadline=None)
@given(boundary_problem())
def test_cubic_matches_position_and_velocity_at_both_ends(problem) -> None:
    (p0, v0, _, p1, v1, _), duration = problem
    seg = PolynomialSegment.cubic(p0, v0, p1, v1, duration)
    j = len(p0)
    p, v, _ = state_at(seg, 0.0, j)
    np.testing.assert_allclose(p, p0, atol=1e-9)
    np.testing.assert_allclose(v, v0, atol=1e-9)
    p, v, _ = state_at(seg, duration, j)
    np.testing.assert_allclose(p, p1, atol=1e-9)
    np.testing.assert_allclose(v, v1, atol=1e-9 * max(1.0, 1.0 / duration))
    assert not seg.coefficients[:, 4:].any(), "a cubic has no 4th/5th order terms"


def test_linear_moves_at_constant_velocity() -> None:
    seg = PolynomialSegment.linear(np.array([0.0, 1.0]), np.array([2.0, -1.0]), 4.0)
    for t in (0.0, 1.0, 2.5, 4.0):
        p, v, a = state_at(seg, t, 2)
        np.testing.assert_allclose(p, [0.5 * t, 1.0 - 0.5 * t], atol=1e-15)
        np.testing.assert_allclose(v, [0.5, -0.5], atol=1e-15)
        np.testing.assert_array_equal(a, [0.0, 0.0])


def test_velocity_and_acceleration_are_the_derivatives_of_position() -> None:
    rng = np.random.default_rng(3)
    seg = PolynomialSegment.quintic(*(rng.uniform(-2, 2, 4) for _ in range(6)), 1.7)
    times, p, v, a = sample_segment(seg, 4, steps=20000)
    dt = times[1] - times[0]
    np.testing.assert_allclose(np.gradient(p, dt, axis=0)[1:-1], v[1:-1], atol=1e-5)
    np.testing.assert_allclose(np.gradient(v, dt, axis=0)[1:-1], a[1:-1], atol=1e-4)


def test_sample_clamps_time_into_the_segment() -> None:
    seg = PolynomialSegment.cubic(np.zeros(1), np.ones(1), np.ones(1), np.zeros(1), 2.0)
    for before, start in ((-1.0, 0.0), (-1e9, 0.0)):
        for got, want in zip(state_at(seg, before, 1), state_at(seg, start, 1), strict=True):
            np.testing.assert_array_equal(got, want)
    for got, want in zip(state_at(seg, 7.0, 1), state_at(seg, 2.0, 1), strict=True):
        np.testing.assert_array_equal(got, want)


def test_sample_writes_into_caller_views() -> None:
    """The cycle passes slices of its own arrays; sample must fill them in place, whatever their strides."""
    seg = PolynomialSegment.linear(np.zeros(3), np.array([3.0, 6.0, 9.0]), 3.0)
    block = np.zeros((3, 6))
    p, v, a = block[0, ::2], block[1, ::2], block[2, ::2]
    seg.sample(1.0, p, v, a)
    np.testing.assert_allclose(block[0], [1.0, 0.0, 2.0, 0.0, 3.0, 0.0])
    np.testing.assert_allclose(block[1], [1.0, 0.0, 2.0, 0.0, 3.0, 0.0])
    assert not block[2].any()


@pytest.mark.parametrize("duration", [0.0, -1.0, np.inf, np.nan])
def test_polynomials_need_a_positive_duration(duration: float) -> None:
    z = np.zeros(2)
    with pytest.raises(ValueError, match="duration"):
        PolynomialSegment.linear(z, z, duration)
    with pytest.raises(ValueError, match="duration"):
        PolynomialSegment.cubic(z, z, z, z, duration)
    with pytest.raises(ValueError, match="duration"):
        PolynomialSegment.quintic(z, z, z, z, z, z, duration)


def test_polynomials_reject_mismatched_or_non_finite_inputs() -> None:
    with pytest.raises(ValueError, match="p1"):
        PolynomialSegment.linear(np.zeros(2), np.zeros(3), 1.0)
    with pytest.raises(ValueError, match="v0"):
        PolynomialSegment.cubic(np.zeros(2), np.array([np.nan, 0.0]), np.zeros(2), np.zeros(2), 1.0)
    with pytest.raises(ValueError, match="coefficients"):
        PolynomialSegment(np.zeros((2, 4)), 1.0)


def test_position_bounds_find_interior_extrema_exactly() -> None:
    # p(τ) = τ(1-τ) on [0, 1] peaks at 1/4 at τ = 1/2; p(τ) = -τ^3 + τ is monotone then falls back.
    seg = PolynomialSegment(np.array([[0.0, 1.0, -1.0, 0, 0, 0], [0.0, 1.0, 0.0, -1.0, 0, 0]]), 1.0)
    lo, hi = seg.position_bounds()
    np.testing.assert_allclose(lo, [0.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(hi, [0.25, 2.0 / (3.0 * np.sqrt(3.0))], rtol=1e-12)


@settings(derandomize=True, max_examples=100, deadline=None)
@given(boundary_problem(), st.sampled_from(["linear", "cubic", "quintic"]))
def test_position_bounds_enclose_dense_samples_tightly(problem, kind: str) -> None:
    (p0, v0, a0, p1, v1, a1), duration = problem
    if kind == "linear":
        seg = PolynomialSegment.linear(p0, p1, duration)
    elif kind == "cubic":
        seg = PolynomialSegment.cubic(p0, v0, p1, v1, duration)
    else:
        seg = PolynomialSegment.quintic(p0, v0, a0, p1, v1, a1, duration)
    times = np.linspace(0.0, duration, 4001)
    p = np.polynomial.polynomial.polyval(times, seg.coefficients.T).T  # (steps, J)
    lo, hi = seg.position_bounds()
    span = np.maximum(hi - lo, 1.0)
    assert np.all(p.min(axis=0) >= lo - 1e-9 * span)
    assert np.all(p.max(axis=0) <= hi + 1e-9 * span)
    # Exact extrema lie within one sampling step's worth of curvature of the dense samples.
    np.testing.assert_allclose(p.min(axis=0), lo, atol=1e-4 * span.max())
    np.testing.assert_allclose(p.max(axis=0), hi, atol=1e-4 * span.max())


def test_hold_segment_holds_at_any_time() -> None:
    hold = HoldSegment([0.5, -0.25])
    assert hold.duration == 0.0
    for t in (-1.0, 0.0, 3.0, 1e6):
        p, v, a = state_at(hold, t, 2)
        assert p.tolist() == [0.5, -0.25]
        assert not v.any() and not a.any()
    lo, hi = hold.position_bounds()
    assert lo.tolist() == hi.tolist() == [0.5, -0.25]


def test_ruckig_segment_wraps_any_trajectory_like_object() -> None:
    calls: list[float] = []

    def at_time(t: float) -> tuple[list[float], list[float], list[float]]:
        calls.append(t)
        return [t, 2 * t], [1.0, 2.0], [0.0, 0.0]

    seg = RuckigSegment(SimpleNamespace(duration=2.0, degrees_of_freedom=2, at_time=at_time))
    p, v, _ = state_at(seg, 1.5, 2)
    assert p.tolist() == [1.5, 3.0] and v.tolist() == [1.0, 2.0]
    state_at(seg, 5.0, 2)
    state_at(seg, -1.0, 2)
    assert calls == [1.5, 2.0, 0.0], "time is clamped into [0, duration] before asking ruckig"


# ---- crossing to the cycle process: a ruckig plan becomes a table of phases ---------------------------------------
def _ruckig_plans() -> list:
    from hild.motion.limits import KinematicLimits
    from hild.motion.planning import plan_move, plan_stop, plan_waypoints

    rng = np.random.default_rng(7)
    limits = KinematicLimits(np.array([1.0, 2.0, 0.5]), np.array([2.0, 4.0, 1.0]), np.array([10.0, 20.0, 5.0]))
    plans = []
    for _ in range(20):
        p, target = rng.uniform(-2, 2, 3), rng.uniform(-2, 2, 3)
        v, a = rng.uniform(-0.4, 0.4, 3), rng.uniform(-0.5, 0.5, 3)
        plans.append(plan_move(p, v, a, target, None, limits))
        plans.append(plan_move(p, v * 3.0, a * 3.0, target, rng.uniform(-0.2, 0.2, 3), limits, 3.0))  # brakes first
        plans.append(plan_stop(p, v, a, limits))
    _, legs = plan_waypoints(rng.uniform(-1, 1, (5, 3)), limits)
    return plans + legs


def test_a_ruckig_segment_crosses_as_a_phase_table_that_samples_and_bounds_like_ruckig() -> None:
    import pickle

    from hild.motion.segments import PhaseSegment

    for segment in _ruckig_plans():
        crossed = pickle.loads(pickle.dumps(segment))
        assert isinstance(crossed, PhaseSegment) and crossed.duration == segment.duration
        want, got = [np.zeros(3) for _ in range(3)], [np.zeros(3) for _ in range(3)]
        times = [*np.linspace(-0.1, segment.duration + 0.1, 157), 0.3, 0.1, segment.duration / 2]  # and backwards
        for t in times:
            segment.sample(float(t), *want)
            crossed.sample(float(t), *got)
            for w, g in zip(want, got, strict=True):
                np.testing.assert_allclose(g, w, rtol=0, atol=1e-9)
        for w, g in zip(segment.position_bounds(), crossed.position_bounds(), strict=True):
            np.testing.assert_allclose(g, w, rtol=0, atol=1e-12)
