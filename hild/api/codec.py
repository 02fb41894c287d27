"""JSON on the wire: strict in, always-valid out.

Incoming payloads are size-checked before they are copied, must be UTF-8 JSON, and may not use the ``NaN`` /
``Infinity`` literals Python's json accepts by default (other JSON parsers reject them, and a NaN command must
never reach a controller). Integers a double cannot hold (``1`` followed by 400 zeros) are refused too: no float
conversion downstream survives them. ``1e999`` still decodes to ``inf``, which every consumer refuses as
non-finite. Outgoing messages never contain non-finite numbers: a non-finite float becomes ``null``.

json's C scanner holds the GIL for its whole run (about 0.1 ms per KiB of small containers): 100 ms on a 1 MiB
payload, during which no other thread of the process runs (Zenoh's callbacks, the asyncio loop, and in the
in-process case the cycle thread). Payloads above ``FAST_DECODE`` bytes are therefore parsed by the pure-Python
scanner: slower, but it lets other threads in every switch interval. Callers decode those off the event loop.
That scanner counts as it goes and stops at the first container, element or level beyond the caller's
:class:`Limits` (a 1 MiB array of 524 000 numbers took it 0.6 s to build in full; it now stops at the 4 097th).
Below ``FAST_DECODE`` a payload cannot hold enough elements or containers to matter; its depth is checked after the
C scanner, so both scanners refuse the same nesting with the same words.
"""

from __future__ import annotations

import json
import json.scanner
import math
import sys
from dataclasses import dataclass, replace
from typing import Any

MAX_PAYLOAD = 1 << 20  # bytes; anything larger is refused before it is decoded
FAST_DECODE = 4096  # bytes; up to this size the C scanner's GIL hold (≤ ~0.4 ms) is harmless
MAX_CONTAINERS = 1024  # arrays + objects in a request or command: a few are ever needed
MAX_ELEMENTS = 4096  # array elements + object members in a request or command (256 names in two lists: 512)
GOAL_CONTAINERS = 65_536  # in a goal: 10 000 points with velocities, accelerations and a {sec, nanosec} time each
GOAL_ELEMENTS = 320_000  # in a goal: 10 000 points of 8 joints with velocities and accelerations (31 each)
MAX_DEPTH = 32  # levels of nesting; the deepest legitimate payload (a goal's time_from_start) has 5


@dataclass(frozen=True, slots=True)
class Limits:
    """What one payload may hold, counted while it is decoded."""

    containers: int  # arrays + objects
    elements: int  # array elements + object members, at every level
    depth: int  # levels of nesting


REQUEST_LIMITS = Limits(MAX_CONTAINERS, MAX_ELEMENTS, MAX_DEPTH)  # service requests, commands, cancel and result
GOAL_LIMITS = Limits(GOAL_CONTAINERS, GOAL_ELEMENTS, MAX_DEPTH)


class PayloadError(ValueError):
    """The payload cannot be decoded; the message says why, for the sender."""


def _reject_constant(name: str) -> Any:
    raise PayloadError(f"{name} is not valid JSON; send finite numbers only")


_MAX_INT_DIGITS = len(str(int(sys.float_info.max)))  # 309: longer integers cannot be a float


def _float_range_int(text: str) -> int:
    digits = len(text) - text.startswith("-")
    value = int(text) if digits <= _MAX_INT_DIGITS else None
    if value is None or abs(value) > sys.float_info.max:
        raise PayloadError(f"integer of {digits} digits is out of range; send finite numbers only")
    return value


def _too_deep(depth: int) -> PayloadError:
    return PayloadError(f"malformed JSON: nested too deeply (more than {depth} levels)")


def decode(raw: bytes, limits: Limits = REQUEST_LIMITS, *, max_containers: int | None = None) -> Any:
    """The JSON value of ``raw``, or PayloadError saying why not.

    Above ``FAST_DECODE`` bytes, parsing stops at the first array or object beyond ``limits.containers``, element
    beyond ``limits.elements`` or level beyond ``limits.depth``: building and freeing hundreds of thousands of
    values holds the GIL in long passes of the garbage collector. (Below it, a payload cannot hold enough of them
    to matter; only its depth is checked, after decoding.)
    """
    if max_containers is not None:
        limits = replace(limits, containers=max_containers)
    if len(raw) > MAX_PAYLOAD:
        raise PayloadError(f"payload of {len(raw)} bytes exceeds the {MAX_PAYLOAD}-byte limit")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise PayloadError(f"payload is not UTF-8: {exc.reason} at byte {exc.start}") from None
    decoder = json.JSONDecoder(parse_constant=_reject_constant, parse_int=_float_range_int)
    large = len(raw) > FAST_DECODE
    if large:
        _capped_scanner(decoder, limits)
    try:
        value = decoder.decode(text)
    except json.JSONDecodeError as exc:
        raise PayloadError(f"malformed JSON: {exc.msg} at line {exc.lineno} column {exc.colno}") from None
    except RecursionError:
        raise _too_deep(limits.depth) from None
    except PayloadError:
        raise
    except ValueError as exc:  # defensive: json raises plain ValueError for a few inputs (e.g. huge integers)
        raise PayloadError(f"malformed JSON: {exc}") from None
    if not large and raw.count(b"[") + raw.count(b"{") > limits.depth and _deeper(value, limits.depth):
        raise _too_deep(limits.depth)
    return value


def _deeper(value: Any, depth: int) -> bool:
    """Whether ``value`` nests more than ``depth`` levels (breadth first: no recursion)."""
    level, levels = [value], 0
    while level := [v for v in level if isinstance(v, list | dict)]:
        levels += 1
        if levels > depth:
            return True
        level = [c for v in level for c in (v if isinstance(v, list) else v.values())]
    return False


def _capped_scanner(decoder: json.JSONDecoder, limits: Limits) -> None:
    """Give ``decoder`` the pure-Python scanner, counting containers, elements and depth as it builds them."""
    containers = elements = depth = 0
    scan: Any = None  # the scanner's own scan function, which it hands to parse_array and parse_object

    def counted(string: str, idx: int) -> Any:  # scans one array element or object member's value
        nonlocal elements
        elements += 1
        if elements > limits.elements:
            raise PayloadError(f"payload holds more than {limits.elements} array elements and object members")
        return scan(string, idx)

    def enter(scan_once: Any) -> None:
        nonlocal containers, depth, scan
        scan = scan_once
        containers += 1
        if containers > limits.containers:
            raise PayloadError(f"payload holds more than {limits.containers} arrays and objects")
        depth += 1
        if depth > limits.depth:
            raise _too_deep(limits.depth)

    def parse_array(s_and_end: Any, scan_once: Any) -> Any:
        nonlocal depth
        enter(scan_once)
        try:
            return json.decoder.JSONArray(s_and_end, counted)  # type: ignore[attr-defined]
        finally:
            depth -= 1

    def parse_object(s_and_end: Any, strict: bool, scan_once: Any, *args: Any) -> Any:
        nonlocal depth
        enter(scan_once)
        try:
            return json.decoder.JSONObject(s_and_end, strict, counted, *args)  # type: ignore[attr-defined]
        finally:
            depth -= 1

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
