"""Trajectory playback, JTC-style timed segments, point velocities and the splice into a new goal."""

from __future__ import annotations

import numpy as np
import pytest

from hild.motion.segments import HoldSegment, PolynomialSegment
from hild.motion.trajectory import Trajectory, point_velocities, splice, timed_segments
from tests.motion.sampling import state_at

RNG = np.random.default_rng(7)
TIMES = np.array([0.5, 1.0, 1.75, 3.0, 3.2])
POSITIONS = RNG.uniform(-1.0, 1.0, (5, 3))
VELOCITIES = RNG.uniform(-0.5, 0.5, (5, 3))
ACCELERATIONS = RNG.uniform(-2.0, 2.0, (5, 3))


def order(segment: PolynomialSegment) -> int:
    nonzero = np.flatnonzero(np.abs(segment.coefficients).max(axis=0) > 1e-12)
    return int(nonzero[-1])


@pytest.mark.parametrize(
    ("velocities", "accelerations", "degree"),
    [(None, None, 1), (VELOCITIES, None, 3), (VELOCITIES, ACCELERATIONS, 5)],
)
def test_timed_segments_pick_interpolation_from_the_derivatives_given(velocities, accelerations, degree) -> None:
    segments = timed_segments(TIMES, POSITIONS, velocities, accelerations)
    assert len(segments) == len(TIMES) - 1
    for i, seg in enumerate(segments):
        assert isinstance(seg, PolynomialSegment)
        assert order(seg) == degree
        assert seg.duration == pytest.approx(TIMES[i + 1] - TIMES[i])
        for end, k in ((0.0, i), (seg.duration, i + 1)):
            p, v, a = state_at(seg, end, 3)
            np.testing.assert_allclose(p, POSITIONS[k], atol=1e-12)
            if velocities is not None:
                np.testing.assert_allclose(v, velocities[k], atol=1e-11)
            if accelerations is not None:
                np.testing.assert_allclose(a, accelerations[k], atol=1e-9)


@pytest.mark.parametrize("accelerations", [None, ACCELERATIONS])
def test_playback_is_continuous_across_segment_boundaries(accelerations) -> None:
    traj = Trajectory(timed_segments(TIMES, POSITIONS, VELOCITIES, accelerations), 3)
    eps = 1e-9
    for boundary in traj.start_times()[1:]:
        before = state_at(traj, boundary - eps, 3)
        after = state_at(traj, boundary + eps, 3)
        at = state_at(traj, boundary, 3)
        np.testing.assert_allclose(before[0], after[0], atol=1e-8)
        np.testing.assert_allclose(before[1], after[1], atol=1e-6)
        np.testing.assert_allclose(at[0], before[0], atol=1e-8)
        if accelerations is not None:
            np.testing.assert_allclose(before[2], after[2], atol=1e-5)


def test_linear_playback_is_continuous_in_position() -> None:
    traj = Trajectory(timed_segments(TIMES, POSITIONS, None, None), 3)
    for boundary, point in zip(traj.start_times()[1:], POSITIONS[1:-1], strict=True):
        np.testing.assert_allclose(state_at(traj, boundary - 1e-12, 3)[0], point, atol=1e-10)
        np.testing.assert_allclose(state_at(traj, boundary, 3)[0], point, atol=1e-12)


def test_sample_reports_the_segment_and_holds_after_the_end() -> None:
    segments = timed_segments(TIMES - TIMES[0], POSITIONS, VELOCITIES, None)
    traj = Trajectory(segments, 3)
    assert traj.duration == pytest.approx(TIMES[-1] - TIMES[0])
    p, v, a = np.empty(3), np.empty(3), np.empty(3)
    for t in np.linspace(-0.5, traj.duration - 1e-9, 200):
        expected = max(0, int(np.searchsorted(TIMES - TIMES[0], t, side="right")) - 1)
        assert traj.sample(float(t), p, v, a) == expected
        assert not traj.finished(float(t))
    np.testing.assert_allclose(traj.final_position(), POSITIONS[-1], atol=1e-12)
    for t in (traj.duration, traj.duration + 1e-9, traj.duration + 100.0):
        assert traj.sample(t, p, v, a) == len(segments)
        assert traj.finished(t)
        np.testing.assert_allclose(p, POSITIONS[-1], atol=1e-12)
        assert not v.any() and not a.any(), "the final hold has v = a = 0 even if the last point had a velocity"


def test_lookup_skips_zero_length_segments_and_matches_a_linear_search() -> None:
    hold = HoldSegment(np.zeros(1))
    segs = [PolynomialSegment.linear(np.zeros(1), np.zeros(1), d) if d else hold for d in (0.3, 0, 0.2, 0, 0, 0.5)]
    traj = Trajectory(segs, 1)
    starts = traj.start_times()
    np.testing.assert_allclose(starts, [0.0, 0.3, 0.3, 0.5, 0.5, 0.5])
    p, v, a = np.empty(1), np.empty(1), np.empty(1)
    for t in np.linspace(0.0, 0.999, 500):
        used = traj.sample(float(t), p, v, a)
        linear = max(i for i, s in enumerate(starts) if s <= t and (segs[i].duration > 0 or i == len(segs) - 1))
        assert used == linear and segs[used].duration > 0


