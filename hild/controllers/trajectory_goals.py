"""Goal bodies of the joint_trajectory controller: validate JSON, prepare the plan, build it at adoption.

Everything that can be checked or computed without the current desired state happens here, on the asyncio side,
with a reason for every rejection. What depends on the desired state at the moment the cycle adopts the goal (the
first segment, which always starts from it, and a move's whole profile) is built by ``Plan.trajectory`` — a few
microseconds of ruckig or one quintic, never the bulk of a long trajectory.

Three bodies share the ``goal`` key:
- timed trajectory: every point has ``time_from_start``; interpolation linear / cubic / quintic by the
  derivatives given (like ros2_controllers' JTC);
- untimed trajectory: no point has ``time_from_start``; time-parameterized through every waypoint under the
  velocity, acceleration and jerk limits;
- move_to: ``{"positions", "velocities"?, "duration"?}``; a time-optimal jerk-limited move, all joints arriving
  together, never faster than the limits allow.
"""

from __future__ import annotations

import functools
import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from hild.action import GoalRejected
from hild.controller import and_more, unknown_keys
from hild.motion.limits import KinematicLimits
from hild.motion.planning import plan_move, plan_stop, plan_waypoints
from hild.motion.segments import Segment
from hild.motion.tables import SegmentTable
from hild.motion.trajectory import Trajectory, point_velocities, splice, timed_table

MAX_POINTS = 10_000  # a timed goal this long takes ~0.1 s to prepare (off the event loop, but on the GIL)
MAX_WAYPOINTS = 250  # untimed: each waypoint is a ruckig plan, the costliest part of parsing a goal
AT_REST = 1e-9  # |v|, |a| below this count as zero when deciding whether a final stop segment is needed


@dataclass(frozen=True)
class GoalContext:
    """What validation needs to know about the controller (built once, read-only)."""

    joints: tuple[str, ...]
    soft_lower: np.ndarray
    soft_upper: np.ndarray
    limits: KinematicLimits  # scaled planning limits of the controller's joints
    allow_partial: bool
    path_position: np.ndarray  # default per-joint tolerances; 0 = not checked
    path_velocity: np.ndarray
    goal_position: np.ndarray
    goal_velocity: np.ndarray  # the stopped-velocity tolerance
    goal_time: float
    start_tolerance: float

    @classmethod
    def unchecked(
        cls, joints: tuple[str, ...], bound: float, limits: KinematicLimits, start_tolerance: float = 0.01
    ) -> GoalContext:
        """A context for parsing goals without a controller (tools, tests): soft limits ±``bound``, no path or goal
        tolerance checked, a goal time of 1 s."""
        ones, zeros = np.ones(len(joints)), np.zeros(len(joints))
        return cls(joints, -bound * ones, bound * ones, limits, False, zeros, zeros, zeros, zeros, 1.0, start_tolerance)


@dataclass(frozen=True)
class Tolerances:
    path_position: np.ndarray  # over the goal's joints, 0 = not checked
    path_velocity: np.ndarray
    goal_position: np.ndarray
    goal_velocity: np.ndarray
    goal_time: float  # s after the trajectory's end to get within the goal tolerance


@dataclass(frozen=True)
class TimedPlan:
    """A timed trajectory, prepared: its N-1 segments as one table, so the plan crosses to the cycle process as a
    few arrays and the cycle's adoption adds a splice in front (and maybe a stop behind), whatever N is."""

    times: np.ndarray  # (N,) time_from_start, strictly increasing, ≥ 0
    positions: np.ndarray  # (N, J)
    velocities: np.ndarray  # (N, J) velocities to reach each point with (given, or implied by linear segments)
    accelerations: np.ndarray  # (N, J)
    table: SegmentTable | None  # the segments between consecutive points (N-1), placed at times[0]; None if N = 1
    start_tolerance: float

    def trajectory(self, p: np.ndarray, v: np.ndarray, a: np.ndarray, limits: KinematicLimits) -> Trajectory:
        if self.times[0] > 0.0:
            first = splice(p, v, a, self.positions[0], self.velocities[0], self.accelerations[0], self.times[0])
            rest = self.table
        else:  # point 0 at t = 0 is the start: it must be where the joints already are
            offset = np.abs(self.positions[0] - p)
            if offset.max() > self.start_tolerance:
                raise GoalRejected(
                    f"the first point has time_from_start 0 but is {offset.max():.4g} rad from the current "
                    f"position (start_tolerance {self.start_tolerance:g}); give it a time > 0"
                )
            duration = float(self.times[1])
            first = splice(p, v, a, self.positions[1], self.velocities[1], self.accelerations[1], duration)
            rest = self.table.rows_from(1) if self.table is not None and len(self.table) > 1 else None
        segments: list[Segment | SegmentTable] = [first] if rest is None else [first, rest]
        return _ending_at_rest(segments, len(p), limits, self.velocities[-1], self.accelerations[-1])


