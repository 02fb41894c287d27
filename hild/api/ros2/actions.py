"""A controller's goals as a ROS 2 action, over rmw_zenoh: what every action hild serves shares.

An action is not an RMW concept: it is three services (``_action/send_goal``, ``get_result``, ``cancel_goal``) and
two topics (``_action/feedback``; ``_action/status``, kept for late joiners). Each maps onto the controller's own
:class:`hild.api.goals.GoalEndpoint` (the client half of its goals), as the JSON API's goal endpoint does: a goal
is converted to hild's JSON goal body and goes through ``submit`` (the same parsing, limits and planning; a
refusal is ``accepted = false`` and a warning event), a cancel through ``cancel``, and results are read with
``result`` (so the JSON API still publishes each one). Statuses are ROS's. A subclass says how its action's goal
becomes a JSON body and how a JSON result and feedback become its messages (follow_joint_trajectory.py,
gripper_command.py).
"""

from __future__ import annotations

import asyncio
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hild.action import ActionServer
from hild.api.goals import GoalEndpoint
from hild.api.ros2 import types
from hild.api.ros2.clock import ros_time
from hild.api.ros2.node import RosNode, Writer

CANCEL_GOAL = "action_msgs/srv/CancelGoal"
STATUS_ARRAY = "action_msgs/msg/GoalStatusArray"
# action_msgs/msg/GoalStatus
UNKNOWN, ACCEPTED, EXECUTING, CANCELING, SUCCEEDED, CANCELED, ABORTED = range(7)
ROS_STATUS = {"succeeded": SUCCEEDED, "canceled": CANCELED, "aborted": ABORTED, "preempted": CANCELED}
# action_msgs/srv/CancelGoal return codes
CANCEL_ACCEPTED, CANCEL_REJECTED, CANCEL_UNKNOWN_GOAL, CANCEL_TERMINATED = range(4)
KEPT_FINISHED = 32  # finished goals still listed in status and answerable by get_result
NO_GOAL = bytes(16)

m = types.message


@dataclass
class Goal:
    uuid: bytes
    hild_id: str
    stamp_ns: int
    status: int = EXECUTING
    result: dict[str, Any] = field(default_factory=dict)  # hild's JSON result, once the goal ended
    done: asyncio.Event = field(default_factory=asyncio.Event)


def uuid_message(raw: bytes) -> Any:
    return m("unique_identifier_msgs/msg/UUID", uuid=np.frombuffer(raw, dtype=np.uint8).copy())


