"""What a request, an event or a marker becomes on ``/hild/events``: JSON, whatever the request carries."""

from __future__ import annotations

import enum
import json
import math

import numpy as np

from hild.controllers.forward_command import ForwardCommandParams
from hild.crossing.events import Event
from hild.crossing.requests import Estop, Load, SetParams, Switch
from hild.record.events import cycle_event, json_safe, marker, reply_event, request_event


class Color(enum.Enum):
    RED = "red"


def test_a_request_is_its_type_and_fields() -> None:
    event = request_event(Switch(("fwd",), ("jtc",), strict=False), 1.5, wall=10.0)
    assert (event.wall, event.t, event.kind) == (10.0, 1.5, "request")
    assert event.data == {"request": "Switch", "fields": {"activate": ["fwd"], "deactivate": ["jtc"], "strict": False}}
    assert request_event(Estop(), 0.0).data == {"request": "Estop", "fields": {}}


def test_validated_params_are_recorded_as_their_json_and_a_parameter_change_is_kind_params() -> None:
    params = ForwardCommandParams(joints=["a", "b"], interface="position")
    load = request_event(Load("fwd2", "forward_command", params, source="by me"), 0.0)
    fields = load.data["fields"]
    assert load.kind == "request" and fields["params"]["joints"] == ["a", "b"] and fields["source"] == "by me"
    change = request_event(SetParams("fwd2", params, ("command_timeout: 0.5 → 0.2",), "op@host"), 0.0)
    assert change.kind == "params" and change.data["fields"]["changes"] == ["command_timeout: 0.5 → 0.2"]
    json.dumps([load.data, change.data])  # JSON as it stands
    assert reply_event(SetParams("x", params), 0.0, "refused: nope").data == {
        "reply": "SetParams",
        "ok": False,
        "error": "refused: nope",
    }


def test_json_safe_takes_what_json_cannot() -> None:
    value = {1: (np.float64(2.5), np.arange(3)), "nan": math.nan, "color": Color.RED, "obj": object}
    safe = json_safe(value)
    assert safe == {"1": [2.5, [0, 1, 2]], "nan": "nan", "color": "red", "obj": repr(object)}
    json.dumps(safe)


def test_an_event_keeps_its_cycle_time_and_a_marker_its_words() -> None:
    event = cycle_event(Event(2.25, "error", "supervisor", "joint a fault"), wall=5.0)
    assert (event.wall, event.t, event.kind) == (5.0, 2.25, "event")
    assert event.data == {"stamp": 2.25, "level": "error", "source": "supervisor", "message": "joint a fault"}
    assert marker("task", 1.0, 2.0, task="wave").data == {"marker": "task", "task": "wave"}