@dataclass(frozen=True)
class WaypointPlan:
    waypoints: np.ndarray  # (N, J)
    velocities: np.ndarray  # (N, J) chosen by the planner
    table: SegmentTable | None  # legs between consecutive waypoints (N-1); None for a single waypoint

    def trajectory(self, p: np.ndarray, v: np.ndarray, a: np.ndarray, limits: KinematicLimits) -> Trajectory:
        first = plan_move(p, v, a, self.waypoints[0], self.velocities[0], limits)
        segments: list[Segment | SegmentTable] = [first] if first.duration > 0.0 else []
        if self.table is not None:
            segments.append(self.table)
        return Trajectory(segments, len(p))


@dataclass(frozen=True)
class MovePlan:
    positions: np.ndarray
    velocities: np.ndarray | None
    duration: float | None

    def trajectory(self, p: np.ndarray, v: np.ndarray, a: np.ndarray, limits: KinematicLimits) -> Trajectory:
        move = plan_move(p, v, a, self.positions, self.velocities, limits, self.duration)
        final_v = self.velocities if self.velocities is not None else np.zeros(len(p))
        return _ending_at_rest([move], len(p), limits, final_v, np.zeros(len(p)))


Plan = TimedPlan | WaypointPlan | MovePlan


@dataclass(frozen=True)
class PreparedGoal:
    cols: np.ndarray  # indices into the controller's joints
    plan: Plan
    tolerances: Tolerances
    limits: KinematicLimits  # of the goal's joints

    def trajectory(self, p: np.ndarray, v: np.ndarray, a: np.ndarray) -> Trajectory:
        return self.plan.trajectory(p, v, a, self.limits)

    @functools.cached_property
    def path_check(self) -> tuple[list[int], list[float], list[float]]:
        """``cols``, path position and path velocity tolerances as plain lists, for the per-cycle check."""
        tol = self.tolerances
        return self.cols.tolist(), tol.path_position.tolist(), tol.path_velocity.tolist()


def _ending_at_rest(
    segments: list[Segment | SegmentTable],
    joints: int,
    limits: KinematicLimits,
    final_v: np.ndarray,
    final_a: np.ndarray,
) -> Trajectory:
    """A trajectory whose last point still moves gets a jerk-limited stop, so holding it never steps velocity."""
    trajectory = Trajectory(segments, joints)
    if np.abs(final_v).max(initial=0.0) > AT_REST or np.abs(final_a).max(initial=0.0) > AT_REST:
        p, v, a = np.empty(joints), np.empty(joints), np.empty(joints)
        trajectory.end_state(p, v, a)
        trajectory = Trajectory([*trajectory.segments, plan_stop(p, v, a, limits)], joints)
    return trajectory


# ---- parsing (asyncio side) ------------------------------------------------------------------------------------
GOAL_KEYS = {"trajectory", "path_tolerance", "goal_tolerance", "goal_time_tolerance"}
MOVE_KEYS = {"positions", "velocities", "duration", "joint_names", "path_tolerance", "goal_tolerance",
             "goal_time_tolerance"}  # fmt: skip
POINT_KEYS = {"positions", "velocities", "accelerations", "effort", "time_from_start"}


