"""JSON on the wire: strict in, always-valid out.

Incoming payloads are size-checked before they are copied, must be UTF-8 JSON, and may not use the ``NaN`` /
``Infinity`` literals Python's json accepts by default (other JSON parsers reject them, and a NaN command must
never reach a controller). Integers a double cannot hold (``1`` followed by 400 zeros) are refused too: no float
conversion downstream survives them. ``1e999`` still decodes to ``inf``, which every consumer refuses as
non-finite. Outgoing messages never contain non-finite numbers: a non-finite float becomes ``null``.

json's C scanner holds the GIL for its whole run (about 0.1 ms per KiB of small containers), which would stop the
cycle thread for 100 ms on a 1 MiB payload. Payloads above ``FAST_DECODE`` bytes are therefore parsed by the
pure-Python scanner: slower, but it lets the cycle thread in every switch interval. Callers decode those off the
event loop.
"""

from __future__ import annotations

import itertools
import json
import json.scanner
import math
import sys
from collections.abc import Collection, Mapping
from typing import Any

MAX_PAYLOAD = 1 << 20  # bytes; anything larger is refused before it is decoded
FAST_DECODE = 4096  # bytes; up to this size the C scanner's GIL hold (≤ ~0.4 ms) is harmless
MAX_CONTAINERS = 1024  # arrays + objects in a request or command: a few are ever needed
GOAL_CONTAINERS = 65_536  # in a goal: 10 000 points with velocities, accelerations and a {sec, nanosec} time each


SHOWN_KEYS = 3  # unknown keys a refusal names; the rest are counted


class PayloadError(ValueError):
    """The payload cannot be decoded; the message says why, for the sender."""


def unknown_keys(obj: Mapping[str, Any], allowed: Collection[str]) -> tuple[list[str], int]:
    """Up to ``SHOWN_KEYS`` keys of ``obj`` that ``allowed`` lacks, and how many more there are.

    Work in ``len(allowed) + SHOWN_KEYS``, whatever the size of ``obj``: a refusal that sorted and joined all the
    keys of a 90 000-key object held the GIL for 45 ms to build an 889 000-character error. When every unknown key
    is shown they are sorted (the error reads as it always did); otherwise the first ones, in the sender's order.
    """
    count = len(obj) - sum(1 for key in allowed if key in obj)
    if count <= 0:
        return [], 0
    shown = list(itertools.islice((key for key in obj if key not in allowed), SHOWN_KEYS))
    if len(shown) == count:
        shown.sort()
    return shown, count - len(shown)


def and_more(more: int) -> str:
    """`` and N more`` after a list that ``unknown_keys`` cut short, else nothing."""
    return f" and {more} more" if more else ""


def _reject_constant(name: str) -> Any:
    raise PayloadError(f"{name} is not valid JSON; send finite numbers only")


_MAX_INT_DIGITS = len(str(int(sys.float_info.max)))  # 309: longer integers cannot be a float


def _float_range_int(text: str) -> int:
    digits = len(text) - text.startswith("-")
    value = int(text) if digits <= _MAX_INT_DIGITS else None
    if value is None or abs(value) > sys.float_info.max:
        raise PayloadError(f"integer of {digits} digits is out of range; send finite numbers only")
    return value


def decode(raw: bytes, max_containers: int = MAX_CONTAINERS) -> Any:
    """The JSON value of ``raw``, or PayloadError saying why not.

    Above ``FAST_DECODE`` bytes, parsing stops at the first array or object beyond ``max_containers``: building and
    freeing hundreds of thousands of them runs the garbage collector in long passes that hold the GIL. (Below it,
    a payload cannot hold enough of them to matter.)
    """
    if len(raw) > MAX_PAYLOAD:
        raise PayloadError(f"payload of {len(raw)} bytes exceeds the {MAX_PAYLOAD}-byte limit")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise PayloadError(f"payload is not UTF-8: {exc.reason} at byte {exc.start}") from None
    decoder = json.JSONDecoder(parse_constant=_reject_constant, parse_int=_float_range_int)
    if len(raw) > FAST_DECODE:
        _yielding_scanner(decoder, max_containers)
    try:
        return decoder.decode(text)
    except json.JSONDecodeError as exc:
        raise PayloadError(f"malformed JSON: {exc.msg} at line {exc.lineno} column {exc.colno}") from None
    except RecursionError:
        raise PayloadError("malformed JSON: nested too deeply") from None
    except PayloadError:
        raise
    except ValueError as exc:  # defensive: json raises plain ValueError for a few inputs (e.g. huge integers)
        raise PayloadError(f"malformed JSON: {exc}") from None


def _yielding_scanner(decoder: json.JSONDecoder, max_containers: int) -> None:
    """Give ``decoder`` the pure-Python scanner, counting the arrays and objects it builds."""
    built = 0

    def count() -> None:
        nonlocal built
        built += 1
        if built > max_containers:
            raise PayloadError(f"payload holds more than {max_containers} arrays and objects")

    def parse_array(*args: Any, **kwargs: Any) -> Any:
        count()
        return json.decoder.JSONArray(*args, **kwargs)  # type: ignore[attr-defined]

    def parse_object(*args: Any, **kwargs: Any) -> Any:
        count()
        return json.decoder.JSONObject(*args, **kwargs)  # type: ignore[attr-defined]

    decoder.parse_array = parse_array  # type: ignore[attr-defined]
    decoder.parse_object = parse_object  # type: ignore[assignment]
    decoder.scan_once = json.scanner.py_make_scanner(decoder)  # type: ignore[attr-defined]


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
