"""JSON on the wire: strict in, always-valid out.

Incoming payloads are size-checked before they are copied, must be UTF-8 JSON, and may not use the ``NaN`` /
``Infinity`` literals Python's json accepts by default (other JSON parsers reject them, and a NaN command must
never reach a controller). Outgoing messages never contain them either: a non-finite float becomes ``null``.
"""

from __future__ import annotations

import json
import math
from typing import Any

MAX_PAYLOAD = 1 << 20  # bytes; anything larger is refused before it is decoded


class PayloadError(ValueError):
    """The payload cannot be decoded; the message says why, for the sender."""


def _reject_constant(name: str) -> Any:
    raise PayloadError(f"{name} is not valid JSON; send finite numbers only")


def decode(raw: bytes) -> Any:
    if len(raw) > MAX_PAYLOAD:
        raise PayloadError(f"payload of {len(raw)} bytes exceeds the {MAX_PAYLOAD}-byte limit")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise PayloadError(f"payload is not UTF-8: {exc.reason} at byte {exc.start}") from None
    try:
        return json.loads(text, parse_constant=_reject_constant)
    except json.JSONDecodeError as exc:
        raise PayloadError(f"malformed JSON: {exc.msg} at line {exc.lineno} column {exc.colno}") from None
    except RecursionError:
        raise PayloadError("malformed JSON: nested too deeply") from None


def _finite(obj: Any) -> Any:
    if hasattr(obj, "tolist"):  # numpy
        obj = obj.tolist()
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_finite(v) for v in obj]
    return obj


def _plain(obj: Any) -> Any:
    """numpy scalars and arrays (anything with ``tolist``) as plain JSON values."""
    if hasattr(obj, "tolist"):
        return obj.tolist()
    raise TypeError(f"{type(obj).__name__} is not JSON serializable")


def encode(obj: Any) -> bytes:
    """Compact JSON; the rare non-finite float is sent as ``null`` rather than as invalid JSON."""
    try:
        text = json.dumps(obj, separators=(",", ":"), allow_nan=False, default=_plain)
    except ValueError:
        text = json.dumps(_finite(obj), separators=(",", ":"), allow_nan=False, default=_plain)
    return text.encode()