def parse_goal(payload: Any, ctx: GoalContext) -> PreparedGoal:
    """A goal body → a prepared goal, or GoalRejected with the reason."""
    if not isinstance(payload, dict):
        raise GoalRejected(f"expected a JSON object; found {type(payload).__name__}")
    if "trajectory" in payload:
        _no_unknown(payload, GOAL_KEYS, "goal")
        return _parse_trajectory(payload, ctx)
    if "positions" in payload:
        _no_unknown(payload, MOVE_KEYS, "move_to goal")
        return _parse_move(payload, ctx)
    raise GoalRejected('expected {"trajectory": {...}} or a move_to goal {"positions": [...]}')


def _parse_trajectory(payload: dict[str, Any], ctx: GoalContext) -> PreparedGoal:
    traj = payload["trajectory"]
    if not isinstance(traj, dict):
        raise GoalRejected("trajectory must be an object with joint_names and points")
    _no_unknown(traj, {"joint_names", "points"}, "trajectory")
    names = _names(traj.get("joint_names"), "trajectory.joint_names")
    cols = _columns(names, ctx)
    points = traj.get("points")
    if not isinstance(points, list) or not points:
        raise GoalRejected("trajectory.points must be a non-empty list")
    if len(points) > MAX_POINTS:
        raise GoalRejected(f"trajectory has {len(points)} points; at most {MAX_POINTS} are accepted")
    n = len(names)
    for k, point in enumerate(points):
        if not isinstance(point, dict):
            raise GoalRejected(f"point {k}: expected an object; found {type(point).__name__}")
        _no_unknown(point, POINT_KEYS, f"point {k}")
    positions = _matrix(points, "positions", n, required=True)
    velocities = _matrix(points, "velocities", n, required=False)
    accelerations = _matrix(points, "accelerations", n, required=False)
    assert positions is not None
    limits = ctx.limits.subset(cols)
    _check_positions(positions, cols, names, ctx)
    _check_bound(velocities, limits.velocity, names, "velocity")
    _check_bound(accelerations, limits.acceleration, names, "acceleration")
    tolerances = _tolerances(payload, cols, ctx)
    timed = [("time_from_start" in p) for p in points]
    if any(timed) and not all(timed):
        missing = timed.index(False)
        raise GoalRejected(f"point {missing} has no time_from_start while others do: give all points one or none")
    if not all(timed):
        if len(points) > MAX_WAYPOINTS:
            raise GoalRejected(
                f"an untimed trajectory has at most {MAX_WAYPOINTS} waypoints (found {len(points)}); "
                "give time_from_start for longer ones"
            )
        if accelerations is not None:
            raise GoalRejected("accelerations need time_from_start: untimed goals are parameterized by hild")
        try:
            chosen, legs = plan_waypoints(positions, limits, velocities)
        except ValueError as exc:
            raise GoalRejected(f"cannot time-parameterize the waypoints: {exc}") from None
        table = SegmentTable.of(legs, n) if legs else None
        return PreparedGoal(cols, WaypointPlan(positions, chosen, table), tolerances, limits)
    times = np.array([_time(p["time_from_start"], k) for k, p in enumerate(points)])
    _check_times(times)
    _check_speed(times, positions, limits.velocity, names)
    point_v = point_velocities(times, positions, velocities)
    point_a = accelerations if accelerations is not None else np.zeros_like(positions)
    table = timed_table(times, positions, velocities, accelerations)
    plan = TimedPlan(times, positions, point_v, point_a, table, ctx.start_tolerance)
    return PreparedGoal(cols, plan, tolerances, limits)


def _parse_move(payload: dict[str, Any], ctx: GoalContext) -> PreparedGoal:
    names = _names(payload["joint_names"], "joint_names") if "joint_names" in payload else list(ctx.joints)
    cols = _columns(names, ctx)
    n = len(names)
    positions = _vector(payload["positions"], n, "positions")
    velocities = _vector(payload["velocities"], n, "velocities") if "velocities" in payload else None
    limits = ctx.limits.subset(cols)
    _check_positions(positions[None, :], cols, names, ctx, what="target")
    _check_bound(None if velocities is None else velocities[None, :], limits.velocity, names, "velocity", "target")
    duration = payload.get("duration")
    if duration is not None:
        if not _is_number(duration) or not math.isfinite(duration) or duration <= 0.0:
            raise GoalRejected(f"duration must be a positive number of seconds; found {duration!r}")
        duration = float(duration)
    return PreparedGoal(cols, MovePlan(positions, velocities, duration), _tolerances(payload, cols, ctx), limits)


