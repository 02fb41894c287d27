"""joint_trajectory: executes timed and untimed trajectories and move_to goals, jump-free.

At parity with ros2_controllers' JointTrajectoryController where it makes sense, and stricter where its users
get hurt: every new goal starts from the current *desired* state (no jump on activation or preemption), a
cancel or an abort decelerates jerk-limited to a stop instead of freezing the command (after a path-tolerance abort
from the *measured* state: the arm is not where its path is, and a setpoint held beyond an obstacle would press on
it), and a trajectory that ends while still moving gets a stop appended.

Joints are driven by *tracks*: a trajectory, its start time and the joints it still owns. A full goal replaces
every track; a partial goal (``allow_partial_joints_goal``) takes its joints and leaves the others to their
current motion (``continue``) or brings them to a stop (``stop``). Joints without a track hold their desired
position. It runs the cycle half of its goals (:class:`~hild.action.ActionServer`); the client half, in the client
domain, does the bookkeeping (:class:`hild.api.goals.GoalEndpoint`). This module only executes.

A goal whose sender disappears (its Zenoh liveliness token goes away) is stopped by default: decelerated
jerk-limited to rest and aborted (``on_client_lost: stop``). A robot should not keep executing for someone who is
no longer there to watch it, cancel it or read its result; ``continue`` is for fire-and-forget senders.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from hild.action import ActionServer, CancelRequest, ClientLost, ErrorCode, GoalRejected, GoalRequest, GoalStatus
from hild.arrays import JointState, ServoCommand
from hild.config.params import Field, Params, dynamic, model_validator
from hild.controller import Controller, ControllerContext
from hild.controllers.motion_common import PlansMotion, first_taken_over
from hild.controllers.trajectory_goals import GoalContext, PreparedGoal, parse_goal
from hild.modes import Source
from hild.motion.limits import KinematicLimits
from hild.motion.planning import PlanningError, plan_stop
from hild.motion.trajectory import Trajectory

INTERFACE_SETS = (("position",), ("position", "velocity"), ("effort",))
GAIN_RAMP = 0.5  # s over which changed PID gains replace the old ones on an active controller
GAIN_FIELDS = ("p", "i", "d", "i_clamp", "ff_velocity_scale")
PLAN_MARGIN = 1.0 - 1e-6  # ruckig plans exactly at the limits; stay a hair inside so the supervisor never clamps


class JointConstraint(Params):
    trajectory: float = Field(default=0.0, ge=0.0, description="Path position tolerance (rad); 0 = not checked.")
    goal: float = Field(default=0.0, ge=0.0, description="Goal position tolerance (rad); 0 = not checked.")
    trajectory_velocity: float = Field(default=0.0, ge=0.0, description="Path velocity tolerance; 0 = not checked.")


class Constraints(Params):
    goal_time: float = Field(
        default=1.0, gt=0.0, description="s after the trajectory's end to get within the goal tolerance."
    )
    stopped_velocity_tolerance: float = Field(
        default=0.01, ge=0.0, description="rad/s; at the goal every joint must move slower than this (0 = unchecked)."
    )
    joints: dict[str, JointConstraint] = Field(default_factory=dict)


class PidGains(Params):
    p: float = Field(ge=0.0)
    i: float = Field(default=0.0, ge=0.0)
    d: float = Field(default=0.0, ge=0.0)
    i_clamp: float = Field(default=0.0, ge=0.0, description="Bound of the integral term (N·m).")
    ff_velocity_scale: float = Field(default=0.0, description="Desired velocity × this is added to the effort.")


class JointTrajectoryParams(Params):
    joints: list[str] = Field(min_length=1)
    command_interfaces: list[Literal["position", "velocity", "effort"]] = Field(
        default_factory=lambda: ["position", "velocity"],
        description="[position], [position, velocity] (velocity as feed-forward) or [effort] (PID).",
    )
    allow_partial_joints_goal: bool = dynamic(False)
    partial_goal_other_joints: Literal["continue", "stop"] = dynamic(
        default="continue", description="Joints a partial goal leaves out keep their current motion, or stop."
    )
    constraints: Constraints = dynamic(
        default_factory=Constraints, description="Goals accepted after a change are checked against the new ones."
    )
    gains: dict[str, PidGains] = dynamic(
        default_factory=dict,
        description="Per joint, for the effort interface. Changed while active, new gains are ramped in over "
        "0.5 s: the effort command never steps.",
    )
    gravity_compensation: bool = Field(
        default=False,
        description="Effort interface only: the supervisor adds the robot model's gravity torque (robot.model) to "
        "the PID's effort, as a real arm's own driver does under an effort controller. Off, the PID alone holds the "
        "arm up and a P-only PID stops short by gravity / p (docs/safety.md).",
    )
    feedback_rate: float = dynamic(default=25.0, gt=0.0, description="Hz of the feedback topic while a goal runs.")
    velocity_scale: float = dynamic(
        default=1.0, gt=0.0, le=1.0, description="Of the joints' limits, for planning (goals planned after a change)."
    )
    acceleration_scale: float = dynamic(default=1.0, gt=0.0, le=1.0, description="Jerk scales with it.")
    start_tolerance: float = dynamic(
        default=0.01, gt=0.0, description="A first point at time 0 must be this close to the current position."
    )
    on_client_lost: Literal["continue", "stop"] = dynamic(
        default="stop",
        description="A goal whose sender disappeared (Zenoh liveliness): decelerate to a stop and abort it, "
        "or run it to its end.",
    )

    @model_validator(mode="after")
    def _consistent(self) -> JointTrajectoryParams:
        if tuple(self.command_interfaces) not in INTERFACE_SETS:
            raise ValueError(f"command_interfaces must be one of {[list(s) for s in INTERFACE_SETS]}")
        if len(set(self.joints)) != len(self.joints):
            raise ValueError(f"joints listed twice in {self.joints}")
        for what, names in (("constraints.joints", self.constraints.joints), ("gains", self.gains)):
            unknown = sorted(set(names) - set(self.joints))
            if unknown:
                raise ValueError(f"{what} names joints {unknown} that are not in joints")
        if self.command_interfaces == ["effort"]:
            missing = [j for j in self.joints if j not in self.gains]
            if missing:
                raise ValueError(f"the effort interface needs gains for {missing}")
        elif self.gravity_compensation:
            raise ValueError(
                "gravity_compensation is for the effort interface: a position command already gets the "
                "supervisor's gravity feed-forward"
            )
        return self


@dataclass
class Track:
    """A trajectory over some of the controller's joints; ``owned`` shrinks as later goals take joints."""

    trajectory: Trajectory
    t0: float
    cols: np.ndarray  # the trajectory's columns → controller joints
    owned: np.ndarray  # bool per trajectory column
    p: np.ndarray
    v: np.ndarray
    a: np.ndarray
    direct: bool  # owns every joint of the controller, in order: samples straight into the desired state

    @classmethod
    def of(cls, trajectory: Trajectory, t0: float, cols: np.ndarray, joints: int) -> Track:
        n = len(cols)
        direct = n == joints and bool(np.array_equal(cols, np.arange(n)))
        return cls(trajectory, t0, cols, np.ones(n, dtype=bool), np.zeros(n), np.zeros(n), np.zeros(n), direct)

    def sample(self, t: float, pd: np.ndarray, vd: np.ndarray, ad: np.ndarray) -> None:
        if self.direct:
            self.trajectory.sample(t - self.t0, pd, vd, ad)
            return
        self.trajectory.sample(t - self.t0, self.p, self.v, self.a)
        cols = self.cols[self.owned]
        pd[cols], vd[cols], ad[cols] = self.p[self.owned], self.v[self.owned], self.a[self.owned]

    def release(self, taken: np.ndarray) -> None:
        """Stop driving the controller joints marked in ``taken`` (a later goal has them)."""
        self.owned &= ~taken[self.cols]
        self.direct = self.direct and bool(self.owned.all())

    def finished(self, t: float) -> bool:
        return self.trajectory.finished(t - self.t0)


