"""What every service request is checked against before it is served: its fields, their validators, its size.

A service is a :class:`Service`: its fields (name → validator) and what runs it, read-only on any thread or
changing state on the asyncio thread. A validator takes ``(field, value)`` and returns the value or raises
:class:`RequestError`, whose message is the reply's ``error``. The service modules (``services``, ``lifecycle``,
``parameters``) share these, so every service refuses alike.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable, Mapping
from dataclasses import dataclass
from typing import Any

from hild.api.codec import PayloadError, decode
from hild.api.keys import check_chunk
from hild.api.queries import too_large
from hild.controller import and_more, unknown_keys

MAX_NAMES = 256
MAX_SENDER = 64  # characters of a request's "by"
MAX_NAME_CHARS = 100  # characters of a controller's name or type
# Bytes a request may have, refused larger before it is copied or decoded (docs/protocol.md, "Limits"). A request
# without fields is "", "{}" or a little whitespace; the largest with fields, a switch of 2 x MAX_NAMES names of
# up to ~120 characters. One status poll of 1 MiB cost the cycle 43 ms of GIL to refuse by its keys.
EMPTY_REQUEST = 256
FIELDS_REQUEST = 64 * 1024


def ok(body: Reply) -> Reply:
    """A successful reply; a body may carry its own ok/error (switch, reset)."""
    return {"ok": True, "error": None, **body}


class RequestError(Exception):
    """A request that cannot be served; the message is the reply's ``error``."""


Validator = Callable[[str, Any], Any]
Reply = dict[str, Any]


def names(field: str, value: Any) -> list[str]:
    """A list of distinct, non-empty controller names."""
    if not isinstance(value, list):
        raise RequestError(f"{field} must be a list of controller names, not {type(value).__name__}")
    if len(value) > MAX_NAMES:
        raise RequestError(f"{field} lists {len(value)} names; at most {MAX_NAMES}")
    seen: set[str] = set()
    for item in value:
        if not isinstance(item, str) or not item:
            raise RequestError(f"{field} must contain non-empty strings, found {item!r}")
        if item in seen:
            raise RequestError(f"{field} lists {item!r} twice")
        seen.add(item)
    return value


def boolean(field: str, value: Any) -> bool:
    if not isinstance(value, bool):
        raise RequestError(f"{field} must be true or false, not {value!r}")
    return value


def joint_name(field: str, value: Any) -> str:
    if not isinstance(value, str) or not value:
        raise RequestError(f"{field} must be a joint name, not {value!r}")
    return value


def controller_name(field: str, value: Any) -> str:
    """A controller's name: it becomes a chunk of its Zenoh keys (``hild/<robot>/ctrl/<name>/…``)."""
    if not isinstance(value, str) or not value:
        raise RequestError(f"{field} must be a controller name (letters, digits, _ - .), not {type(value).__name__}")
    if len(value) > MAX_NAME_CHARS:
        raise RequestError(f"{field} is {len(value)} characters long; at most {MAX_NAME_CHARS}")
    try:
        return check_chunk(value, field)
    except ValueError as exc:
        raise RequestError(str(exc)) from None


def text(field: str, value: Any) -> str:
    if not isinstance(value, str) or not value:
        raise RequestError(f"{field} must be a non-empty string, not {type(value).__name__}")
    if len(value) > MAX_NAME_CHARS:
        raise RequestError(f"{field} is {len(value)} characters long; at most {MAX_NAME_CHARS}")
    return value


def mapping(field: str, value: Any) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise RequestError(f"{field} must be a JSON object, not {type(value).__name__}")
    return value


def sender(field: str, value: Any) -> str:
    """Who a change is from, as the client says (``user@host``): it goes into the event and the recording."""
    if not isinstance(value, str) or not 0 < len(value) <= MAX_SENDER or not value.isprintable():
        raise RequestError(f"{field} must be a printable string of at most {MAX_SENDER} characters")
    return value


def request_limit(fields: Mapping[str, Validator]) -> int:
    """The size limit of a request with these fields, in bytes."""
    return FIELDS_REQUEST if fields else EMPTY_REQUEST


def parse_request(raw: bytes, fields: Mapping[str, Validator]) -> dict[str, Any]:
    """Decode a request object and check every field; an empty payload is an empty object.

    The size limit is checked first; the API's gate checks it too, before the payload is even copied."""
    limit = request_limit(fields)
    if len(raw) > limit:
        raise RequestError(too_large(len(raw), limit)["error"])
    if not raw.strip():
        return {}
    try:
        request = decode(raw)
    except PayloadError as exc:
        raise RequestError(str(exc)) from None
    if not isinstance(request, dict):
        raise RequestError(f"request must be a JSON object, not {type(request).__name__}")
    unknown, more = unknown_keys(request, fields)
    if unknown:
        allowed = ", ".join(sorted(fields)) if fields else "none"
        raise RequestError(f"unknown field(s) {', '.join(map(repr, unknown))}{and_more(more)} (allowed: {allowed})")
    return {key: fields[key](key, value) for key, value in request.items()}


@dataclass(frozen=True)
class Service:
    fields: Mapping[str, Validator]
    run: Callable[[dict[str, Any]], Awaitable[Reply]] | None = None  # changes state: on the asyncio thread
    read: Callable[[dict[str, Any]], Reply] | None = None  # read-only: answered on any thread

    @property
    def limit(self) -> int:
        return request_limit(self.fields)


def required(request: dict[str, Any], field: str) -> Any:
    """A field the service cannot do without (validators check only the fields present)."""
    if field not in request:
        raise RequestError(f"give the {field}: {{{field!r}: ...}}".replace("'", '"'))
    return request[field]
