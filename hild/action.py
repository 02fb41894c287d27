"""Goals a controller executes over time (trajectories, moves), with the goal → feedback → result contract.

The asyncio side accepts or rejects a goal at once (parsing and planning happen there, so the cycle only ever
receives a prepared goal), assigns its id and hands it to the cycle through a bounded queue. The cycle adopts it
at the start of an update, reports feedback into a preallocated ring and a final result into a bounded queue
(mailboxes from the controller's context, so the halves may live in two processes); the asyncio side turns both
into messages. Results wait in that queue for at most ``KEPT_RESULTS`` goals: if the API half collects none for
that long (it is gone), later results are refused there and the restarted API half learns the goal's end from
the cycle's own record. Results of recent goals are kept so a client that missed the published
result can still ask for it; the API half also leaves them in a latest-value cell of its own, so that the API
half a restarted client domain builds answers for goals that ended before the crash too.

A goal body may name its sender (``"client": "<id>"``, the id of the sender's Zenoh liveliness token,
hild/api/goal_senders.py). When that token goes away, ``client_lost`` hands each of the sender's running goals to the
cycle as a :class:`ClientLost` request; the controller decides (joint_trajectory: ``on_client_lost``). A controller
that does not know the request treats it as the cancel it derives from: the safe default.

Statuses and error codes follow ROS's FollowJointTrajectory action, so tools that know it read ours.
"""

from __future__ import annotations

import enum
import itertools
import re
import uuid
from collections import OrderedDict, deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

from hild.crossing.mailboxes import InProcess, Latest, Mailboxes, Queue
from hild.crossing.ring import RingReader

__all__ = [
    "ActionServer",
    "CancelRequest",
    "ClientLost",
    "ErrorCode",
    "GoalRejected",
    "GoalRequest",
    "GoalResult",
    "GoalStatus",
    "split_client",
]

G = TypeVar("G")

PENDING_GOALS = 16  # goals accepted but not yet adopted by the cycle; more are refused ("busy")
KEPT_RESULTS = 256  # finished goals whose result can still be queried
KEPT_BYTES = 256 << 10  # those results as the pickle left for a restarted API half (texts of ~1 KB each fit)
GOAL_BYTES = 16 << 20  # a prepared goal as it crosses to the cycle process: MAX_POINTS points, planned
CLIENT_KEY = "client"  # optional key of a goal body: the sender's liveliness id
_CLIENT_ID = re.compile(r"^[A-Za-z0-9_\-.]{1,64}$")  # one Zenoh key chunk, bounded
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


