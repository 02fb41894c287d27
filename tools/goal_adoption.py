#!/usr/bin/env python3
"""What a timed goal costs to cross to the cycle process: pickle (API half), unpickle and adopt (cycle half).

    python tools/goal_adoption.py              # 100 / 1 000 / 10 000 points, median of 7 runs
    python tools/goal_adoption.py --runs 15 --points 10000

For each size a timed goal (six joints, velocities given: cubic segments, 1–20 ms apart) is prepared once by
``parse_goal``, then crossed both ways: *segments*, the plan as it crossed before segment tables (one
``PolynomialSegment`` object per pair of points), and *table*, as it crosses now. Columns: the pickle's size;
``pickle`` (the API half's ``offer``); ``unpickle`` (the cycle half's ``poll``); ``adopt`` (the cycle builds the
trajectory from its desired state and takes the first sample); ``sample`` (a later cycle's sample, µs, averaged
over 2 000 cycles at 1 kHz). Wall clock on this machine, garbage collector on as in the cycle process.
"""

from __future__ import annotations

import argparse
import dataclasses
import gc
import pickle
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from hild.action import GoalRequest
from hild.controllers.trajectory_goals import GoalContext, PreparedGoal, TimedPlan, parse_goal
from hild.crossing.stats import percentiles
from hild.motion.limits import KinematicLimits
from hild.motion.planning import plan_stop
from hild.motion.segments import Segment
from hild.motion.trajectory import Trajectory, splice, timed_segments

J = 6
NAMES = [f"j{k}" for k in range(J)]
PROTOCOL = pickle.HIGHEST_PROTOCOL  # as hild.crossing.mailboxes


@dataclasses.dataclass(frozen=True)
class PerSegmentPlan:
    """A timed plan as it crossed before segment tables: its segments as a list of objects."""

    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    accelerations: np.ndarray
    segments: list[Segment]

    def trajectory(self, p: np.ndarray, v: np.ndarray, a: np.ndarray, limits: KinematicLimits) -> Trajectory:
        segments = [splice(p, v, a, self.positions[0], self.velocities[0], self.accelerations[0], self.times[0])]
        segments += self.segments
        if np.abs(self.velocities[-1]).max() > 1e-9:
            end = [np.empty(J) for _ in range(3)]
            segments[-1].sample(segments[-1].duration, *end)
            segments.append(plan_stop(*end, limits))
        return Trajectory(segments, J)


def goal(n: int) -> PreparedGoal:
    rng = np.random.default_rng(n)
    steps = rng.uniform(0.001, 0.02, n - 1)
    times = 0.5 + np.concatenate([[0.0], np.cumsum(steps)])
    positions = np.cumsum(np.vstack([np.zeros(J), rng.uniform(-1.0, 1.0, (n - 1, J)) * steps[:, None]]), axis=0)
    velocities = rng.uniform(-0.3, 0.3, (n, J))
    points = [
        {"positions": p, "velocities": v, "time_from_start": t}
        for p, v, t in zip(positions.tolist(), velocities.tolist(), times.tolist(), strict=True)
    ]
    ones = np.ones(J)
    ctx = GoalContext.unchecked(tuple(NAMES), 3.0, KinematicLimits(2.0 * ones, 5.0 * ones, 50.0 * ones))
    return parse_goal({"trajectory": {"joint_names": NAMES, "points": points}}, ctx)


def per_segment(prepared: PreparedGoal) -> PreparedGoal:
    plan = prepared.plan
    assert isinstance(plan, TimedPlan)
    segments = timed_segments(plan.times, plan.positions, plan.velocities, None)
    old = PerSegmentPlan(plan.times, plan.positions, plan.velocities, plan.accelerations, segments)
    return dataclasses.replace(prepared, plan=old)  # type: ignore[arg-type]


def timed(fn: Callable[[], Any]) -> tuple[float, Any]:
    start = time.perf_counter()
    value = fn()
    return time.perf_counter() - start, value


def measure(prepared: PreparedGoal, runs: int) -> dict[str, float]:
    request = GoalRequest("goal", 1, prepared)
    rows: dict[str, list[float]] = {"pickle": [], "unpickle": [], "adopt": [], "sample": []}
    p, v, a = np.zeros(J), np.zeros(J), np.zeros(J)
    for _ in range(runs):
        gc.collect()
        seconds, raw = timed(lambda: pickle.dumps(request, PROTOCOL))
        rows["pickle"].append(seconds)
        seconds, crossed = timed(lambda raw=raw: pickle.loads(raw))
        rows["unpickle"].append(seconds)

        def adopt(goal: PreparedGoal = crossed.goal) -> Trajectory:
            trajectory = goal.trajectory(p, v, a)
            trajectory.sample(0.0, p, v, a)
            return trajectory

        seconds, trajectory = timed(adopt)
        rows["adopt"].append(seconds)
        cycles = 2000
        start = time.perf_counter()
        for k in range(1, cycles + 1):
            trajectory.sample(k * 1e-3, p, v, a)
        rows["sample"].append((time.perf_counter() - start) / cycles)
        del crossed, trajectory
    result = {key: percentiles(values, "s", to="s", digits=9)["p50"] for key, values in rows.items()}
    result["kib"] = len(pickle.dumps(request, PROTOCOL)) / 1024
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--points", type=int, nargs="+", default=[100, 1_000, 10_000])
    parser.add_argument("--runs", type=int, default=7)
    args = parser.parse_args()
    print(
        f"{'points':>7} {'form':<9} {'KiB':>7} {'pickle ms':>10} {'unpickle ms':>12} {'adopt ms':>9} {'sample µs':>10}"
    )
    for n in args.points:
        prepared = goal(n)
        for form, crossing in (("segments", per_segment(prepared)), ("table", prepared)):
            r = measure(crossing, args.runs)
            print(
                f"{n:>7} {form:<9} {r['kib']:>7.0f} {r['pickle'] * 1e3:>10.2f} {r['unpickle'] * 1e3:>12.2f} "
                f"{r['adopt'] * 1e3:>9.3f} {r['sample'] * 1e6:>10.2f}"
            )
    print(f"median of {args.runs} runs; adopt = build the trajectory from the desired state + its first sample")


if __name__ == "__main__":
    main()
