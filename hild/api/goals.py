"""A controller's goals, client half: accept or refuse a goal, cancel it, answer for its result, publish feedback.

The cycle half is the controller's :class:`hild.action.ActionServer` (hild/action.py): the two share only its doors.
This half keeps the bookkeeping a client sees — which goals are live, the results of the last ``KEPT_RESULTS``,
which client sent which goal — and runs in the client domain only: parsing and planning a goal happen here (in a
worker thread for large ones), never on the cycle. One per controller in a process (:meth:`GoalEndpoint.of`), so the
JSON endpoints, the ROS 2 face and the liveliness watch see the same goals. It also leaves its results in a
latest-value door, so the half a restarted client domain builds answers for goals that ended before the crash.
"""

from __future__ import annotations

import itertools
import re
import uuid
import weakref
from collections import OrderedDict, deque
from typing import Any, ClassVar, Generic, TypeVar

from hild.action import (
    KEPT_RESULTS,
    PENDING_GOALS,
    ActionServer,
    CancelRequest,
    ClientLost,
    GoalRejected,
    GoalRequest,
    GoalResult,
    GoalStatus,
)
from hild.crossing.ring import RingReader

G = TypeVar("G")

CLIENT_KEY = "client"  # optional key of a goal body: the sender's liveliness id
_CLIENT_ID = re.compile(r"[A-Za-z0-9_\-.]{1,64}")  # one Zenoh key chunk, bounded (fullmatch: no final "\n")


class GoalEndpoint(Generic[G]):
    _endpoints: ClassVar[weakref.WeakKeyDictionary[ActionServer[Any], GoalEndpoint[Any]]] = weakref.WeakKeyDictionary()

    def __init__(self, action: ActionServer[G]) -> None:
        self._action = action
        self._feedback_reader = RingReader(action.feedback)
        self._inherited = False  # the predecessor's kept results are in the store (taken at the first absorb)
        self._serials = itertools.count(1)
        self._live: dict[str, int] = {}  # accepted, no result yet: goal id → serial
        self._ids_by_serial: dict[int, str] = {}
        self._results: OrderedDict[str, GoalResult] = OrderedDict()
        self._unannounced: deque[GoalResult] = deque()  # stored by a query's bookkeeping, not yet returned by collect
        self._clients: dict[str, str] = {}  # live goal id → the client that sent it (when the goal named one)
        self._lost: deque[ClientLost] = deque()  # client-lost notices waiting for room in the request queue

    @classmethod
    def of(cls, action: ActionServer[G]) -> GoalEndpoint[G]:
        """The one client half of ``action`` in this process (built at the first call)."""
        endpoint = cls._endpoints.get(action)
        if endpoint is None:
            endpoint = cls._endpoints[action] = cls(action)
        return endpoint

    @property
    def joint_names(self) -> list[str]:
        return self._action.joint_names

    def submit(self, payload: Any) -> dict[str, Any]:
        """``{"ok", "error", "goal_id"}``: ok means accepted (its result comes later).

        Safe to call from a worker thread (the API parses large goals off the event loop)."""
        goal_id = uuid.uuid4().hex
        try:
            payload, client = split_client(payload)
            reason = self._action.accepting()
            if reason:
                raise GoalRejected(reason)
            goal = self._action.parse(payload)
        except (GoalRejected, ValueError) as exc:
            return {"ok": False, "error": str(exc) or type(exc).__name__, "goal_id": goal_id}
        serial = next(self._serials)
        self._live[goal_id] = serial  # before the cycle can see it, so its result always finds it live
        self._ids_by_serial[serial] = goal_id
        if client is not None:
            self._clients[goal_id] = client
        if not self._action.requests.offer(GoalRequest(goal_id, serial, goal)):
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
        if not self._action.requests.offer(CancelRequest(goal_id)):
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
            for kept in self._action.kept.take() or ():  # a dead predecessor's: already published by it
                self._results[kept.goal_id] = kept
        absorbed = False
        while (result := self._action.results.poll()) is not None:
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
                self._action.kept.put(kept)
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
            if notice.goal_id in self._live and not self._action.requests.offer(notice):
                return
            self._lost.popleft()

    def feedback_reader(self) -> RingReader:
        """A reader of its own for another consumer of feedback (the ROS 2 face); the API's is untouched."""
        return RingReader(self._action.feedback)

    def feedback_messages(self, reader: RingReader | None = None) -> list[dict[str, Any]]:
        """New feedback as messages, from the API's reader or ``reader``: each in the controller's own shape
        (:class:`hild.action.FeedbackShape`), with its goal's id and stamp."""
        out = []
        render, names = self._action.feedback_shape.render, self._action.joint_names
        for _, stamp, fields in (reader or self._feedback_reader).read():
            goal_id = self._ids_by_serial.get(int(fields["serial"][0]))
            if goal_id is None:  # the goal finished since; its result says the rest
                continue
            out.append({"goal_id": goal_id, "stamp": stamp, **render(names, fields)})
        return out


def split_client(payload: Any) -> tuple[Any, str | None]:
    """A goal body without its ``client`` key, and the client id it named (None when it named none)."""
    if not isinstance(payload, dict) or CLIENT_KEY not in payload:
        return payload, None
    client = payload[CLIENT_KEY]
    if not isinstance(client, str) or not _CLIENT_ID.fullmatch(client):
        raise GoalRejected(f"{CLIENT_KEY} must be the sender's liveliness id (1–64 of A-Z a-z 0-9 _ - .)")
    return {key: value for key, value in payload.items() if key != CLIENT_KEY}, client


def _goal_id(payload: Any) -> str:
    if not isinstance(payload, dict) or not isinstance(payload.get("goal_id"), str) or set(payload) != {"goal_id"}:
        raise ValueError('expected an object {"goal_id": "<id>"}')
    return payload["goal_id"]
