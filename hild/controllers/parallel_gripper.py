"""parallel_gripper: a gripper's goals — go to a position with a bounded force, stop on an object, keep it.

ros2_controllers' parallel_gripper_controller, on hild's servo command. A goal is a position with a max effort and a
max velocity (JSON ``{"position", "max_effort", "max_velocity"}``; ROS 2 ParallelGripperCommand or GripperCommand).
It ends one of three ways, each result carrying ``position``, ``effort``, ``stalled`` and ``reached_goal``:

* **reached**: the finger is within ``goal_tolerance`` of the goal — succeeded;
* **stalled**: short of the goal, slower than ``stall_velocity_threshold`` for ``stall_timeout`` — an object
  between the fingers. Succeeded with ``allow_stalling``, else aborted; either way the gripper keeps the grasp;
* **timed out**: neither, by the travel at ``max_velocity`` plus ``stall_timeout`` plus ``goal_time_margin`` —
  aborted; the finger stops where it is.

The force is bounded here, not by the drive's full torque: the reference moves toward the goal at ``max_velocity``,
and the position command never leads the measured finger by more than ``max_effort / kp`` (``kp``: the joint's
position gain), so a finger blocked by an object presses with at most ``max_effort``. On a stall the gripper keeps
pressing from where it stopped with the goal's effort — ``grasp position + effort / kp``, so a box pulled out lets
the fingers close by that much, never slam shut — and hands that effort to the supervisor as the joint's
``hold_effort``. Hold, and a fault's or an e-stop's hold, keep it: **a gripper never lets go by itself**; only a new
goal (open) does (docs/safety.md, "Grasps").
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from hild.action import ActionServer, CancelRequest, ErrorCode, FeedbackShape, GoalRejected, GoalRequest, GoalStatus
from hild.arrays import JointState, ServoCommand
from hild.config.model import JointLimits
from hild.config.params import Field, Params, dynamic
from hild.controller import Controller, ControllerContext, and_more, unknown_keys
from hild.controllers.motion_common import first_taken_over
from hild.interfaces import interface_name
from hild.modes import Source

__all__ = ["GripperGoal", "ParallelGripperController", "ParallelGripperParams"]

GOAL_KEYS = ("position", "max_effort", "max_velocity")
NAMED_POSITIONS = ("open", "close")
FEEDBACK = ("position", "velocity", "effort", "stalled", "reached_goal")


class ParallelGripperParams(Params):
    joint: str = Field(min_length=1, description="The gripper's actuated joint (the knuckle, or one finger).")
    max_effort: float = dynamic(
        default=10.0, gt=0.0, description="Grasp force (N, or N·m for a knuckle) of a goal that gives none."
    )
    max_velocity: float = dynamic(default=0.1, gt=0.0, description="Speed (m/s or rad/s) of a goal that gives none.")
    goal_tolerance: float = dynamic(default=0.01, ge=0.0, description="A goal is reached within this distance.")
    allow_stalling: bool = dynamic(
        default=False, description="A stall (an object between the fingers) succeeds instead of aborting."
    )
    stall_velocity_threshold: float = dynamic(
        default=0.001, ge=0.0, description="Slower than this (m/s or rad/s) counts as not moving."
    )
    stall_timeout: float = dynamic(default=1.0, ge=0.0, description="s not moving, short of the goal, before a stall.")
    goal_time_margin: float = dynamic(
        default=2.0,
        ge=0.0,
        description="s a goal may take beyond its travel at its max velocity and the stall timeout.",
    )
    open_position: float | None = dynamic(
        default=None, description='Where goal "open" goes; default: the upper soft limit (fingers apart).'
    )
    closed_position: float | None = dynamic(
        default=None, description='Where goal "close" goes; default: the lower soft limit.'
    )
    action_monitor_rate: float = dynamic(default=20.0, gt=0.0, description="Hz of feedback while a goal runs.")
    ros_action: Literal["parallel_gripper_command", "gripper_command"] = Field(
        default="parallel_gripper_command",
        description="The ROS 2 action the face serves on <controller>/gripper_cmd: control_msgs "
        "ParallelGripperCommand, or GripperCommand (MoveIt's gripper controllers).",
    )


@dataclass(frozen=True, slots=True)
class GripperGoal:
    """A parsed goal, as it crosses to the cycle: all checked against the joint's limits."""

    position: float
    max_effort: float
    max_velocity: float


