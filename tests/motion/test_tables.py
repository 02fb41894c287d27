"""Segment tables: many segments as a few arrays, sampled to the bit as the segment objects they stand for, and
pickled as the same few objects whatever their length."""

from __future__ import annotations

import pickle
import pickletools
from typing import Any

import numpy as np
import pytest

from hild.motion.limits import KinematicLimits
from hild.motion.planning import plan_move, plan_waypoints
from hild.motion.segments import HoldSegment, PolynomialSegment, RuckigSegment, Segment
from hild.motion.tables import SegmentTable
from hild.motion.trajectory import Trajectory, timed_segments, timed_table

J = 3


def points(n: int, seed: int = 5) -> tuple[np.ndarray, ...]:
    """``n`` timed points: uneven spacing from 1 to 20 ms, starting 0.25 s in, with velocities and accelerations."""
    rng = np.random.default_rng(seed)
    times = 0.25 + np.cumsum(rng.uniform(0.001, 0.02, n)) - 0.001
    positions = np.cumsum(rng.uniform(-0.01, 0.01, (n, J)), axis=0)
    return times, positions, rng.uniform(-0.5, 0.5, (n, J)), rng.uniform(-2.0, 2.0, (n, J))


def probe_times(starts: np.ndarray, end: float, seed: int = 11) -> list[float]:
    """Before the start, at and just around every boundary, the end and after it, then random jumps both ways."""
    rng = np.random.default_rng(seed)
    edges = np.concatenate([starts, [end]])
    ordered = np.sort(np.concatenate([[-1.0, 0.0], edges, edges - 1e-12, edges + 1e-12, [end + 1.0]]))
    return [*ordered.tolist(), *rng.uniform(-0.5, end + 0.5, 5000).tolist()]


def assert_same_samples(want: Trajectory, got: Trajectory, times: list[float]) -> None:
    """Bit for bit: the table runs the segment objects' arithmetic on the same numbers."""
    w, g = [np.empty(want.joints) for _ in range(3)], [np.empty(got.joints) for _ in range(3)]
    for t in times:
        want.sample(t, *w)
        got.sample(t, *g)
        for name, x, y in zip("pva", w, g, strict=True):
            if not np.array_equal(x, y):
                raise AssertionError(f"{name} at t = {t!r}: {y.tolist()} != segments' {x.tolist()}")


def splice_to(position: np.ndarray, duration: float) -> PolynomialSegment:
    return PolynomialSegment.quintic(
        np.zeros(J), np.zeros(J), np.zeros(J), position, np.zeros(J), np.zeros(J), duration
    )


@pytest.mark.parametrize("given", ["positions", "velocities", "accelerations"])
def test_a_crossed_table_of_10000_points_samples_exactly_as_its_segment_objects(given: str) -> None:
    times, positions, velocities, accelerations = points(10_000)
    vel = velocities if given != "positions" else None
    acc = accelerations if given == "accelerations" else None
    segments = timed_segments(times, positions, vel, acc)
    table = timed_table(times, positions, vel, acc)
    assert table is not None and len(table) == len(segments) == 9_999
    np.testing.assert_array_equal(table.coefficients, [s.coefficients for s in segments])
    crossed = pickle.loads(pickle.dumps(table, pickle.HIGHEST_PROTOCOL))
    head = splice_to(positions[0], float(times[0]))  # as a goal plays it: a splice to the first point, then the rows
    want, got = Trajectory([head, *segments], J), Trajectory([head, crossed], J)
    assert got.segments[1] is crossed, "placed at times[0], it is played where it is, not copied"
    assert got.duration == want.duration
    assert_same_samples(want, got, probe_times(want.start_times(), want.duration))
    for w, g in zip(want.position_bounds(), got.position_bounds(), strict=True):
        np.testing.assert_allclose(g, w, rtol=0.0, atol=1e-12)


def test_rows_from_is_a_view_that_samples_as_the_later_segments() -> None:
    times, positions, velocities, _ = points(50)
    segments = timed_segments(times, positions, velocities, None)
    table = timed_table(times, positions, velocities, None)
    assert table is not None
    tail = table.rows_from(1)
    assert len(tail) == len(table) - 1 and tail.start == table.starts[1]
    assert np.shares_memory(tail.coefficients, table.coefficients) and np.shares_memory(tail.starts, table.starts)
    head = splice_to(positions[1], float(table.starts[1]))
    want, got = Trajectory([head, *segments[1:]], J), Trajectory([head, tail], J)
    assert got.segments[1] is tail
    assert_same_samples(want, got, probe_times(want.start_times(), want.duration))
    with pytest.raises(ValueError, match="rows_from"):
        table.rows_from(len(table))


def waypoint_legs() -> list[Segment]:
    """A chain through repeated waypoints too: ruckig legs and holds, as they cross on their own."""
    limits = KinematicLimits(np.array([1.0, 2.0, 0.5]), np.array([2.0, 4.0, 1.0]), np.array([10.0, 20.0, 5.0]))
    waypoints = np.random.default_rng(3).uniform(-1.0, 1.0, (8, J))
    waypoints[4] = waypoints[3]
    _, legs = plan_waypoints(waypoints, limits)
    assert any(isinstance(leg, HoldSegment) for leg in legs)
    return legs


