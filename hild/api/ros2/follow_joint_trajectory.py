"""A joint_trajectory controller's ``follow_joint_trajectory`` action (control_msgs/action/FollowJointTrajectory)
and its ``joint_trajectory`` topic, as JTC has them. The action's services and topics are ``actions.RosAction``'s;
this module converts the goal, the result and the feedback. hild's error codes come from FollowJointTrajectory.
"""

from __future__ import annotations

import asyncio
from typing import Any

import numpy as np

from hild.action import ActionServer
from hild.api.ros2 import types
from hild.api.ros2.actions import RosAction
from hild.api.ros2.clock import ros_time
from hild.api.ros2.node import RosNode
from hild.api.ros2.trajectory import trajectory_body

ACTION = "control_msgs/action/FollowJointTrajectory"
TRAJECTORY = "trajectory_msgs/msg/JointTrajectory"

m = types.message


def _seconds(duration: Any) -> float:
    return float(duration.sec) + float(duration.nanosec) * 1e-9


def goal_body(goal: Any, now_ns: int) -> dict[str, Any]:
    """A FollowJointTrajectory goal as hild's JSON goal body; ValueError for what hild does not do."""
    multi = goal.multi_dof_trajectory
    if len(multi.joint_names) or len(multi.points):
        raise ValueError("multi-DOF trajectories are not supported")
    if len(goal.component_path_tolerance) or len(goal.component_goal_tolerance):
        raise ValueError("component tolerances (multi-DOF joints) are not supported")
    body: dict[str, Any] = {"trajectory": trajectory_body(goal.trajectory, now_ns)}
    for key in ("path_tolerance", "goal_tolerance"):
        entries = getattr(goal, key)
        if len(entries):
            body[key] = [
                {"name": t.name, "position": float(t.position), "velocity": float(t.velocity)} for t in entries
            ]
    if _seconds(goal.goal_time_tolerance) > 0.0:
        body["goal_time_tolerance"] = _seconds(goal.goal_time_tolerance)
    return body


def _point(positions: Any, velocities: Any) -> Any:
    empty = np.zeros(0)
    return m(
        "trajectory_msgs/msg/JointTrajectoryPoint",
        positions=np.asarray(positions, dtype=np.float64),
        velocities=np.asarray(velocities, dtype=np.float64),
        accelerations=empty,
        effort=empty,
        time_from_start=m("builtin_interfaces/msg/Duration", sec=0, nanosec=0),
    )


def _multi_point() -> Any:
    return m(
        "trajectory_msgs/msg/MultiDOFJointTrajectoryPoint",
        transforms=[],
        velocities=[],
        accelerations=[],
        time_from_start=m("builtin_interfaces/msg/Duration", sec=0, nanosec=0),
    )


class TrajectoryAction(RosAction):
    """JTC's ``follow_joint_trajectory`` action, and its ``joint_trajectory`` topic."""

    ACTION = ACTION
    ACTION_NAME = "follow_joint_trajectory"

    def __init__(self, face: RosNode, controller: str, server: ActionServer[Any]) -> None:
        super().__init__(face, controller, server)
        face.subscribe(controller, face.name(f"{controller}/joint_trajectory"), TRAJECTORY, self._on_trajectory)

    # ---- the joint_trajectory topic (asyncio thread) -------------------------------------------------------
    async def _on_trajectory(self, trajectory: Any) -> None:
        """JTC's topic: a goal without an action (no result, no feedback); refused ones are dropped commands."""
        body = {"trajectory": trajectory_body(trajectory, self.face.now_ns())}
        reply = await asyncio.to_thread(self.server.submit, body)
        if not reply.get("ok"):
            raise ValueError(str(reply.get("error")))

    # ---- the action's messages -----------------------------------------------------------------------------
    def goal_body(self, goal: Any, now_ns: int) -> dict[str, Any]:
        return goal_body(goal, now_ns)

    def result_message(self, result: dict[str, Any]) -> Any:
        return m(
            f"{ACTION}_Result",
            error_code=int(result.get("error_code", 0)),
            error_string=str(result.get("error_string", "")),
        )

    def feedback_message(self, message: dict[str, Any]) -> Any:
        header = m("std_msgs/msg/Header", stamp=ros_time(self.face.now_ns()), frame_id="")
        return m(
            f"{ACTION}_Feedback",
            header=header,
            joint_names=list(message["joint_names"]),
            desired=_point(message["desired"]["positions"], message["desired"]["velocities"]),
            actual=_point(message["actual"]["positions"], message["actual"]["velocities"]),
            error=_point(message["error"]["positions"], message["error"]["velocities"]),
            multi_dof_joint_names=[],
            multi_dof_desired=_multi_point(),
            multi_dof_actual=_multi_point(),
            multi_dof_error=_multi_point(),
        )
