"""A parallel_gripper controller's ``gripper_cmd`` action, as ros2_controllers' gripper controllers serve it.

Two types, chosen by the controller's ``ros_action`` parameter: ``control_msgs/action/ParallelGripperCommand``
(the parallel_gripper_action_controller's: a JointState command with optional max velocity and effort) and
``control_msgs/action/GripperCommand`` (the older GripperActionController's, what MoveIt's gripper controllers
send: a position and a max effort). The services and topics are ``actions.RosAction``'s; this module converts the
goal, the result (``position``, ``effort``, ``stalled``, ``reached_goal``) and the feedback.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from hild.api.ros2 import types
from hild.api.ros2.actions import RosAction
from hild.api.ros2.clock import ros_time

PARALLEL = "control_msgs/action/ParallelGripperCommand"
GRIPPER = "control_msgs/action/GripperCommand"
ROS_ACTIONS = {"parallel_gripper_command": PARALLEL, "gripper_command": GRIPPER}

m = types.message


def _number(value: Any) -> float:
    return float(value) if isinstance(value, int | float) else math.nan


class GripperAction(RosAction):
    """``<controller>/gripper_cmd`` of the type the controller's ``ros_action`` names."""

    ACTION_NAME = "gripper_cmd"

    def __init__(self, face: Any, controller: str, server: Any, ros_action: str) -> None:
        self.ACTION = ROS_ACTIONS[ros_action]
        self.joint = server.joint_names[0]
        super().__init__(face, controller, server)

    def goal_body(self, goal: Any, now_ns: int) -> dict[str, Any]:
        if self.ACTION == GRIPPER:
            command = goal.command
            body: dict[str, Any] = {"position": float(command.position)}
            if command.max_effort > 0.0:  # GripperCommand's 0 means "no limit given": the controller's max_effort
                body["max_effort"] = float(command.max_effort)
            return body
        command = goal.command
        names = list(command.name)
        if len(command.position) != 1 or (names and names != [self.joint]):
            raise ValueError(f"expected one position for joint {self.joint}, got {len(command.position)} for {names}")
        body = {"position": float(command.position[0])}
        if len(command.velocity):
            body["max_velocity"] = float(command.velocity[0])
        if len(command.effort):
            body["max_effort"] = float(command.effort[0])
        return body

    def result_message(self, result: dict[str, Any]) -> Any:
        position, effort = _number(result.get("position")), _number(result.get("effort"))
        stalled, reached = bool(result.get("stalled", False)), bool(result.get("reached_goal", False))
        if self.ACTION == GRIPPER:
            return m(f"{GRIPPER}_Result", position=position, effort=effort, stalled=stalled, reached_goal=reached)
        state = self._state(position, math.nan, effort)
        return m(f"{PARALLEL}_Result", state=state, stalled=stalled, reached_goal=reached)

    def feedback_message(self, message: dict[str, Any]) -> Any:
        position, effort = float(message["position"]), float(message["effort"])
        if self.ACTION == GRIPPER:
            stalled, reached = bool(message["stalled"]), bool(message["reached_goal"])
            return m(f"{GRIPPER}_Feedback", position=position, effort=effort, stalled=stalled, reached_goal=reached)
        return m(f"{PARALLEL}_Feedback", state=self._state(position, float(message["velocity"]), effort))

    def _state(self, position: float, velocity: float, effort: float) -> Any:
        header = m("std_msgs/msg/Header", stamp=ros_time(self.face.now_ns()), frame_id="")
        return m(
            "sensor_msgs/msg/JointState",
            header=header,
            name=[self.joint],
            position=np.array([position]),
            velocity=np.array([velocity]),
            effort=np.array([effort]),
        )