@pytest.mark.parametrize("mixed", [True, False], ids=["legs-holds-quintic", "ruckig-legs-only"])
def test_a_waypoint_chain_placed_anew_samples_as_its_crossed_legs(mixed: bool) -> None:
    legs = waypoint_legs()
    if mixed:
        legs.append(
            PolynomialSegment.quintic(np.zeros(J), np.ones(J), np.zeros(J), np.ones(J), np.zeros(J), np.zeros(J), 2)
        )
    else:
        legs = [leg for leg in legs if isinstance(leg, RuckigSegment)]
    crossed_legs = pickle.loads(pickle.dumps(legs))  # what the cycle sampled before tables: PhaseSegments
    table = pickle.loads(pickle.dumps(SegmentTable.of(legs, J)))
    limits = KinematicLimits(np.ones(J), np.ones(J), np.ones(J))
    first = plan_move(np.zeros(J), np.zeros(J), np.zeros(J), np.full(J, 0.3), None, limits)  # ruckig, not crossed
    want, got = Trajectory([first, *crossed_legs], J), Trajectory([first, table], J)
    assert got.segments[1] is not table and got.segments[1].start == first.duration, "re-placed after the move"
    assert got.duration == want.duration
    assert_same_samples(want, got, probe_times(want.start_times(), want.duration))
    for w, g in zip(want.position_bounds(), got.position_bounds(), strict=True):
        np.testing.assert_allclose(g, w, rtol=0.0, atol=1e-12)


def test_the_cursor_finds_what_a_binary_search_finds_over_zero_length_rows_and_jumps() -> None:
    durations = np.array([0.3, 0.0, 0.2, 0.0, 0.0, 0.5, 0.1, 0.0])
    coefficients = np.zeros((len(durations), 1, 6))
    coefficients[:, 0, 0] = np.arange(len(durations))  # each row holds its own index as its position
    table = SegmentTable.polynomials(coefficients, durations)
    p, v, a = np.empty(1), np.empty(1), np.empty(1)
    rng = np.random.default_rng(1)
    forward = np.linspace(-0.1, 1.2, 400)
    for t in [*forward, *rng.uniform(-0.1, 1.2, 400), *forward[::-1], 0.3, 0.5, 1.0, 1.1]:
        table.sample(float(t), p, v, a)
        want = len(durations) - 1 if t >= table.end else max(int(np.searchsorted(table.starts, t, "right")) - 1, 0)
        assert p[0] == want, f"t = {t}"


def test_tables_check_what_they_are_built_from() -> None:
    with pytest.raises(ValueError, match="durations"):
        SegmentTable.polynomials(np.zeros((2, 1, 6)), np.array([1.0, -1.0]))
    with pytest.raises(ValueError, match="expected coefficients"):
        SegmentTable.polynomials(np.zeros((0, 1, 6)), np.zeros(0))
    with pytest.raises(ValueError, match="segment 1 has 2 joints"):
        SegmentTable.of([HoldSegment([0.0]), HoldSegment([0.0, 0.0])], 1)
    with pytest.raises(TypeError, match="hild's own segments"):
        SegmentTable.of([object()], 1)  # type: ignore[list-item]
    assert timed_table(np.array([1.0]), np.zeros((1, 2)), None, None) is None
    with pytest.raises(ValueError, match="strictly increasing"):
        timed_table(np.array([0.0, 1.0, 1.0]), np.zeros((3, 2)), None, None)
    with pytest.raises(ValueError, match="accelerations need velocities"):
        timed_table(np.array([0.0, 1.0]), np.zeros((2, 2)), None, np.zeros((2, 2)))


# ---- the pickled form --------------------------------------------------------------------------------------------
def opcodes(obj: Any) -> int:
    """Pickle opcodes of ``obj`` but FRAME (protocol 4+ frames the stream in pieces of about 64 KiB: no object)."""
    ops = pickletools.genops(pickle.dumps(obj, pickle.HIGHEST_PROTOCOL))
    return sum(1 for op, _, _ in ops if op.name != "FRAME")


def reachable(obj: Any) -> list[Any]:
    """Every object reachable through attributes and containers, but numbers and strings (arrays are leaves)."""
    seen: dict[int, Any] = {}
    stack = [obj]
    while stack:
        item = stack.pop()
        if id(item) in seen or isinstance(item, int | float | str):
            continue
        seen[id(item)] = item
        if isinstance(item, dict):
            stack += [*item.keys(), *item.values()]
        elif isinstance(item, list | tuple):
            stack += item
        elif hasattr(item, "__dict__"):
            stack.append(vars(item))
    return list(seen.values())


def test_a_pickled_table_is_the_same_few_objects_whatever_its_length() -> None:
    tables = {}
    for n in (10, 10_000):
        times, positions, velocities, accelerations = points(n)
        tables[n] = timed_table(times, positions, velocities, accelerations)
    assert opcodes(tables[10]) == opcodes(tables[10_000])
    crossed = {n: pickle.loads(pickle.dumps(table, pickle.HIGHEST_PROTOCOL)) for n, table in tables.items()}
    assert len(reachable(crossed[10])) == len(reachable(crossed[10_000]))
    arrays = [x for x in reachable(crossed[10_000]) if isinstance(x, np.ndarray)]
    assert sum(x.size for x in arrays) > 9_999 * J * 6, "the rows live in arrays"
    assert not any(isinstance(x, PolynomialSegment) for x in reachable(crossed[10_000]))
    p, v, a = np.empty(J), np.empty(J), np.empty(J)
    for t in np.linspace(0.0, crossed[10_000].end + 1.0, 1000):
        crossed[10_000].sample(float(t), p, v, a)
    assert len(reachable(crossed[10_000])) == len(reachable(crossed[10])), "playing it creates no per-row objects"