class RosAction:
    """One controller's action ``<controller>/<ACTION_NAME>`` of type ``ACTION``: declared on the face's session,
    flushed when the face is."""

    ACTION: str  # e.g. control_msgs/action/FollowJointTrajectory
    ACTION_NAME: str  # e.g. follow_joint_trajectory

    def __init__(self, face: RosNode, controller: str, server: ActionServer[Any]) -> None:
        self.face = face
        self.controller = controller
        self.server = GoalEndpoint.of(server)
        base = f"{controller}/{self.ACTION_NAME}/_action"
        self.name = face.name(f"{controller}/{self.ACTION_NAME}")
        self._goals: OrderedDict[bytes, Goal] = OrderedDict()
        self._reader = self.server.feedback_reader()
        self._feedback: Writer = face.writer(face.name(f"{base}/feedback"), f"{self.ACTION}_FeedbackMessage")
        self._status: Writer = face.writer(face.name(f"{base}/status"), STATUS_ARRAY, latched=True)
        face.declare_service(f"{base}/send_goal", f"{self.ACTION}_SendGoal", self._send_goal)
        face.declare_service(f"{base}/get_result", f"{self.ACTION}_GetResult", self._get_result)
        face.declare_service(f"{base}/cancel_goal", CANCEL_GOAL, self._cancel_goal)
        self._publish_status()

    # ---- what an action type says --------------------------------------------------------------------------
    def goal_body(self, goal: Any, now_ns: int) -> dict[str, Any]:
        """The action's goal as hild's JSON goal body; ValueError (the reason) for what hild does not do."""
        raise NotImplementedError

    def result_message(self, result: dict[str, Any]) -> Any:
        """The action's ``_Result`` from hild's JSON result (empty for a goal hild does not know)."""
        raise NotImplementedError

    def feedback_message(self, message: dict[str, Any]) -> Any:
        """The action's ``_Feedback`` from one of hild's JSON feedback messages."""
        raise NotImplementedError

    # ---- services (asyncio thread) -------------------------------------------------------------------------
    async def _send_goal(self, request: Any) -> Any:
        uuid = bytes(np.asarray(request.goal_id.uuid, dtype=np.uint8))
        now = self.face.now_ns()
        try:
            if uuid in self._goals:
                raise ValueError("a goal with this id was already sent")
            body = self.goal_body(request.goal, now)
        except ValueError as exc:
            reply = {"ok": False, "error": str(exc)}
        else:  # parsing and planning off the loop, as the JSON goal endpoint does
            reply = await asyncio.to_thread(self.server.submit, body)
        if reply.get("ok"):
            self._goals[uuid] = Goal(uuid, reply["goal_id"], now)
            self._prune()
            self._publish_status()
        else:
            self.face.refused(f"{self.name} send_goal", str(reply.get("error")))
        return m(f"{self.ACTION}_SendGoal_Response", accepted=bool(reply.get("ok")), stamp=ros_time(now))

    async def _get_result(self, request: Any) -> Any:
        """ROS's get_result answers when the goal has ended; an unknown id at once, with status UNKNOWN."""
        goal = self._goals.get(bytes(np.asarray(request.goal_id.uuid, dtype=np.uint8)))
        if goal is not None:
            await goal.done.wait()
        result = self.result_message({} if goal is None else goal.result)
        return m(f"{self.ACTION}_GetResult_Response", status=UNKNOWN if goal is None else goal.status, result=result)

    async def _cancel_goal(self, request: Any) -> Any:
        """A zero id with a zero stamp cancels every goal (ROS's rule); otherwise the one named."""
        info = request.goal_info
        uuid = bytes(np.asarray(info.goal_id.uuid, dtype=np.uint8))
        everything = uuid == NO_GOAL and info.stamp.sec == 0 and info.stamp.nanosec == 0
        targets = [g for g in self._goals.values() if everything or g.uuid == uuid]
        canceling = []
        for goal in targets:
            if goal.status in (ACCEPTED, EXECUTING) and self.server.cancel({"goal_id": goal.hild_id}).get("ok"):
                goal.status = CANCELING
                canceling.append(goal)
        if canceling:
            code = CANCEL_ACCEPTED
            self._publish_status()
        elif not targets and not everything:
            code = CANCEL_UNKNOWN_GOAL
        elif targets and all(g.done.is_set() for g in targets):
            code = CANCEL_TERMINATED
        else:
            code = CANCEL_REJECTED
        infos = [
            m("action_msgs/msg/GoalInfo", goal_id=uuid_message(g.uuid), stamp=ros_time(g.stamp_ns)) for g in canceling
        ]
        return m(f"{CANCEL_GOAL}_Response", return_code=code, goals_canceling=infos)

    # ---- out (asyncio thread) ------------------------------------------------------------------------------
    def flush(self) -> None:
        """Results of goals that ended (status published on change), and new feedback."""
        changed = False
        for goal in self._goals.values():
            if goal.done.is_set():
                continue
            result = self.server.result({"goal_id": goal.hild_id})
            status = result.get("status")
            if status in ROS_STATUS:
                goal.status = ROS_STATUS[status]
                goal.result = result
                goal.done.set()
                changed = True
        if changed:
            self._publish_status()
        by_id = {g.hild_id: g for g in self._goals.values()}
        for message in self.server.feedback_messages(self._reader):
            goal = by_id.get(message["goal_id"])
            if goal is not None:
                wrapped = m(
                    f"{self.ACTION}_FeedbackMessage",
                    goal_id=uuid_message(goal.uuid),
                    feedback=self.feedback_message(message),
                )
                self._feedback.put(types.encode(wrapped, f"{self.ACTION}_FeedbackMessage"))

    def close(self) -> None:
        """The controller was unloaded: goals still running end CANCELED (as JTC's do when it is deactivated), so
        a waiting ``get_result`` answers, and the status says so before the endpoints go."""
        ending = [g for g in self._goals.values() if not g.done.is_set()]
        for goal in ending:
            goal.status, goal.result = CANCELED, {"error_string": "the controller was unloaded"}
            goal.done.set()
        if ending:
            self._publish_status()

    def _publish_status(self) -> None:
        statuses = [
            m(
                "action_msgs/msg/GoalStatus",
                goal_info=m("action_msgs/msg/GoalInfo", goal_id=uuid_message(g.uuid), stamp=ros_time(g.stamp_ns)),
                status=g.status,
            )
            for g in self._goals.values()
        ]
        self._status.put(types.encode(m(STATUS_ARRAY, status_list=statuses), STATUS_ARRAY))

    def _prune(self) -> None:
        finished = [uuid for uuid, g in self._goals.items() if g.done.is_set()]
        for uuid in finished[: max(0, len(finished) - KEPT_FINISHED)]:
            del self._goals[uuid]
