"""Goals a controller executes over time (trajectories, moves), with the goal → feedback → result contract.

The asyncio side accepts or rejects a goal at once (parsing and planning happen there, so the cycle only ever
receives a prepared goal), assigns its id and hands it to the cycle through a bounded queue. The cycle adopts it
at the start of an update, reports feedback into a preallocated ring and a final result into a small deque; the
asyncio side turns both into messages. Results of recent goals are kept so a client that missed the published
result can still ask for it.

Statuses and error codes follow ROS's FollowJointTrajectory action, so tools that know it read ours.
"""

from __future__ import annotations

import enum
import itertools
import uuid
from collections import OrderedDict, deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

from hild.mailbox import BoundedQueue
from hild.ring import RingReader, SampleRing

G = TypeVar("G")

PENDING_GOALS = 16  # goals accepted but not yet adopted by the cycle; more are refused ("busy")
KEPT_RESULTS = 256  # finished goals whose result can still be queried
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


@dataclass(frozen=True, slots=True)
class GoalResult:
    goal_id: str
    status: GoalStatus
    error_code: int = ErrorCode.SUCCESSFUL
    error_string: str = ""

    def as_dict(self) -> dict[str, Any]:
        return {
            "goal_id": self.goal_id,
            "status": str(self.status),
            "error_code": int(self.error_code),
            "error_string": self.error_string,
        }


@dataclass(frozen=True, slots=True)
class GoalRequest(Generic[G]):
    goal_id: str
    serial: int  # small integer the cycle writes into the feedback ring instead of the id string
    goal: G


@dataclass(frozen=True, slots=True)
class CancelRequest:
    goal_id: str


class GoalRejected(ValueError):
    """A goal that cannot be executed; the message is the reason given to the client."""


class ActionServer(Generic[G]):
    """One controller's goal endpoint. ``parse`` validates a decoded JSON goal and returns a prepared goal."""

    def __init__(
        self,
        joint_names: Sequence[str],
        parse: Callable[[Any], G],
        accepting: Callable[[], str | None],
        notify: Callable[[], None],
    ) -> None:
        self.joint_names = list(joint_names)
        self._parse = parse
        self._accepting = accepting  # None when goals are welcome, else the reason they are not
        self._notify = notify
        self.requests: BoundedQueue[GoalRequest[G] | CancelRequest] = BoundedQueue(PENDING_GOALS)
        self.feedback = SampleRing(len(self.joint_names), (*FEEDBACK_FIELDS, "serial"), capacity=64)
        self._feedback_reader = RingReader(self.feedback)
        self._finished: deque[GoalResult] = deque(maxlen=KEPT_RESULTS)  # cycle → asyncio
        self._serials = itertools.count(1)
        self._live: dict[str, int] = {}  # accepted, no result yet: goal id → serial
        self._ids_by_serial: dict[int, str] = {}
        self._results: OrderedDict[str, GoalResult] = OrderedDict()

    # ---- asyncio side --------------------------------------------------------------------------------------
    def submit(self, payload: Any) -> dict[str, Any]:
        """``{"ok", "error", "goal_id"}``: ok means accepted (its result comes later).

        Safe to call from a worker thread (the API parses large goals off the event loop)."""
        goal_id = uuid.uuid4().hex
        try:
            reason = self._accepting()
            if reason:
                raise GoalRejected(reason)
            goal = self._parse(payload)
        except (GoalRejected, ValueError) as exc:
            return {"ok": False, "error": str(exc) or type(exc).__name__, "goal_id": goal_id}
        serial = next(self._serials)
        self._live[goal_id] = serial  # before the cycle can see it, so its result always finds it live
        self._ids_by_serial[serial] = goal_id
        if not self.requests.offer(GoalRequest(goal_id, serial, goal)):
            del self._live[goal_id], self._ids_by_serial[serial]
            return {"ok": False, "error": f"busy: {PENDING_GOALS} goals waiting for the cycle", "goal_id": goal_id}
        return {"ok": True, "error": None, "goal_id": goal_id}

    def cancel(self, payload: Any) -> dict[str, Any]:
        goal_id = _goal_id(payload)
        self.collect()
        if goal_id not in self._live:
            known = "finished" if goal_id in self._results else "unknown"
            return {"ok": False, "error": f"goal {goal_id} is {known}; nothing to cancel"}
        if not self.requests.offer(CancelRequest(goal_id)):
            return {"ok": False, "error": "busy: too many requests waiting for the cycle; retry"}
        return {"ok": True, "error": None}

    def result(self, payload: Any) -> dict[str, Any]:
        goal_id = _goal_id(payload)
        self.collect()
        if goal_id in self._results:
            return self._results[goal_id].as_dict()
        if goal_id in self._live:
            return {"goal_id": goal_id, "status": str(GoalStatus.EXECUTING)}
        return {"ok": False, "error": f"unknown goal {goal_id} (results are kept for the last {KEPT_RESULTS} goals)"}

    def collect(self) -> list[GoalResult]:
        """Move results the cycle reported into the store; returns the new ones (to publish)."""
        new = []
        while self._finished:
            result = self._finished.popleft()
            serial = self._live.pop(result.goal_id, None)
            if serial is not None:
                self._ids_by_serial.pop(serial, None)
            self._results[result.goal_id] = result
            while len(self._results) > KEPT_RESULTS:
                self._results.popitem(last=False)
            new.append(result)
        return new

    def feedback_messages(self) -> list[dict[str, Any]]:
        out = []
        for _, stamp, fields in self._feedback_reader.read():
            goal_id = self._ids_by_serial.get(int(fields["serial"][0]))
            if goal_id is None:  # the goal finished since; its result says the rest
                continue
            desired_p, desired_v = fields["desired_positions"], fields["desired_velocities"]
            actual_p, actual_v = fields["actual_positions"], fields["actual_velocities"]
            out.append(
                {
                    "goal_id": goal_id,
                    "stamp": stamp,
                    "joint_names": self.joint_names,
                    "desired": {"positions": desired_p, "velocities": desired_v},
                    "actual": {"positions": actual_p, "velocities": actual_v},
                    "error": {
                        "positions": [d - a for d, a in zip(desired_p, actual_p, strict=True)],
                        "velocities": [d - a for d, a in zip(desired_v, actual_v, strict=True)],
                    },
                }
            )
        return out

    # ---- cycle side ----------------------------------------------------------------------------------------
    def finish(self, goal_id: str, status: GoalStatus, code: int = ErrorCode.SUCCESSFUL, text: str = "") -> None:
        """Report a goal's end (once per goal, on a transition: never per cycle)."""
        self._finished.append(GoalResult(goal_id, status, code, text))
        self._notify()


def _goal_id(payload: Any) -> str:
    if not isinstance(payload, dict) or not isinstance(payload.get("goal_id"), str) or set(payload) != {"goal_id"}:
        raise ValueError('expected an object {"goal_id": "<id>"}')
    return payload["goal_id"]