def _feedback_message(joint_names: Sequence[str], fields: Mapping[str, list[float]]) -> dict[str, Any]:
    return {
        "joint": joint_names[0],
        "position": fields["position"][0],
        "velocity": fields["velocity"][0],
        "effort": fields["effort"][0],
        "stalled": bool(fields["stalled"][0]),
        "reached_goal": bool(fields["reached_goal"][0]),
    }


GRIPPER_FEEDBACK = FeedbackShape(FEEDBACK, _feedback_message)


class ParallelGripperController(Controller):
    SOURCE = Source.TRAJECTORY
    Params = ParallelGripperParams

    def __init__(self, context: ControllerContext, params: ParallelGripperParams) -> None:
        super().__init__(context, params)
        self.params: ParallelGripperParams = params
        self._index = context.index_of([params.joint])
        self._i = int(self._index[0])
        self._mode = np.zeros(1, dtype=np.int64)  # scratch for first_taken_over
        i, lim = self._i, context.limits
        self._lower, self._upper = float(lim.soft_lower[i]), float(lim.soft_upper[i])
        self._effort_limit, self._velocity_limit = float(lim.effort[i]), float(lim.velocity[i])
        self._kp = float(context.gains.position_kp[i]) if context.gains is not None else 0.0
        self._kd = float(context.gains.position_kd[i]) if context.gains is not None else 0.0
        if context.gains is not None and not self._kp > 0.0:
            raise ValueError(
                f"{context.name}: joint {params.joint} has position kp {self._kp:g}: a gripper bounds its force "
                "through the drive's spring, so it needs position_gains (or hold gains) with kp > 0"
            )
        self.action: ActionServer[GripperGoal] = ActionServer(
            [params.joint], self._parse, self._accepting, context.notify, context.mailboxes, GRIPPER_FEEDBACK
        )
        self._monitor_interval = 1.0 / min(params.action_monitor_rate, context.update_rate)
        # The cycle's state, as plain floats (one joint: numpy would only add overhead).
        self._target = self._reference = self._command = 0.0
        self._effort = params.max_effort
        self._speed = params.max_velocity
        self._grasp_at = math.nan  # where the fingers stopped on an object; NaN: no grasp
        self._squeeze = 0.0  # signed effort the grasp keeps (toward the goal it stalled short of)
        self._pressing = 0.0  # signed effort the finger presses with now, when the force bound is what holds it
        self._carried = 0.0  # a grasp a goal in its direction started from: still pressing until the goal ends
        self._goal: GoalRequest[GripperGoal] | None = None
        self._moved_at = 0.0  # last time the finger moved faster than the stall threshold
        self._deadline = math.inf
        self._next_feedback = 0.0
        self._taken_over = False

    @classmethod
    def claims_for(cls, params: Params) -> list[str]:
        assert isinstance(params, ParallelGripperParams)
        return [interface_name(params.joint, "position"), interface_name(params.joint, "velocity")]

    @classmethod
    def joints_for(cls, params: Params) -> list[str]:
        assert isinstance(params, ParallelGripperParams)
        return [params.joint]

    @classmethod
    def robot_problems(cls, params: Params, limits: Mapping[str, JointLimits]) -> list[str]:
        assert isinstance(params, ParallelGripperParams)
        joint = limits.get(params.joint)
        if joint is None:
            return []
        problems = []
        if params.max_effort > joint.effort:
            problems.append(
                f"max_effort {params.max_effort:g} is above joint {params.joint}'s effort limit {joint.effort:g}: "
                "set params.max_effort"
            )
        if params.max_velocity > joint.velocity:
            problems.append(
                f"max_velocity {params.max_velocity:g} is above joint {params.joint}'s velocity limit "
                f"{joint.velocity:g}: set params.max_velocity"
            )
        lower = joint.position.lower + joint.soft_margin
        upper = joint.position.upper - joint.soft_margin
        for name in ("open_position", "closed_position"):
            value = getattr(params, name)
            if value is not None and not lower <= value <= upper:
                problems.append(f"{name} {value:g} is outside joint {params.joint}'s soft range [{lower:g}, {upper:g}]")
        return problems

    def state_interfaces(self) -> list[str]:
        return [interface_name(self.params.joint, f) for f in ("position", "velocity", "effort")]

    def action_server(self) -> ActionServer[GripperGoal]:
        return self.action

    def on_params(self, old: Params) -> None:
        """Defaults and tolerances apply to goals accepted from now on; the running goal keeps its own."""
        self._monitor_interval = 1.0 / min(self.params.action_monitor_rate, self.context.update_rate)

    # ---- API side ------------------------------------------------------------------------------------------------
    def _accepting(self) -> str | None:
        return None if self.active else f"controller {self.name} is not active"

    def named_position(self, name: str) -> float:
        """Where ``"open"`` or ``"close"`` goes."""
        p = self.params
        if name == "open":
            return self._upper if p.open_position is None else p.open_position
        return self._lower if p.closed_position is None else p.closed_position

    def _parse(self, payload: Any) -> GripperGoal:
        """``{"position": number | "open" | "close", "max_effort"?: N, "max_velocity"?: v}``, checked here."""
        if not isinstance(payload, dict):
            raise GoalRejected('expected an object {"position": ..., "max_effort"?: ..., "max_velocity"?: ...}')
        unknown, more = unknown_keys(payload, GOAL_KEYS)
        if unknown:
            raise GoalRejected(f"unknown keys {unknown}{and_more(more)} (a gripper goal has {list(GOAL_KEYS)})")
        if "position" not in payload:
            raise GoalRejected('a gripper goal needs "position": a number, "open" or "close"')
        raw = payload["position"]
        if isinstance(raw, str):
            if raw not in NAMED_POSITIONS:
                raise GoalRejected(f'position {raw!r}: a number, "open" or "close"')
            position = self.named_position(raw)
        else:
            position = _number(raw, "position")
            if not self._lower <= position <= self._upper:
                raise GoalRejected(
                    f"position {position:g} is outside {self.params.joint}'s soft range "
                    f"[{self._lower:g}, {self._upper:g}]"
                )
        effort = _limited(payload, "max_effort", self.params.max_effort, self._effort_limit, "effort")
        speed = _limited(payload, "max_velocity", self.params.max_velocity, self._velocity_limit, "velocity")
        return GripperGoal(position, effort, speed)

    # ---- cycle side ----------------------------------------------------------------------------------------------
    def on_activate(self, state: JointState, last_command: ServoCommand) -> None:
        """Start where the finger is; a grasp the joint's hold keeps (``hold_effort``) is taken over, not dropped."""
        q = state.position.item(self._i)
        self._target = self._reference = self._command = q
        self._effort, self._speed = self.params.max_effort, self.params.max_velocity
        kept = last_command.hold_effort.item(self._i)
        self._grasp_at, self._squeeze = (q, kept) if kept else (math.nan, 0.0)
        self._pressing = self._carried = 0.0
        self._goal, self._taken_over = None, False

    def on_deactivate(self) -> None:
        if self._goal is not None:
            text = "the controller was deactivated"
            self._end(GoalStatus.ABORTED, ErrorCode.INVALID_GOAL, text, self._command, 0.0)
        self._refuse_requests("the controller was deactivated")

    def on_client_domain_lost(self, t: float, reason: str) -> None:
        self._refuse_requests(reason)
        if self._goal is not None:
            self._stop_here()
            self._end(GoalStatus.ABORTED, ErrorCode.INVALID_GOAL, reason, self._command, 0.0)

    def update(self, t: float, dt: float, state: JointState, command: ServoCommand) -> None:
        i = self._i
        q, qd, effort = state.position.item(i), state.velocity.item(i), state.effort.item(i)
        if first_taken_over(self.context.joint_modes, self._index, self._mode) >= 0:  # fault or e-stop
            self._taken_over_by_supervisor(q, effort)
            return
        if self._taken_over:  # back after a reset: stay where the finger is (a grasp is kept)
            self._taken_over = False
            self._stop_here(q)
        if len(self.action.requests):
            self._take_requests(t, q)
        if self._grasp_at == self._grasp_at:  # holding an object: press from where the fingers stopped
            position, velocity = self._grasp_at + self._squeeze / self._kp, 0.0
        else:
            position, velocity = self._follow_reference(dt, q, qd)
        if self._goal is not None:
            self._supervise(t, q, qd, effort)
        self._command = position
        command.position[i] = position
        command.velocity[i] = velocity
        # What hold keeps if this controller stops now: the grasp, or the press of a goal still closing on it.
        command.hold_effort[i] = self._squeeze if self._grasp_at == self._grasp_at else self._pressing
        command.written[i] = True

    def _follow_reference(self, dt: float, q: float, qd: float) -> tuple[float, float]:
        """The reference moves toward the target at the goal's speed; the command is bounded so that the drive's
        law, ``kp·(position − q) + kd·(velocity − q̇)``, never asks for more than the goal's effort: a blocked finger
        presses with at most that."""
        step = self._speed * dt
        gap = self._target - self._reference
        moved = gap if -step <= gap <= step else (step if gap > 0.0 else -step)
        self._reference += moved
        speed = moved / dt if dt > 0.0 else 0.0
        kp, kd, effort = self._kp, self._kd, self._effort
        asked = kp * (self._reference - q) + kd * (speed - qd)
        if -effort <= asked <= effort:
            self._pressing = self._carried
            return self._reference, speed
        bound = effort if asked > 0.0 else -effort  # pressing: no speed term, the spring gives what is left
        self._pressing = bound
        return q + (bound + kd * qd) / kp, 0.0

    def _supervise(self, t: float, q: float, qd: float, effort: float) -> None:
        goal = self._goal
        assert goal is not None
        if abs(self._target - q) < self.params.goal_tolerance:
            self._end(GoalStatus.SUCCEEDED, ErrorCode.SUCCESSFUL, "", q, effort, reached=True)
            return
        if abs(qd) > self.params.stall_velocity_threshold:
            self._moved_at = t
        elif t - self._moved_at > self.params.stall_timeout:
            self._grasp_at = q
            self._squeeze = self._effort if self._target > q else -self._effort
            if self.params.allow_stalling:
                self._end(GoalStatus.SUCCEEDED, ErrorCode.SUCCESSFUL, "", q, effort, stalled=True)
            else:
                text = "stalled short of the goal (allow_stalling is off); holding"
                self._end(GoalStatus.ABORTED, ErrorCode.GOAL_TOLERANCE_VIOLATED, text, q, effort, stalled=True)
            return
        if t > self._deadline:
            self._stop_here(q)
            text = f"timed out {abs(self._target - q):.4g} from the goal; stopped where it is"
            self._end(GoalStatus.ABORTED, ErrorCode.GOAL_TOLERANCE_VIOLATED, text, q, effort)
            return
        if t + 1e-9 >= self._next_feedback:
            self._feedback(t, q, qd, effort)

    def _feedback(self, t: float, q: float, qd: float, effort: float) -> None:
        assert self._goal is not None
        self._next_feedback += self._monitor_interval
        if self._next_feedback <= t:
            self._next_feedback = t + self._monitor_interval
        ring = self.action.feedback
        k, data = ring.slot(), ring.data
        data["position"][k, 0] = q
        data["velocity"][k, 0] = qd
        data["effort"][k, 0] = effort
        data["stalled"][k, 0] = 0.0
        data["reached_goal"][k, 0] = 0.0
        data["serial"][k, 0] = self._goal.serial
        ring.commit(t)
        self.context.notify()

    def _take_requests(self, t: float, q: float) -> None:
        while (request := self.action.requests.poll()) is not None:
            if isinstance(request, CancelRequest):  # a cancel, or its sender is gone: stop where it is
                if self._goal is not None and request.goal_id == self._goal.goal_id:
                    self._stop_here(q)
                    self._end(GoalStatus.CANCELED, ErrorCode.SUCCESSFUL, "canceled; holding where it is", q, 0.0)
            else:
                self._adopt(request, t, q)

    def _adopt(self, request: GoalRequest[GripperGoal], t: float, q: float) -> None:
        if self._goal is not None:
            self._end(GoalStatus.PREEMPTED, ErrorCode.SUCCESSFUL, f"preempted by goal {request.goal_id}", q, 0.0)
        goal = request.goal
        self._reference = self._command  # bumpless: the force it presses with now changes smoothly
        further = (goal.position - q) * self._squeeze > 0.0  # closing on what it holds: harder, or further
        self._carried = self._squeeze if self._grasp_at == self._grasp_at and further else 0.0
        self._grasp_at, self._squeeze = math.nan, 0.0
        self._target, self._effort, self._speed = goal.position, goal.max_effort, goal.max_velocity
        self._goal = request
        self._moved_at = t
        travel = abs(goal.position - q) / goal.max_velocity
        self._deadline = t + travel + self.params.stall_timeout + self.params.goal_time_margin
        self._next_feedback = t

    def _stop_here(self, q: float | None = None) -> None:
        """Stay where the finger is; a finger pressing on an object keeps pressing (a grasp from here)."""
        here = self._command if q is None else q
        if self._grasp_at == self._grasp_at:
            return
        if self._pressing:
            self._grasp_at, self._squeeze = here, self._pressing
        else:
            self._target = self._reference = here
        self._pressing = self._carried = 0.0

    def _taken_over_by_supervisor(self, q: float, effort: float) -> None:
        """A fault or an e-stop: the supervisor holds the joint (with the grasp, if any). The goal ends; after a
        reset the finger stays where it is, and nothing asked for before the reset starts."""
        if not self._taken_over:
            self._taken_over = True
            if self._goal is not None:
                text = f"joint {self.params.joint} was taken over (fault or e-stop)"
                self._end(GoalStatus.ABORTED, ErrorCode.INVALID_GOAL, text, q, effort)
        if len(self.action.requests):
            self._refuse_requests(f"joint {self.params.joint} is faulted or e-stopped")
        self._stop_here(q)

    def _refuse_requests(self, reason: str) -> None:
        while (request := self.action.requests.poll()) is not None:
            if isinstance(request, GoalRequest):
                text = f"not started: {reason}"
                self.action.finish(request.goal_id, GoalStatus.ABORTED, ErrorCode.INVALID_GOAL, text)

    def _end(
        self,
        status: GoalStatus,
        code: int,
        text: str,
        position: float,
        effort: float,
        *,
        stalled: bool = False,
        reached: bool = False,
    ) -> None:
        assert self._goal is not None
        values = (("position", position), ("effort", effort), ("stalled", stalled), ("reached_goal", reached))
        self.action.finish(self._goal.goal_id, status, code, text, values)
        self._goal, self._deadline, self._carried = None, math.inf, 0.0


def _number(raw: Any, name: str) -> float:
    if isinstance(raw, bool) or not isinstance(raw, int | float) or not math.isfinite(raw):
        raise GoalRejected(f"{name} must be a finite number, got {raw!r}")
    return float(raw)


def _limited(payload: Mapping[str, Any], key: str, default: float, limit: float, what: str) -> float:
    """A goal's max effort or velocity: positive, and within the joint's limit (its default when absent)."""
    if key not in payload:
        return min(default, limit)
    value = _number(payload[key], key)
    if not 0.0 < value <= limit:
        raise GoalRejected(f"{key} {value:g} must be above 0 and at most the joint's {what} limit {limit:g}")
    return value
