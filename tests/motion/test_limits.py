"""KinematicLimits: validation, scaling and per-controller subsets."""

from __future__ import annotations

import numpy as np
import pytest

from hild.motion.limits import KinematicLimits


def limits3() -> KinematicLimits:
    return KinematicLimits(np.array([1.0, 2.0, 3.0]), np.array([10.0, 20.0, 30.0]), np.array([100.0, 200.0, 300.0]))


def test_keeps_private_read_only_copies() -> None:
    velocity = np.array([1.0, 2.0])
    limits = KinematicLimits(velocity, np.array([3.0, 4.0]), np.array([5.0, 6.0]))
    velocity[0] = 99.0
    assert limits.velocity.tolist() == [1.0, 2.0]
    assert limits.joints == 2
    with pytest.raises(ValueError):
        limits.acceleration[0] = 1.0


@pytest.mark.parametrize("bad", [0.0, -1.0, np.inf, np.nan])
@pytest.mark.parametrize("field", ["velocity", "acceleration", "jerk"])
def test_rejects_non_positive_or_non_finite(field: str, bad: float) -> None:
    values = {"velocity": np.ones(3), "acceleration": np.ones(3), "jerk": np.ones(3)}
    values[field] = np.array([1.0, bad, 1.0])
    with pytest.raises(ValueError, match=rf"{field} limits .*joints \[1\]"):
        KinematicLimits(**values)


def test_rejects_mismatched_lengths() -> None:
    with pytest.raises(ValueError, match="acceleration"):
        KinematicLimits(np.ones(3), np.ones(2), np.ones(3))
    with pytest.raises(ValueError, match="velocity"):
        KinematicLimits(np.ones((2, 2)), np.ones(2), np.ones(2))


def test_scaled_scales_jerk_with_acceleration() -> None:
    scaled = limits3().scaled(0.5, 0.25)
    np.testing.assert_allclose(scaled.velocity, [0.5, 1.0, 1.5])
    np.testing.assert_allclose(scaled.acceleration, [2.5, 5.0, 7.5])
    np.testing.assert_allclose(scaled.jerk, [25.0, 50.0, 75.0])


@pytest.mark.parametrize("scales", [(0.0, 1.0), (1.0, 0.0), (1.5, 1.0), (1.0, -0.5), (np.nan, 1.0)])
def test_scaled_rejects_factors_outside_unit_interval(scales: tuple[float, float]) -> None:
    with pytest.raises(ValueError, match="scale"):
        limits3().scaled(*scales)


def test_subset_picks_joints_in_order() -> None:
    sub = limits3().subset(np.array([2, 0]))
    assert sub.velocity.tolist() == [3.0, 1.0]
    assert sub.acceleration.tolist() == [30.0, 10.0]
    assert sub.jerk.tolist() == [300.0, 100.0]
