"""Prepared goals crossing to the cycle process: through the shared-memory goal queue as segment tables, adopted
into trajectories that sample exactly as the per-segment goals did, in the same few objects whatever their length."""

from __future__ import annotations

import pickle
from typing import Any

import numpy as np
import pytest

from hild.action import GOAL_BYTES, PENDING_GOALS, GoalRequest
from hild.controllers.trajectory_goals import MAX_POINTS, GoalContext, PreparedGoal, TimedPlan, parse_goal
from hild.crossing.mailboxes import Shared
from hild.crossing.region import Region
from hild.motion.limits import KinematicLimits
from hild.motion.planning import plan_stop, plan_waypoints
from hild.motion.segments import PolynomialSegment
from hild.motion.tables import SegmentTable
from hild.motion.trajectory import Trajectory, splice, timed_segments
from tests.motion.test_tables import assert_same_samples, opcodes, probe_times, reachable

J = 6
NAMES = [f"j{k}" for k in range(J)]


def context() -> GoalContext:
    ones = np.ones(J)
    return GoalContext.unchecked(tuple(NAMES), 3.0, KinematicLimits(2.0 * ones, 5.0 * ones, 50.0 * ones))


def timed_goal(n: int, first_time: float, seed: int = 2) -> dict[str, Any]:
    """``n`` points 1 to 20 ms apart with velocities; the last still moving, so adoption appends a stop."""
    rng = np.random.default_rng(seed)
    steps = rng.uniform(0.001, 0.02, n - 1)
    times = first_time + np.concatenate([[0.0], np.cumsum(steps)])
    positions = np.cumsum(np.vstack([np.zeros(J), rng.uniform(-1.0, 1.0, (n - 1, J)) * steps[:, None]]), axis=0)
    velocities = rng.uniform(-0.3, 0.3, (n, J))
    points = [
        {"positions": p, "velocities": v, "time_from_start": t}
        for p, v, t in zip(positions.tolist(), velocities.tolist(), times.tolist(), strict=True)
    ]
    return {"trajectory": {"joint_names": NAMES, "points": points}}


def crossed(goal: PreparedGoal) -> PreparedGoal:
    """Through the goal queue as the API half hands it to the cycle process."""
    queue = Shared(Region(4 * GOAL_BYTES), create=True).queue("goals", PENDING_GOALS, GOAL_BYTES)
    assert queue.offer(GoalRequest("g", 1, goal))
    request = queue.poll()
    assert isinstance(request, GoalRequest)
    return request.goal


def per_segment(plan: TimedPlan, p: np.ndarray, v: np.ndarray, a: np.ndarray, limits: KinematicLimits) -> Trajectory:
    """The trajectory as adopted before tables: one PolynomialSegment per pair of points."""
    segments: list[Any] = timed_segments(plan.times, plan.positions, plan.velocities, None)
    if plan.times[0] > 0.0:
        segments.insert(0, splice(p, v, a, plan.positions[0], plan.velocities[0], plan.accelerations[0], plan.times[0]))
    else:
        duration = float(plan.times[1])
        segments[0] = splice(p, v, a, plan.positions[1], plan.velocities[1], plan.accelerations[1], duration)
    end = [np.empty(J) for _ in range(3)]
    segments[-1].sample(segments[-1].duration, *end)
    return Trajectory([*segments, plan_stop(*end, limits)], J)


@pytest.mark.parametrize("first_time", [0.5, 0.0])
def test_a_timed_goal_of_10000_points_crosses_and_plays_exactly_as_its_segments(first_time: float) -> None:
    goal = parse_goal(timed_goal(MAX_POINTS, first_time), context())
    assert isinstance(goal.plan, TimedPlan) and isinstance(goal.plan.table, SegmentTable)
    assert len(pickle.dumps(GoalRequest("g", 1, goal), pickle.HIGHEST_PROTOCOL)) < GOAL_BYTES // 2
    came = crossed(goal)
    assert isinstance(came.plan, TimedPlan)
    p, v, a = np.full(J, 0.005), np.full(J, -0.05), np.full(J, 0.2)  # the desired state at adoption: moving
    got = came.trajectory(p, v, a)
    want = per_segment(came.plan, p, v, a, came.limits)
    assert [type(s).__name__ for s in got.segments] == ["PolynomialSegment", "SegmentTable", "RuckigSegment"]
    assert got.duration == want.duration
    assert_same_samples(want, got, probe_times(want.start_times(), want.duration))


def test_a_waypoint_goal_crosses_and_plays_exactly_as_its_crossed_legs() -> None:
    rng = np.random.default_rng(4)
    waypoints = rng.uniform(-1.0, 1.0, (12, J))
    waypoints[5] = waypoints[4]  # a zero-length leg: a hold
    body = {"trajectory": {"joint_names": NAMES, "points": [{"positions": w} for w in waypoints.tolist()]}}
    ctx = context()
    came = crossed(parse_goal(body, ctx))
    p, v, a = np.zeros(J), np.zeros(J), np.zeros(J)
    got = came.trajectory(p, v, a)
    _, legs = plan_waypoints(waypoints, ctx.limits)  # deterministic: the legs the plan was made of
    first = got.segments[0]
    want = Trajectory([first, *pickle.loads(pickle.dumps(legs))], J)  # legs crossed one by one, as before tables
    assert isinstance(got.segments[1], SegmentTable) and got.duration == want.duration
    assert_same_samples(want, got, probe_times(want.start_times(), want.duration))


def test_a_crossed_goal_is_the_same_few_objects_whatever_its_length() -> None:
    goals = {n: GoalRequest("g", 1, parse_goal(timed_goal(n, 0.5), context())) for n in (10, MAX_POINTS)}
    assert opcodes(goals[10]) == opcodes(goals[MAX_POINTS])
    arrived = {n: crossed(request.goal) for n, request in goals.items()}
    assert len(reachable(arrived[10])) == len(reachable(arrived[MAX_POINTS]))
    assert not any(isinstance(x, PolynomialSegment) for x in reachable(arrived[MAX_POINTS]))
    p, v, a = np.zeros(J), np.zeros(J), np.zeros(J)
    adopted = {n: goal.trajectory(p, v, a) for n, goal in arrived.items()}
    assert len(reachable(adopted[10])) == len(reachable(adopted[MAX_POINTS])), "adoption adds a splice and a stop"