@dataclass(frozen=True, slots=True)
class ClientLost(CancelRequest):
    """The client that sent ``goal_id`` is gone (its liveliness token was withdrawn)."""

    client: str
    reason: str


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
        mailboxes: Mailboxes | None = None,
    ) -> None:
        self.joint_names = list(joint_names)
        self._parse = parse
        self._accepting = accepting  # None when goals are welcome, else the reason they are not
        self._notify = notify
        boxes = mailboxes or InProcess()
        self.requests: Queue[GoalRequest[G] | CancelRequest] = boxes.queue("goals", PENDING_GOALS, GOAL_BYTES)
        self.feedback = boxes.ring("feedback", len(self.joint_names), (*FEEDBACK_FIELDS, "serial"), capacity=64)
        self._feedback_reader = RingReader(self.feedback)
        self._finished: Queue[GoalResult] = boxes.queue("results", KEPT_RESULTS)  # cycle → API half
        self._kept: Latest[list[GoalResult]] = boxes.latest("kept_results", KEPT_BYTES)  # API half → its successor
        self._inherited = False  # the predecessor's kept results are in the store (taken at the first absorb)
        self._serials = itertools.count(1)
        self._live: dict[str, int] = {}  # accepted, no result yet: goal id → serial
        self._ids_by_serial: dict[int, str] = {}
        self._results: OrderedDict[str, GoalResult] = OrderedDict()
        self._unannounced: deque[GoalResult] = deque()  # stored by a query's bookkeeping, not yet returned by collect
        self._clients: dict[str, str] = {}  # live goal id → the client that sent it (when the goal named one)
        self._lost: deque[ClientLost] = deque()  # client-lost notices waiting for room in the request queue

    # ---- asyncio side --------------------------------------------------------------------------------------
    def submit(self, payload: Any) -> dict[str, Any]:
        """``{"ok", "error", "goal_id"}``: ok means accepted (its result comes later).

        Safe to call from a worker thread (the API parses large goals off the event loop)."""
        goal_id = uuid.uuid4().hex
        try:
            payload, client = split_client(payload)
            reason = self._accepting()
            if reason:
                raise GoalRejected(reason)
            goal = self._parse(payload)
        except (GoalRejected, ValueError) as exc:
            return {"ok": False, "error": str(exc) or type(exc).__name__, "goal_id": goal_id}
        serial = next(self._serials)
        self._live[goal_id] = serial  # before the cycle can see it, so its result always finds it live
        self._ids_by_serial[serial] = goal_id
        if client is not None:
            self._clients[goal_id] = client
        if not self.requests.offer(GoalRequest(goal_id, serial, goal)):
            del self._live[goal_id], self._ids_by_serial[serial]
            self._clients.pop(goal_id, None)
            return {"ok": False, "error": f"busy: {PENDING_GOALS} goals waiting for the cycle", "goal_id": goal_id}
        return {"ok": True, "error": None, "goal_id": goal_id}

    def cancel(self, payload: Any) -> dict[str, Any]:
        goal_id = _goal_id(payload)
        self._absorb()
        if goal_id not in self._live:
            known = "finished" if goal_id in self._results else "unknown"
            return {"ok": False, "error": f"goal {goal_id} is {known}; nothing to cancel"}
        if not self.requests.offer(CancelRequest(goal_id)):
            return {"ok": False, "error": "busy: too many requests waiting for the cycle; retry"}
        return {"ok": True, "error": None}

    def result(self, payload: Any) -> dict[str, Any]:
        goal_id = _goal_id(payload)
        self._absorb()
        if goal_id in self._results:
            return self._results[goal_id].as_dict()
        if goal_id in self._live:
            return {"goal_id": goal_id, "status": str(GoalStatus.EXECUTING)}
        return {"ok": False, "error": f"unknown goal {goal_id} (results are kept for the last {KEPT_RESULTS} goals)"}

    def collect(self) -> list[GoalResult]:
        """Move results the cycle reported into the store; returns the ones not returned before (to publish).

        Results a ``cancel`` or ``result`` query moved into the store meanwhile are returned too: every result
        is published once."""
        self._absorb()
        self._offer_lost()
        new = []
        while self._unannounced:
            new.append(self._unannounced.popleft())
        return new

    def _absorb(self) -> None:
        """Move results the cycle reported into the store (any asyncio-side thread)."""
        if not self._inherited:
            self._inherited = True
            for kept in self._kept.take() or ():  # a dead predecessor's: already published by it
                self._results[kept.goal_id] = kept
        absorbed = False
        while (result := self._finished.poll()) is not None:
            serial = self._live.pop(result.goal_id, None)
            if serial is not None:
                self._ids_by_serial.pop(serial, None)
            self._clients.pop(result.goal_id, None)
            self._results[result.goal_id] = result
            while len(self._results) > KEPT_RESULTS:
                self._results.popitem(last=False)
            self._unannounced.append(result)
            absorbed = True
        if absorbed:
            self._leave_results()

    def _leave_results(self) -> None:
        """Leave the store where a successor can take it; texts longer than planned keep only the newest."""
        kept = list(self._results.values())
        while kept:
            try:
                self._kept.put(kept)
                return
            except ValueError:
                kept = kept[len(kept) // 2 :]

    def client_lost(self, client: str) -> list[str]:
        """``client``'s liveliness token went away: hand each of its running goals to the cycle as a
        :class:`ClientLost` request. Returns their ids. A notice that finds the request queue full is offered
        again at the next ``collect`` (the API collects whenever the cycle rings)."""
        self._absorb()
        goals = [goal_id for goal_id, sender in list(self._clients.items()) if sender == client]
        for goal_id in goals:
            self._lost.append(ClientLost(goal_id, client, f"the client that sent it ({client}) is gone"))
        self._offer_lost()
        return goals

    def _offer_lost(self) -> None:
        while self._lost:
            notice = self._lost[0]
            if notice.goal_id in self._live and not self.requests.offer(notice):
                return
            self._lost.popleft()

    def feedback_reader(self) -> RingReader:
        """A reader of its own for another consumer of feedback (the ROS 2 face); the API's is untouched."""
        return RingReader(self.feedback)

    def feedback_messages(self, reader: RingReader | None = None) -> list[dict[str, Any]]:
        """New feedback as messages, from the API's reader or ``reader``."""
        out = []
        for _, stamp, fields in (reader or self._feedback_reader).read():
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
        self._finished.offer(GoalResult(goal_id, status, code, text))  # full only if the API half is gone: see above
        self._notify()


def split_client(payload: Any) -> tuple[Any, str | None]:
    """A goal body without its ``client`` key, and the client id it named (None when it named none)."""
    if not isinstance(payload, dict) or CLIENT_KEY not in payload:
        return payload, None
    client = payload[CLIENT_KEY]
    if not isinstance(client, str) or not _CLIENT_ID.match(client):
        raise GoalRejected(f"{CLIENT_KEY} must be the sender's liveliness id (1–64 of A-Z a-z 0-9 _ - .)")
    return {key: value for key, value in payload.items() if key != CLIENT_KEY}, client


def _goal_id(payload: Any) -> str:
    if not isinstance(payload, dict) or not isinstance(payload.get("goal_id"), str) or set(payload) != {"goal_id"}:
        raise ValueError('expected an object {"goal_id": "<id>"}')
    return payload["goal_id"]