# ---- checks ------------------------------------------------------------------------------------------------------
def _no_unknown(obj: dict[str, Any], allowed: set[str], what: str) -> None:
    unknown, more = unknown_keys(obj, allowed)
    if unknown:
        raise GoalRejected(f"{what}: unknown keys {unknown}{and_more(more)} (allowed: {sorted(allowed)})")


def _is_number(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool)


def _names(value: Any, what: str) -> list[str]:
    if not isinstance(value, list) or not value or not all(isinstance(n, str) for n in value):
        raise GoalRejected(f"{what} must be a non-empty list of joint names")
    return value


def _columns(names: Sequence[str], ctx: GoalContext) -> np.ndarray:
    lookup = {j: i for i, j in enumerate(ctx.joints)}
    unknown = [n for n in names if n not in lookup]
    if unknown:
        shown = f"{unknown[:8]} and {len(unknown) - 8} more" if len(unknown) > 8 else str(unknown)
        raise GoalRejected(f"unknown joints {shown} (this controller's joints: {list(ctx.joints)})")
    duplicates = sorted(n for n, count in Counter(names).items() if count > 1)  # linear: names can be 250 000 long
    if duplicates:
        raise GoalRejected(f"joints listed more than once: {duplicates}")
    if len(names) < len(ctx.joints) and not ctx.allow_partial:
        missing = [j for j in ctx.joints if j not in names]
        raise GoalRejected(f"goal leaves out joints {missing}; this controller needs all (allow_partial_joints_goal)")
    return np.array([lookup[n] for n in names], dtype=np.intp)


def _vector(value: Any, n: int, what: str) -> np.ndarray:
    if not isinstance(value, list) or len(value) != n:
        found = f"{len(value)} values" if isinstance(value, list) else type(value).__name__
        raise GoalRejected(f"{what}: expected {n} values (one per joint); found {found}")
    if not all(_is_number(x) for x in value):
        raise GoalRejected(f"{what}: values must be numbers")
    arr = np.array(value, dtype=float)
    if not np.isfinite(arr).all():
        raise GoalRejected(f"{what}[{int(np.flatnonzero(~np.isfinite(arr))[0])}] is not finite")
    return arr


def _matrix(points: list[dict[str, Any]], key: str, n: int, required: bool) -> np.ndarray | None:
    given = [key in p for p in points]
    if not any(given) and not required:
        return None
    if not all(given):
        k = given.index(False)
        raise GoalRejected(f"point {k} has no {key}" + ("" if required else " while others do: give all or none"))
    return np.stack([_vector(p[key], n, f"point {k}: {key}") for k, p in enumerate(points)])


def _time(value: Any, k: int) -> float:
    if isinstance(value, dict) and set(value) <= {"sec", "nanosec"} and all(_is_number(v) for v in value.values()):
        value = value.get("sec", 0) + value.get("nanosec", 0) * 1e-9  # ROS Duration
    if not _is_number(value) or not math.isfinite(value):
        raise GoalRejected(f"point {k}: time_from_start must be seconds (a number or {{sec, nanosec}})")
    return float(value)


def _check_times(times: np.ndarray) -> None:
    if times[0] < 0.0:
        raise GoalRejected(f"point 0: time_from_start {times[0]:g} is negative")
    later = np.diff(times) > 0.0
    if not later.all():
        k = int(np.flatnonzero(~later)[0]) + 1
        raise GoalRejected(f"point {k}: time_from_start {times[k]:g} is not after point {k - 1}'s {times[k - 1]:g}")
    if len(times) == 1 and times[0] == 0.0:
        raise GoalRejected("a single point needs time_from_start > 0 to get there")


