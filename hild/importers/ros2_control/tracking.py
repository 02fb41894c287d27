"""The twin's tracking of a full-speed goal, simulated at import time: will the config's own goals abort?

For each trajectory controller of the written config, a short lockstep run on the twin (the engine in-process on
the sim clock, as the tests run it): hold, then a goal out and back — every joint at once, toward the side of its
soft range with more room, far enough to reach its velocity limit (as the controller plans at its own
``velocity_scale``) — and the controller's own tolerances checked the way it checks them: the path tolerance on
every cycle of the move, then the goal tolerance and ``stopped_velocity_tolerance`` until ``goal_time`` after the
end. The controller runs with its tolerances set to 0 (unchecked), so the move runs to its end and every joint's
margin is measured, not only the first violation's. A few seconds of simulated time per controller; the result
reads "succeeds" or, per joint, which tolerance it breaks and by how much.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hild.action import GoalRejected, GoalRequest, GoalStatus
from hild.config import load_config
from hild.controllers.joint_trajectory import Constraints, JointTrajectoryController, JointTrajectoryParams
from hild.cycle.engine import Engine
from hild.importers.ros2_control.report import Report, SourceRef

HOLD_S = 0.2  # s of hold before the goal: the twin settles from its start
TRAVEL_SHARE = 0.4  # of the room toward the freer side of each joint's soft range: never near a limit
SPEED_MARGIN = 1.2  # × the distance a joint needs to reach its velocity limit (v²/a): it cruises a little
CHECK_ID = "import-tracking-check"
REMEDIES = (
    "what helps: stiffer gains (hold/position_gains, or the PID; hild check says how stiff the effort limit allows), "
    "a lower velocity_scale/acceleration_scale for this controller, or looser tolerances (constraints)"
)


@dataclass(frozen=True)
class JointTracking:
    """One joint's margins in the simulated goal (rad, rad/s; a tolerance of 0 is not checked)."""

    name: str
    offset: float  # how far the goal took it out
    path_error: float  # the largest |desired − measured| while the trajectory ran
    path_at: float  # s into the move when it was largest
    path_tolerance: float
    goal_error: float  # |goal − measured| when the controller would decide (success, or goal_time after the end)
    speed: float  # |measured velocity| then
    goal_tolerance: float
    stopped_tolerance: float
    rest_error: float  # |goal − measured| goal_time after the end


@dataclass(frozen=True)
class Tracking:
    controller: str
    duration: float  # s of the planned out-and-back trajectory
    goal_time: float
    settle: float | None  # s after the end at which the controller would report success; None: it would abort
    joints: tuple[JointTracking, ...]
    fault: str = ""  # a joint faulted, or the controller aborted on its own: the run says nothing more

    def violations(self) -> list[str]:
        """Each tolerance a joint breaks, with by how much; empty when the goal succeeds."""
        if self.fault:
            return [self.fault]
        out = []
        for j in self.joints:
            if 0 < j.path_tolerance < j.path_error:
                out.append(
                    f"path tolerance on {j.name}: lags {j.path_error:.3g} rad > {j.path_tolerance:g} (by "
                    f"{j.path_error - j.path_tolerance:.2g}) {j.path_at:.2g} s into the move"
                )
        if out or self.settle is not None:
            return out
        for j in self.joints:
            if 0 < j.goal_tolerance < j.goal_error:
                out.append(
                    f"goal tolerance on {j.name} {self.goal_time:g} s after the end: {j.goal_error:.3g} rad from "
                    f"the goal > {j.goal_tolerance:g} (by {j.goal_error - j.goal_tolerance:.2g})"
                )
            if 0 < j.stopped_tolerance < j.speed:
                out.append(
                    f"stopped_velocity_tolerance on {j.name} {self.goal_time:g} s after the end: still moving at "
                    f"{j.speed:.3g} rad/s > {j.stopped_tolerance:g} (by {j.speed - j.stopped_tolerance:.2g})"
                )
        return out


def simulate_all(config: Path) -> list[Tracking]:
    """Every trajectory controller of ``config``, each on a fresh twin from the start pose."""
    names = [n for n, c in load_config(config).config.controllers.items() if c.type == "joint_trajectory"]
    return [simulate(config, name) for name in names]


def simulate(config: Path, controller: str) -> Tracking:
    """One controller's out-and-back goal at full speed on the lockstep twin of ``config``."""
    loaded = load_config(config)
    params = loaded.controller_params[controller]
    assert isinstance(params, JointTrajectoryParams)
    unchecked = Constraints(goal_time=params.constraints.goal_time, stopped_velocity_tolerance=0.0)
    loaded.controller_params[controller] = params.model_copy(update={"constraints": unchecked})
    loaded.in_lockstep()
    engine = Engine(loaded)
    engine.start()
    try:
        return _run(engine, controller, params)
    finally:
        engine.stop()


