"""What goes on ``/hild/events``: the cycle's events, the requests sent to it and the markers, as ``RecordedEvent``.

A request is recorded as its type and its fields, made JSON-safe here (a controller's validated params as their
JSON form), never as the bytes a client sent: the recording says what the cycle was asked, whoever asked it.
"""

from __future__ import annotations

import dataclasses
import enum
import math
import time
from collections.abc import Mapping
from typing import Any

from hild.crossing.events import Event
from hild.crossing.requests import Request, SetParams
from hild.record.model import RecordedEvent

EVENT, REQUEST, PARAMS, MARKER = "event", "request", "params", "marker"  # RecordedEvent.kind


def json_safe(value: Any) -> Any:
    """``value`` as JSON can hold it: dataclasses and pydantic models as dicts, tuples as lists, non-finite floats
    and unknown objects as strings (a recording never fails on what it records)."""
    if value is None or isinstance(value, bool | int | str):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else str(value)
    if isinstance(value, enum.Enum):
        return json_safe(value.value)
    if isinstance(value, Mapping):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple | set | frozenset):
        return [json_safe(v) for v in value]
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: json_safe(getattr(value, f.name)) for f in dataclasses.fields(value)}
    dump = getattr(value, "model_dump", None)  # a pydantic model (pydantic itself lives in hild/config)
    if callable(dump):
        try:
            return json_safe(dump(mode="json"))
        except Exception:
            return repr(value)
    tolist = getattr(value, "tolist", None)  # numpy arrays and scalars
    if callable(tolist):
        return json_safe(tolist())
    return repr(value)


def cycle_event(event: Event, wall: float | None = None) -> RecordedEvent:
    """An event the cycle (or the client domain) emitted, stamped on the cycle clock; ``wall`` when it was received
    (the recorder process moves it to the wall time of the cycle that emitted it, when that cycle's row is known)."""
    return RecordedEvent(time.time() if wall is None else wall, event.stamp, EVENT, event.as_dict())


def request_event(request: Request, t: float, wall: float | None = None) -> RecordedEvent:
    """A request as it is sent to the cycle: its type and fields (``SetParams``: a parameter change)."""
    kind = PARAMS if isinstance(request, SetParams) else REQUEST
    data = {"request": type(request).__name__, "fields": json_safe(request)}
    return RecordedEvent(time.time() if wall is None else wall, t, kind, data)


def reply_event(request: Request, t: float, error: str | None) -> RecordedEvent:
    """How the cycle answered a request (``error``: why it refused or failed; None: applied)."""
    kind = PARAMS if isinstance(request, SetParams) else REQUEST
    data: dict[str, Any] = {"reply": type(request).__name__, "ok": error is None}
    if error is not None:
        data["error"] = error
    return RecordedEvent(time.time(), t, kind, data)


def marker(name: str, t: float, wall: float | None = None, **data: Any) -> RecordedEvent:
    """An episode or task marker (``episode_start``, ``episode_stop``, ``task``)."""
    return RecordedEvent(time.time() if wall is None else wall, t, MARKER, {"marker": name, **json_safe(data)})