def _check_positions(
    positions: np.ndarray, cols: np.ndarray, names: Sequence[str], ctx: GoalContext, what: str = "point"
) -> None:
    lo, hi = ctx.soft_lower[cols], ctx.soft_upper[cols]
    outside = (positions < lo) | (positions > hi)
    if outside.any():
        k, j = (int(x) for x in np.argwhere(outside)[0])
        where = f"point {k}" if what == "point" else what
        raise GoalRejected(
            f"{where}: position {positions[k, j]:.6g} of {names[j]} is outside its limits [{lo[j]:.6g}, {hi[j]:.6g}]"
        )


def _check_bound(
    values: np.ndarray | None, bound: np.ndarray, names: Sequence[str], what: str, where: str = "point"
) -> None:
    if values is None:
        return
    over = np.abs(values) > bound * (1.0 + 1e-5)  # bound carries the planning margin
    if over.any():
        k, j = (int(x) for x in np.argwhere(over)[0])
        at = f"point {k}" if where == "point" else where
        raise GoalRejected(f"{at}: {what} {values[k, j]:.6g} of {names[j]} exceeds its limit {bound[j]:.6g}")


def _check_speed(times: np.ndarray, positions: np.ndarray, vmax: np.ndarray, names: Sequence[str]) -> None:
    """Consecutive points closer in time than the velocity limit allows are infeasible whatever the interpolation."""
    if len(times) < 2:
        return
    needed = np.abs(np.diff(positions, axis=0)) / np.diff(times)[:, None]
    over = needed > vmax * (1.0 + 1e-6)
    if over.any():
        k, j = (int(x) for x in np.argwhere(over)[0])
        raise GoalRejected(
            f"points {k}→{k + 1} need {needed[k, j]:.4g} rad/s on {names[j]}, above its limit {vmax[j]:.4g}"
        )


def _tolerances(payload: dict[str, Any], cols: np.ndarray, ctx: GoalContext) -> Tolerances:
    """Defaults from the config, overridden per goal the ROS way: > 0 sets it, 0 keeps the default, -1 disables."""
    path_p, path_v = ctx.path_position[cols].copy(), ctx.path_velocity[cols].copy()
    goal_p, goal_v = ctx.goal_position[cols].copy(), ctx.goal_velocity[cols].copy()
    names = [ctx.joints[c] for c in cols]
    for key, pos, vel in (("path_tolerance", path_p, path_v), ("goal_tolerance", goal_p, goal_v)):
        entries = payload.get(key, [])
        if not isinstance(entries, list):
            raise GoalRejected(f'{key} must be a list of {{"name", "position"?, "velocity"?}}')
        for entry in entries:
            if not isinstance(entry, dict) or not isinstance(entry.get("name"), str):
                raise GoalRejected(f'{key}: each entry needs a "name"')
            _no_unknown(entry, {"name", "position", "velocity", "acceleration"}, f"{key} entry")
            if entry["name"] not in names:
                raise GoalRejected(f"{key}: joint {entry['name']!r} is not part of this goal ({names})")
            j = names.index(entry["name"])
            for field, target in (("position", pos), ("velocity", vel)):
                if field in entry:
                    target[j] = _tolerance_value(entry[field], f"{key} {entry['name']}.{field}", target[j])
    goal_time = payload.get("goal_time_tolerance", 0.0)
    if not _is_number(goal_time) or not math.isfinite(goal_time) or goal_time < 0.0:
        raise GoalRejected(f"goal_time_tolerance must be a number of seconds ≥ 0; found {goal_time!r}")
    return Tolerances(path_p, path_v, goal_p, goal_v, float(goal_time) or ctx.goal_time)


def _tolerance_value(value: Any, what: str, default: float) -> float:
    if not _is_number(value) or not math.isfinite(value) or (value < 0.0 and value != -1):
        raise GoalRejected(f"{what} must be > 0, 0 (default) or -1 (not checked); found {value!r}")
    if value == -1:
        return 0.0
    return float(value) if value > 0.0 else default