class JointTrajectoryController(PlansMotion, Controller):
    SOURCE = Source.TRAJECTORY
    Params = JointTrajectoryParams
    KIND = "joint_trajectory"
    MEASURED = ("position", "velocity")  # tolerances and feedback compare both

    def __init__(self, context: ControllerContext, params: JointTrajectoryParams) -> None:
        super().__init__(context, params)
        self.index = context.index_of(params.joints)
        n = len(self.index)
        self.goal_context = self._goal_context(params, context)
        self.limits = self.goal_context.limits
        self.interfaces = tuple(params.command_interfaces)
        self.pd, self.vd, self.ad = np.zeros(n), np.zeros(n), np.zeros(n)
        self.tracks: list[Track] = []
        self.goal: GoalRequest[PreparedGoal] | None = None
        self.goal_track: Track | None = None
        self.canceling = False
        self._feedback_interval = 1.0 / min(params.feedback_rate, context.update_rate)
        self._next_feedback = 0.0
        self._q = np.zeros(n)
        self._qd = np.zeros(n)
        self._modes = np.zeros(n, dtype=np.int64)
        self._gains = self._gain_table(params)  # rows as GAIN_FIELDS; the rows below are views that stay valid
        self._kp, self._ki, self._kd, self._i_clamp, self._kff = self._gains
        self._gains_target = self._gains.copy()
        self._gains_step = np.zeros_like(self._gains)
        self._ramp_left = 0  # cycles of a gain ramp still to go
        self._integral = np.zeros(n)
        self.action: ActionServer[PreparedGoal] = ActionServer(
            params.joints, self._parse, self._accepting, context.notify, context.mailboxes
        )

    @staticmethod
    def _goal_context(params: JointTrajectoryParams, context: ControllerContext) -> GoalContext:
        idx = context.index_of(params.joints)
        limits = context.limits
        per_joint = [params.constraints.joints.get(j, JointConstraint()) for j in params.joints]
        return GoalContext(
            joints=tuple(params.joints),
            soft_lower=limits.soft_lower[idx],
            soft_upper=limits.soft_upper[idx],
            limits=KinematicLimits(limits.velocity[idx], limits.acceleration[idx], limits.jerk[idx]).scaled(
                params.velocity_scale * PLAN_MARGIN, params.acceleration_scale * PLAN_MARGIN
            ),
            allow_partial=params.allow_partial_joints_goal,
            path_position=np.array([c.trajectory for c in per_joint]),
            path_velocity=np.array([c.trajectory_velocity for c in per_joint]),
            goal_position=np.array([c.goal for c in per_joint]),
            goal_velocity=np.full(len(per_joint), params.constraints.stopped_velocity_tolerance),
            goal_time=params.constraints.goal_time,
            start_tolerance=params.start_tolerance,
        )

    @staticmethod
    def _gain_table(params: JointTrajectoryParams) -> np.ndarray:
        gains = [params.gains.get(j) for j in params.joints]
        return np.array([[getattr(g, k) if g else 0.0 for g in gains] for k in GAIN_FIELDS])

    def on_params(self, old: Params) -> None:
        """Tolerances, scales and options apply to goals accepted from now on (a running goal keeps the plan and
        the checks it was accepted with: nothing it already does changes under it). New PID gains on an active
        controller are ramped in linearly over ``GAIN_RAMP``: with a tracking error, a gain step would be an
        effort step. The integral holds ∫ i·e dt, so a new ``i`` never steps it; a lowered clamp trims it as the
        clamp ramps down."""
        assert isinstance(self.params, JointTrajectoryParams)
        self.goal_context = self._goal_context(self.params, self.context)
        self.limits = self.goal_context.limits
        self._feedback_interval = 1.0 / min(self.params.feedback_rate, self.context.update_rate)
        self._gains_target[:] = self._gain_table(self.params)
        if self.active:
            self._ramp_left = max(1, round(GAIN_RAMP * self.context.update_rate))
            np.subtract(self._gains_target, self._gains, out=self._gains_step)
            self._gains_step /= self._ramp_left
        else:
            self._gains[:] = self._gains_target
            self._ramp_left = 0

    # ---- contract ----------------------------------------------------------------------------------------------
    def gravity_joints(self) -> list[str]:
        assert isinstance(self.params, JointTrajectoryParams)
        return list(self.params.joints) if self.params.gravity_compensation else []

    def action_server(self) -> ActionServer[PreparedGoal]:
        return self.action

    # ---- API side ------------------------------------------------------------------------------------------------
    def _accepting(self) -> str | None:
        return None if self.active else f"controller {self.name} is not active"

    def _parse(self, payload: Any) -> PreparedGoal:
        return parse_goal(payload, self.goal_context)

    # ---- cycle side ----------------------------------------------------------------------------------------------
    def on_activate(self, state: JointState, last_command: ServoCommand) -> None:
        """Hold where the joints are: the first goal starts from here."""
        self.pd[:] = state.position[self.index]
        self.vd[:] = 0.0
        self.ad[:] = 0.0
        self.tracks.clear()
        self.goal, self.goal_track, self.canceling = None, None, False
        self._integral[:] = 0.0
        self._next_feedback = 0.0
        self._gains[:], self._ramp_left = self._gains_target, 0  # a ramp cut short by a deactivation ends here

    def on_deactivate(self) -> None:
        if self.goal is not None:
            self._finish(GoalStatus.ABORTED, ErrorCode.INVALID_GOAL, "the controller was deactivated")
        while (request := self.action.requests.poll()) is not None:
            if isinstance(request, GoalRequest):
                self.action.finish(
                    request.goal_id, GoalStatus.ABORTED, ErrorCode.INVALID_GOAL, "the controller was deactivated"
                )
        self.tracks.clear()

    def update(self, t: float, dt: float, state: JointState, command: ServoCommand) -> None:
        if self._joint_taken_over(state):
            return
        if len(self.action.requests):
            self._take_requests(t)
        for track in self.tracks:
            track.sample(t, self.pd, self.vd, self.ad)
        q, qd = self._q, self._qd
        state.position.take(self.index, out=q)
        state.velocity.take(self.index, out=qd)
        if self.goal is not None:
            self._supervise_goal(t, q, qd)
            if self.goal is not None and t + 1e-9 >= self._next_feedback:
                self._feedback(t, q, qd)
        self._write(dt, q, qd, command)

    def _joint_taken_over(self, state: JointState) -> bool:
        """A faulted or e-stopped joint aborts the goal; the desired state follows the measured one meanwhile."""
        j = first_taken_over(self.context.joint_modes, self.index, self._modes)
        if j < 0:
            return False
        if self.goal is not None:
            self._finish(GoalStatus.ABORTED, ErrorCode.INVALID_GOAL, f"joint {self.params.joints[j]} faulted")
        if len(self.action.requests):
            self._refuse_requests(f"joint {self.params.joints[j]} is faulted")
        self.tracks.clear()
        np.take(state.position, self.index, out=self.pd)
        self.vd[:] = 0.0
        self.ad[:] = 0.0
        self._integral[:] = 0.0
        return True

    def _refuse_requests(self, reason: str) -> None:
        """Goals that arrive while a joint is taken over are aborted, never kept: a reset must not start a motion
        that was asked for before it (cancels and client-lost notices have nothing left to act on)."""
        while (request := self.action.requests.poll()) is not None:
            if isinstance(request, GoalRequest):
                text = f"not started: {reason}"
                self.action.finish(request.goal_id, GoalStatus.ABORTED, ErrorCode.INVALID_GOAL, text)

    # ---- goals ---------------------------------------------------------------------------------------------------
    def _take_requests(self, t: float) -> None:
        while (request := self.action.requests.poll()) is not None:
            if isinstance(request, ClientLost):
                self._client_lost(request, t)
            elif isinstance(request, CancelRequest):
                if self.goal is not None and request.goal_id == self.goal.goal_id and not self.canceling:
                    self.canceling = True
                    self._stop(self.goal.goal.cols, t)
                    self.goal_track = self.tracks[-1]
            else:
                self._adopt(request, t)

    def on_client_domain_lost(self, t: float, reason: str) -> None:
        """Whatever ``on_client_lost`` says: with the client domain gone, no one could cancel the goal."""
        self._refuse_requests(reason)
        if self.goal is not None and not self.canceling:
            self._abort(t, ErrorCode.INVALID_GOAL, reason)

    def _client_lost(self, request: ClientLost, t: float) -> None:
        """The running goal's sender is gone: stop and abort it, or let it run (``on_client_lost``)."""
        if self.goal is None or request.goal_id != self.goal.goal_id or self.canceling:
            return  # it already ended, was preempted, or is being canceled
        if self.params.on_client_lost == "continue":
            self.context.emit_event(
                "warning", f"goal {request.goal_id}: {request.reason}; it runs on (on_client_lost: continue)"
            )
            return
        self._abort(t, ErrorCode.INVALID_GOAL, f"{request.reason} (on_client_lost: stop)")

    def _adopt(self, request: GoalRequest[PreparedGoal], t: float) -> None:
        goal = request.goal
        cols = goal.cols
        try:
            trajectory = goal.trajectory(self.pd[cols], self.vd[cols], self.ad[cols])
        except (GoalRejected, PlanningError) as exc:
            self.action.finish(request.goal_id, GoalStatus.ABORTED, ErrorCode.INVALID_GOAL, str(exc))
            return
        if self.goal is not None:
            self._finish(GoalStatus.PREEMPTED, ErrorCode.SUCCESSFUL, f"preempted by goal {request.goal_id}")
        self._release(cols)
        if self.params.partial_goal_other_joints == "stop" and len(cols) < len(self.index):
            others = np.setdiff1d(np.arange(len(self.index)), cols)
            self._stop(others, t)
        track = Track.of(trajectory, t, cols, len(self.index))
        self.tracks.append(track)
        self.goal, self.goal_track, self.canceling = request, track, False
        self._next_feedback = t

    def _supervise_goal(self, t: float, q: np.ndarray, qd: np.ndarray) -> None:
        assert self.goal is not None and self.goal_track is not None
        track, tol = self.goal_track, self.goal.goal.tolerances
        cols = self.goal.goal.cols
        if self.canceling:
            if track.finished(t):
                self._finish(GoalStatus.CANCELED, ErrorCode.SUCCESSFUL, "canceled; stopped and holding")
            return
        if not track.finished(t):
            violation = self._path_violation(q, qd)
            if violation:
                # The arm is not where its path is (an obstacle, a stall): stop where it *is*. Decelerating from
                # the desired state would hold a setpoint beyond the obstacle and press on it with kp × the lag
                # for good (issue 28: 137 of arm6's 150 N·m, long after the abort).
                self.pd[cols], self.vd[cols], self.ad[cols] = q[cols], qd[cols], 0.0
                self._abort(t, ErrorCode.PATH_TOLERANCE_VIOLATED, violation)
            return
        error = np.abs(self.pd[cols] - q[cols])
        off = (tol.goal_position > 0.0) & (error > tol.goal_position)
        moving = (tol.goal_velocity > 0.0) & (np.abs(qd[cols]) > tol.goal_velocity)
        if not (off.any() or moving.any()):
            self._finish(GoalStatus.SUCCEEDED, ErrorCode.SUCCESSFUL, "")
            return
        late = t - track.t0 - track.trajectory.duration
        if late > tol.goal_time:
            j = int(np.flatnonzero(off | moving)[0])
            name = self.params.joints[cols[j]]
            detail = f"position error {error[j]:.4g} rad" if off[j] else f"still moving at {abs(qd[cols[j]]):.4g} rad/s"
            self._abort(
                t,
                ErrorCode.GOAL_TOLERANCE_VIOLATED,
                f"goal tolerance violated on {name} {tol.goal_time:g} s after the end: {detail}",
            )

    def _path_violation(self, q: np.ndarray, qd: np.ndarray) -> str:
        """Why the running goal is off its path (the first joint out of tolerance), or "" while it is on it.

        Runs every cycle while a goal moves: plain floats over the goal's joints, no temporary arrays."""
        assert self.goal is not None
        cols, position_tol, velocity_tol = self.goal.goal.path_check
        pd, vd, q_now, qd_now = self.pd.tolist(), self.vd.tolist(), q.tolist(), qd.tolist()
        for k, c in enumerate(cols):
            error, tol = abs(pd[c] - q_now[c]), position_tol[k]
            if tol > 0.0 and error > tol:
                return f"path tolerance violated on {self.params.joints[c]}: position error {error:.4g} rad > {tol:g}"
            error, tol = abs(vd[c] - qd_now[c]), velocity_tol[k]
            if tol > 0.0 and error > tol:
                return f"path tolerance violated on {self.params.joints[c]}: velocity error {error:.4g} rad/s > {tol:g}"
        return ""

    def _abort(self, t: float, code: ErrorCode, reason: str) -> None:
        assert self.goal is not None
        cols = self.goal.goal.cols
        self._finish(GoalStatus.ABORTED, code, reason)
        self.context.emit_event("warning", f"goal aborted: {reason}; decelerating to a stop")
        self._stop(cols, t)

    def _finish(self, status: GoalStatus, code: int, text: str) -> None:
        assert self.goal is not None
        self.action.finish(self.goal.goal_id, status, code, text)
        self.goal, self.goal_track, self.canceling = None, None, False

    def _release(self, cols: np.ndarray) -> None:
        """Take ``cols`` away from the tracks that drive them; drop tracks left with nothing."""
        taken = np.zeros(len(self.index), dtype=bool)
        taken[cols] = True
        for track in self.tracks:
            track.release(taken)
        self.tracks = [track for track in self.tracks if track.owned.any()]

    def _stop(self, cols: np.ndarray, t: float) -> None:
        """Decelerate ``cols`` jerk-limited from their desired state to rest; they hold where they stop."""
        segment = plan_stop(self.pd[cols], self.vd[cols], self.ad[cols], self.limits.subset(cols))
        self._release(cols)
        self.tracks.append(Track.of(Trajectory([segment], len(cols)), t, cols, len(self.index)))

    def _feedback(self, t: float, q: np.ndarray, qd: np.ndarray) -> None:
        assert self.goal is not None
        self._next_feedback += self._feedback_interval
        if self._next_feedback <= t:
            self._next_feedback = t + self._feedback_interval
        ring = self.action.feedback
        i = ring.slot()
        data = ring.data
        data["desired_positions"][i] = self.pd
        data["desired_velocities"][i] = self.vd
        data["actual_positions"][i] = q
        data["actual_velocities"][i] = qd
        data["serial"][i, 0] = self.goal.serial
        ring.commit(t)
        self.context.notify()

    # ---- command -------------------------------------------------------------------------------------------------
    def _write(self, dt: float, q: np.ndarray, qd: np.ndarray, command: ServoCommand) -> None:
        idx = self.index
        if self.interfaces[0] == "effort":
            if self._ramp_left:
                self._step_gains()
            error = self.pd - q
            self._integral += self._ki * error * dt
            np.clip(self._integral, -self._i_clamp, self._i_clamp, out=self._integral)
            effort = self._kp * error + self._integral + self._kd * (self.vd - qd)
            command.effort[idx] = effort + self._kff * self.vd
        else:
            command.position[idx] = self.pd
            if "velocity" in self.interfaces:
                command.velocity[idx] = self.vd
        command.written[idx] = True

    def _step_gains(self) -> None:
        self._ramp_left -= 1
        if self._ramp_left:
            self._gains += self._gains_step
        else:
            self._gains[:] = self._gains_target  # exactly the new values, whatever the rounding on the way
