"""Goals a controller executes over time (trajectories, moves), with the goal → feedback → result contract.

Two halves, two rooms. The client half (:class:`hild.api.goals.GoalEndpoint`, in the client domain) accepts or
rejects a goal at once (parsing and planning happen there, so the cycle only ever receives a prepared goal),
assigns its id and hands it to the cycle through a bounded queue. The cycle half, this module's
:class:`ActionServer`, is what a controller declares and runs: the cycle adopts a goal at the start of an update,
reports feedback into a preallocated ring and a final result into a bounded queue (doors from the controller's
mailboxes, so the halves may live in two processes); the client half turns both into messages. Results wait in
that queue for at most ``KEPT_RESULTS`` goals: if the client half collects none for that long (it is gone), later
results are refused there and the restarted client half learns the goal's end from the cycle's own record.

A goal body may name its sender (``"client": "<id>"``, the id of the sender's Zenoh liveliness token,
hild/api/goal_senders.py). When that token goes away, the client half hands each of the sender's running goals to
the cycle as a :class:`ClientLost` request; the controller decides (joint_trajectory: ``on_client_lost``). A
controller that does not know the request treats it as the cancel it derives from: the safe default.

Statuses and error codes follow ROS's FollowJointTrajectory action, so tools that know it read ours.
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

from hild.crossing.mailboxes import InProcess, Latest, Mailboxes, Queue
from hild.crossing.ring import SampleRing

__all__ = [
    "TRAJECTORY_FEEDBACK",
    "ActionServer",
    "CancelRequest",
    "ClientLost",
    "ErrorCode",
    "FeedbackShape",
    "GoalRejected",
    "GoalRequest",
    "GoalResult",
    "GoalStatus",
]

G = TypeVar("G")

PENDING_GOALS = 16  # goals accepted but not yet adopted by the cycle; more are refused ("busy")
KEPT_RESULTS = 256  # finished goals whose result can still be queried
KEPT_BYTES = 256 << 10  # those results as the pickle left for a restarted API half (texts of ~1 KB each fit)
GOAL_BYTES = 16 << 20  # a prepared goal as it crosses to the cycle process: MAX_POINTS points, planned
FEEDBACK_FIELDS = (
    "desired_positions",
    "desired_velocities",
    "actual_positions",
    "actual_velocities",
)


class GoalStatus(enum.StrEnum):
    EXECUTING = "executing"
    SUCCEEDED = "succeeded"
    ABORTED = "aborted"
    CANCELED = "canceled"
    PREEMPTED = "preempted"


class ErrorCode(enum.IntEnum):
    SUCCESSFUL = 0
    INVALID_GOAL = -1
    INVALID_JOINTS = -2
    OLD_HEADER_TIMESTAMP = -3
    PATH_TOLERANCE_VIOLATED = -4
    GOAL_TOLERANCE_VIOLATED = -5


ResultValue = float | bool


@dataclass(frozen=True, slots=True)
class GoalResult:
    goal_id: str
    status: GoalStatus
    error_code: int = ErrorCode.SUCCESSFUL
    error_string: str = ""
    values: tuple[tuple[str, ResultValue], ...] = ()  # a controller's own result fields (a gripper's position, …)

    def as_dict(self) -> dict[str, Any]:
        return {
            "goal_id": self.goal_id,
            "status": str(self.status),
            "error_code": int(self.error_code),
            "error_string": self.error_string,
            **dict(self.values),
        }


FeedbackFields = Mapping[str, list[float]]


@dataclass(frozen=True, slots=True)
class FeedbackShape:
    """What a controller's feedback ring holds per sample (``fields``, each one value per joint) and how the client
    half turns a sample into the message clients see (``render``: joint names and the sample's fields → the
    message's own keys; the client half adds ``goal_id`` and ``stamp``)."""

    fields: tuple[str, ...]
    render: Callable[[Sequence[str], FeedbackFields], dict[str, Any]]


def _trajectory_feedback(joint_names: Sequence[str], fields: FeedbackFields) -> dict[str, Any]:
    desired_p, desired_v = fields["desired_positions"], fields["desired_velocities"]
    actual_p, actual_v = fields["actual_positions"], fields["actual_velocities"]
    return {
        "joint_names": list(joint_names),
        "desired": {"positions": desired_p, "velocities": desired_v},
        "actual": {"positions": actual_p, "velocities": actual_v},
        "error": {
            "positions": [d - a for d, a in zip(desired_p, actual_p, strict=True)],
            "velocities": [d - a for d, a in zip(desired_v, actual_v, strict=True)],
        },
    }


TRAJECTORY_FEEDBACK = FeedbackShape(FEEDBACK_FIELDS, _trajectory_feedback)


@dataclass(frozen=True, slots=True)
class GoalRequest(Generic[G]):
    goal_id: str
    serial: int  # small integer the cycle writes into the feedback ring instead of the id string
    goal: G


@dataclass(frozen=True, slots=True)
class CancelRequest:
    goal_id: str


@dataclass(frozen=True, slots=True)
class ClientLost(CancelRequest):
    """The client that sent ``goal_id`` is gone (its liveliness token was withdrawn)."""

    client: str
    reason: str


class GoalRejected(ValueError):
    """A goal that cannot be executed; the message is the reason given to the client."""


class ActionServer(Generic[G]):
    """A controller's goals, cycle half: what it declares (its joints, how a goal is parsed, whether goals are
    welcome now) and the doors both halves share. The cycle polls :attr:`requests`, writes :attr:`feedback` and
    calls :meth:`finish`; the client half (:class:`hild.api.goals.GoalEndpoint`) does the rest."""

    def __init__(
        self,
        joint_names: Sequence[str],
        parse: Callable[[Any], G],
        accepting: Callable[[], str | None],
        notify: Callable[[], None],
        mailboxes: Mailboxes | None = None,
        feedback: FeedbackShape = TRAJECTORY_FEEDBACK,
    ) -> None:
        self.joint_names = list(joint_names)
        self.parse = parse  # run by the client half: validation and planning never run on the cycle
        self.accepting = accepting  # None when goals are welcome, else the reason they are not
        self.feedback_shape = feedback
        self._notify = notify
        boxes = mailboxes or InProcess()
        self.requests: Queue[GoalRequest[G] | CancelRequest] = boxes.queue("goals", PENDING_GOALS, GOAL_BYTES)
        self.feedback: SampleRing = boxes.ring(
            "feedback", len(self.joint_names), (*feedback.fields, "serial"), capacity=64
        )
        self.results: Queue[GoalResult] = boxes.queue("results", KEPT_RESULTS)  # cycle → client half
        self.kept: Latest[list[GoalResult]] = boxes.latest("kept_results", KEPT_BYTES)  # client half → its successor

    def finish(
        self,
        goal_id: str,
        status: GoalStatus,
        code: int = ErrorCode.SUCCESSFUL,
        text: str = "",
        values: tuple[tuple[str, ResultValue], ...] = (),
    ) -> None:
        """Report a goal's end (once per goal, on a transition: never per cycle); ``values``: the controller's own
        result fields, as plain floats and bools."""
        self.results.offer(GoalResult(goal_id, status, code, text, values))  # full only if the client half is gone
        self._notify()