def _run(engine: Engine, name: str, params: JointTrajectoryParams) -> Tracking:
    engine.run_cycles(max(1, round(HOLD_S * engine.update_rate)))
    switched = engine.switch([name], [])
    if not switched.ok:
        return Tracking(name, 0.0, 0.0, None, (), f"could not activate it on the twin: {switched.error}")
    jtc = engine.manager.records[name].instance
    assert isinstance(jtc, JointTrajectoryController)
    idx, joints = jtc.index, list(params.joints)
    # Out and back to where the joints hold, inside the soft range (a joint resting a hair beyond a limit, as the
    # plausibility margin allows, returns to the limit).
    start = np.clip(engine.state.position[idx], engine.limits.soft_lower[idx], engine.limits.soft_upper[idx])
    offsets = _offsets(engine, jtc, start)
    points = [{"positions": (start + offsets).tolist()}, {"positions": start.tolist()}]
    try:
        goal = jtc.action.parse({"trajectory": {"joint_names": joints, "points": points}})
    except GoalRejected as exc:
        return Tracking(name, 0.0, params.constraints.goal_time, None, (), f"no goal to check with: {exc}")
    jtc.action.requests.offer(GoalRequest(CHECK_ID, 1, goal))
    constraints = params.constraints
    per_joint = [constraints.joints.get(j) for j in joints]
    path_tol = np.array([c.trajectory if c else 0.0 for c in per_joint])
    goal_tol = np.array([c.goal if c else 0.0 for c in per_joint])
    stopped = constraints.stopped_velocity_tolerance

    # The move: the path error on every cycle the trajectory runs (the controller's own check).
    engine.run_cycles(1)
    track = jtc.goal_track
    if track is None:
        return Tracking(name, 0.0, constraints.goal_time, None, (), _ended(jtc) or "the goal was not adopted")
    duration, t0 = track.trajectory.duration, track.t0
    path, path_at = np.zeros(len(idx)), np.zeros(len(idx))
    deadline = t0 + duration + 2 * engine.period
    while (result := jtc.action.results.poll()) is None and engine.t <= deadline:
        error = np.abs(jtc.pd - engine.state.position[idx])
        worse = error > path
        path[worse], path_at[worse] = error[worse], engine.t - t0
        engine.run_cycles(1)
    if result is None or result.status != GoalStatus.SUCCEEDED:
        why = result.error_string if result is not None else "no result at the trajectory's end"
        return Tracking(name, duration, constraints.goal_time, None, (), f"the goal ended early: {why}")

    # The goal: success once every joint is within its goal tolerance and slow enough, at most goal_time late.
    target = jtc.pd.copy()
    settle, decided = None, None
    while True:
        error = np.abs(target - engine.state.position[idx])
        speed = np.abs(engine.state.velocity[idx])
        late = engine.t - t0 - duration
        if settle is None and decided is None:
            within = ((goal_tol <= 0) | (error <= goal_tol)).all() and (stopped <= 0 or (speed <= stopped).all())
            if within:
                settle, decided = max(0.0, late), (error, speed)
            elif late > constraints.goal_time:
                decided = (error, speed)
        if late > constraints.goal_time:
            break
        engine.run_cycles(1)
    if (faulted := _faulted(engine)) or (faulted := _ended(jtc)):
        return Tracking(name, duration, constraints.goal_time, None, (), faulted)
    assert decided is not None
    return Tracking(
        name,
        duration,
        constraints.goal_time,
        settle,
        tuple(
            JointTracking(
                j,
                float(offsets[k]),
                float(path[k]),
                float(path_at[k]),
                float(path_tol[k]),
                float(decided[0][k]),
                float(decided[1][k]),
                float(goal_tol[k]),
                stopped,
                float(error[k]),
            )
            for k, j in enumerate(joints)
        ),
    )


def _offsets(engine: Engine, jtc: JointTrajectoryController, start: np.ndarray) -> np.ndarray:
    """How far out each joint goes: toward its freer side, far enough to reach its (planning) velocity limit."""
    limits, idx = jtc.limits, jtc.index
    up = engine.limits.soft_upper[idx] - start
    down = start - engine.limits.soft_lower[idx]
    reach = SPEED_MARGIN * limits.velocity**2 / limits.acceleration
    return np.where(up >= down, 1.0, -1.0) * np.minimum(reach, TRAVEL_SHARE * np.maximum(up, down))


def _faulted(engine: Engine) -> str:
    faults = engine.supervisor.fault_text
    bad = [f"{j}: {text}" for j, text in zip(engine.joints, faults, strict=True) if text]
    return f"a joint faulted on the twin ({'; '.join(bad)})" if bad else ""


def _ended(jtc: JointTrajectoryController) -> str:
    result = jtc.action.results.poll()
    return f"the goal ended: {result.status}: {result.error_string}" if result is not None else ""


def report_tracking(config: Path, where: Mapping[str, SourceRef], report: Report, fallback: SourceRef) -> None:
    """Simulate every trajectory controller of ``config`` and say, per controller, whether its goal succeeds."""
    failing = []
    for run in simulate_all(config):
        here = where.get(run.controller, fallback)
        violations = run.violations()
        if not violations:
            report.tracking(here, _passed(run))
            continue
        failing.append(run.controller)
        for text in violations:
            report.tracking(here, f"{run.controller}: a full-speed goal on the twin would abort: {text}")
        if not run.fault:
            report.tracking(here, f"{run.controller}: {REMEDIES}")
    if failing:
        report.notes.append(
            f"tracking check: {', '.join(failing)} would abort a full-speed goal on the twin (see Tracking)"
        )


def _passed(run: Tracking) -> str:
    checked = [j for j in run.joints if j.path_tolerance] or list(run.joints)
    worst = max(checked, key=lambda j: j.path_error / (j.path_tolerance or 1.0))
    path = f"{worst.path_error:.3g} rad on {worst.name}" + (
        f" (tolerance {worst.path_tolerance:g})" if worst.path_tolerance else " (no path tolerance)"
    )
    rest = max(run.joints, key=lambda j: j.rest_error)
    out = ", ".join(f"{j.name} {j.offset:+.2f}" for j in run.joints)
    return (
        f"{run.controller}: a full-speed goal on the twin succeeds: out ({out}) and back in {run.duration:.2f} s; "
        f"largest path error {path}; settled {run.settle:.2f} s after the end (goal_time {run.goal_time:g}); "
        f"{rest.name} rests {rest.rest_error:.2g} rad from the goal {run.goal_time:g} s after the end"
    )