def test_hold_only_trajectory_is_finished_at_once() -> None:
    traj = Trajectory([HoldSegment([1.0, 2.0])], 2)
    assert traj.duration == 0.0 and traj.finished(0.0)
    p, v, a = np.full(2, np.nan), np.full(2, np.nan), np.full(2, np.nan)
    assert traj.sample(0.0, p, v, a) == 1
    assert p.tolist() == [1.0, 2.0] and not v.any() and not a.any()


def test_position_bounds_cover_all_segments() -> None:
    segs = [
        PolynomialSegment.cubic(np.array([0.0, 0.0]), np.array([2.0, 0.0]), np.array([0.0, 1.0]), np.zeros(2), 1.0),
        PolynomialSegment.linear(np.array([0.0, 1.0]), np.array([-1.0, 3.0]), 1.0),
    ]
    lo, hi = Trajectory(segs, 2).position_bounds()
    # The first segment's joint 0 leaves 0 at 2 rad/s and comes back to rest there: p = 2τ(1 - τ)², whose
    # derivative 2(1 - τ)(1 - 3τ) vanishes at τ = 1/3, where p = 8/27.
    np.testing.assert_allclose(lo, [-1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(hi, [8.0 / 27.0, 3.0], atol=1e-12)


def test_trajectory_rejects_empty_or_mismatched_segments() -> None:
    with pytest.raises(ValueError, match="at least one"):
        Trajectory([], 2)
    with pytest.raises(ValueError, match="segment 1 does not have 2 joints"):
        Trajectory([HoldSegment([0.0, 0.0]), HoldSegment([0.0, 0.0, 0.0])], 2)
    with pytest.raises(ValueError, match="segment 0 does not have 2 joints"):  # would broadcast if only sampled
        Trajectory([HoldSegment([0.0])], 2)

    class Foreign:  # a segment of someone else's making: no `joints`, so sampling has to prove it
        duration = 1.0

        def sample(self, t: float, p: np.ndarray, v: np.ndarray, a: np.ndarray) -> None:
            p[:], v[:], a[:] = [t, t, t], [1.0, 1.0, 1.0], [0.0, 0.0, 0.0]

    with pytest.raises(ValueError, match="segment 0 does not have 2 joints"):
        Trajectory([Foreign(), HoldSegment([0.0, 0.0])], 2)
    assert Trajectory([Foreign(), HoldSegment([0.0, 0.0, 0.0])], 3).duration == 1.0


def test_timed_segments_validate_their_input() -> None:
    with pytest.raises(ValueError, match="strictly increasing; point 2"):
        timed_segments(np.array([0.0, 1.0, 1.0]), np.zeros((3, 2)), None, None)
    with pytest.raises(ValueError, match="positions"):
        timed_segments(np.array([0.0, 1.0]), np.zeros((3, 2)), None, None)
    with pytest.raises(ValueError, match="velocities"):
        timed_segments(np.array([0.0, 1.0]), np.zeros((2, 2)), np.zeros((2, 3)), None)
    with pytest.raises(ValueError, match="accelerations need velocities"):
        timed_segments(np.array([0.0, 1.0]), np.zeros((2, 2)), None, np.zeros((2, 2)))
    with pytest.raises(ValueError, match="finite"):
        timed_segments(np.array([0.0, np.nan]), np.zeros((2, 2)), None, None)
    assert timed_segments(np.array([1.0]), np.zeros((1, 2)), None, None) == []


def test_point_velocities_are_given_ones_or_the_following_slope() -> None:
    np.testing.assert_array_equal(point_velocities(TIMES, POSITIONS, VELOCITIES), VELOCITIES)
    slopes = point_velocities(TIMES, POSITIONS, None)
    np.testing.assert_allclose(slopes[:-1], np.diff(POSITIONS, axis=0) / np.diff(TIMES)[:, None])
    assert not slopes[-1].any()
    assert not point_velocities(np.array([2.0]), np.ones((1, 3)), None).any()


def test_splice_from_a_moving_state_reaches_the_point_smoothly() -> None:
    p, v, a = np.array([0.1, -0.2, 0.3]), np.array([0.5, 0.0, -1.0]), np.array([2.0, -1.0, 0.0])
    velocities = point_velocities(TIMES, POSITIONS, None)
    seg = splice(p, v, a, POSITIONS[0], velocities[0], np.zeros(3), TIMES[0])
    for got, want in zip(state_at(seg, 0.0, 3), (p, v, a), strict=True):
        np.testing.assert_allclose(got, want, atol=1e-12)
    for got, want in zip(state_at(seg, TIMES[0], 3), (POSITIONS[0], velocities[0], np.zeros(3)), strict=True):
        np.testing.assert_allclose(got, want, atol=1e-9)
    # Played in front of the timed segments, the whole goal is continuous in p and v from its first cycle.
    traj = Trajectory([seg, *timed_segments(TIMES, POSITIONS, None, None)], 3)
    start = state_at(traj, 0.0, 3)
    np.testing.assert_allclose(start[0], p, atol=1e-12)
    np.testing.assert_allclose(start[1], v, atol=1e-12)
    before, after = state_at(traj, TIMES[0] - 1e-9, 3), state_at(traj, TIMES[0] + 1e-9, 3)
    np.testing.assert_allclose(before[0], after[0], atol=1e-8)
    np.testing.assert_allclose(before[1], after[1], atol=1e-6)
    with pytest.raises(ValueError, match="duration"):
        splice(p, v, a, POSITIONS[0], velocities[0], np.zeros(3), 0.0)
