"""In-process checks of the fixes the bad-input suite led to (no daemon: each runs in milliseconds)."""

from __future__ import annotations

import asyncio
import json
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest

from hild.action import GoalRejected
from hild.api.codec import FAST_DECODE, GOAL_LIMITS, MAX_CONTAINERS, MAX_ELEMENTS, MAX_PAYLOAD, PayloadError, decode
from hild.api.keys import Keys
from hild.api.ports import ControllerPorts, Counters, InputSlot
from hild.api.queries import BUSY, BUSY_LARGE, MAX_IN_FLIGHT, MAX_LARGE_IN_FLIGHT, Admitted, QueryAdmission, clip
from hild.controllers.trajectory_goals import GoalContext, parse_goal
from hild.motion.limits import KinematicLimits


# ---- codec ---------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("raw", [b"1" * 400, b"-" + b"9" * 309, b"[" + b"7" * 5000 + b"]", b"1" * 5000])
def test_integers_beyond_a_float_are_a_payload_error(raw: bytes) -> None:
    with pytest.raises(PayloadError, match="out of range; send finite numbers only"):
        decode(raw)


def test_the_largest_integers_that_fit_a_float_still_decode() -> None:
    assert decode(b"-" + b"9" * 308) == -int("9" * 308)
    assert decode(b"1e999") == float("inf")  # documented: consumers refuse it as non-finite


def test_large_payloads_stop_at_the_container_budget() -> None:
    raw = b"[" + b",".join([b"[]"] * 2000) + b"]"
    assert len(raw) > FAST_DECODE
    with pytest.raises(PayloadError, match=f"more than {MAX_CONTAINERS} arrays and objects"):
        decode(raw)
    assert len(decode(raw, max_containers=2001)) == 2000
    flat = json.dumps(list(range(100_000))).encode()  # one container of many numbers: a goal's caps allow it
    assert len(flat) > FAST_DECODE and decode(flat, GOAL_LIMITS)[-1] == 99_999
    with pytest.raises(PayloadError, match=f"more than {MAX_ELEMENTS} array elements"):  # a request's do not
        decode(flat)


@pytest.mark.parametrize("raw", [b"[" * 100_000, b'{"a":' * 3000 + b"1" + b"}" * 3000, b"[" * 1500 + b"]" * 1500])
def test_deep_nesting_is_malformed_on_both_scanners(raw: bytes) -> None:
    with pytest.raises(PayloadError, match="malformed JSON: nested too deeply"):
        decode(raw)


def test_both_scanners_agree() -> None:
    body = {"positions": [0.1, -2, 3e5], "nested": {"a": [True, None, "é\\ud800"]}, "n": -12}
    small = json.dumps(body).encode()
    large = json.dumps({**body, "pad": "x" * FAST_DECODE}).encode()
    assert decode(small) == body and {k: v for k, v in decode(large).items() if k != "pad"} == body
    for raw in (b"NaN", b"[1, 2,] " + b" " * FAST_DECODE, b"{} x" + b" " * FAST_DECODE):
        with pytest.raises(PayloadError):
            decode(raw)


def test_clip() -> None:
    assert clip("short") == "short"
    assert clip("x" * 600) == "x" * 500 + "… (100 more characters)"


# ---- admission -------------------------------------------------------------------------------------------------------
@dataclass
class FakePayload:
    data: bytes

    def __len__(self) -> int:
        return len(self.data)

    def to_bytes(self) -> bytes:
        return self.data


@dataclass
class FakeQuery:
    payload: FakePayload | None


def test_the_gate_caps_small_and_large_requests_separately() -> None:
    gate = QueryAdmission()
    large = [gate.admit(FakeQuery(FakePayload(b" " * (FAST_DECODE + 1)))) for _ in range(MAX_LARGE_IN_FLIGHT + 1)]
    assert all(isinstance(a, Admitted) for a in large[:-1]) and large[-1] is BUSY_LARGE
    small = [gate.admit(FakeQuery(None)) for _ in range(MAX_IN_FLIGHT + 1)]
    assert all(isinstance(a, Admitted) for a in small[:-1]) and small[-1] is BUSY  # large ones took no small place
    assert gate.admit(FakeQuery(FakePayload(b" " * (MAX_PAYLOAD + 1)))) == {
        "ok": False,
        "error": f"payload of {MAX_PAYLOAD + 1} bytes exceeds the {MAX_PAYLOAD}-byte limit",
    }
    first = large[0]
    assert isinstance(first, Admitted)
    first.release()
    assert isinstance(gate.admit(FakeQuery(FakePayload(b" " * (FAST_DECODE + 1)))), Admitted)
    assert len(gate) == MAX_IN_FLIGHT + MAX_LARGE_IN_FLIGHT
    assert gate.small.refused == 1 and gate.large.refused == 1


# ---- streamed inputs ---------------------------------------------------------------------------------------------
class Events:
    def __init__(self) -> None:
        self.emitted: list[tuple[str, str, str]] = []

    def emit(self, level: str, source: str, message: str) -> None:
        self.emitted.append((level, source, message))


@dataclass
class FakeEngine:
    events: Events


@dataclass
class FakeSample:
    payload: FakePayload


class FakeSubscriber:
    """A RingChannel subscriber: ``try_recv`` hands out what Zenoh queued, oldest first, then None."""

    def __init__(self) -> None:
        self.queued: list[FakeSample] = []

    def put(self, raw: bytes) -> None:
        self.queued.append(FakeSample(FakePayload(raw)))

    def try_recv(self) -> FakeSample | None:
        return self.queued.pop(0) if self.queued else None


def ports_with_inputs(loop: asyncio.AbstractEventLoop) -> tuple[ControllerPorts, FakeSubscriber, list[Any], Counters]:
    counters = Counters()
    ports = ControllerPorts(None, FakeEngine(Events()), Keys("r"), loop, counters)  # type: ignore[arg-type]
    accepted: list[Any] = []
    subscriber = FakeSubscriber()
    ports._taken_inputs = (InputSlot("hild/r/ctrl/fwd/commands", "fwd", accepted.append, subscriber),)
    return ports, subscriber, accepted, counters


def test_a_burst_on_one_input_keeps_only_the_newest_sample() -> None:
    """1000 samples queued between two cycles: take_inputs hands over the newest; the rest are superseded unread."""
    loop = asyncio.new_event_loop()  # never run: small samples are handed over by the cycle's take_inputs
    ports, subscriber, accepted, counters = ports_with_inputs(loop)
    for k in range(1000):
        subscriber.put(json.dumps({"values": [k]}).encode())
    ports.take_inputs()
    ports.take_inputs()  # nothing new: nothing handed over twice
    loop.close()
    assert accepted == [{"values": [999]}]
    assert (counters.commands, counters.superseded, counters.dropped, counters.accepted) == (1000, 999, 999, 1)


def test_a_large_sample_goes_to_the_loop_and_never_overtakes_a_newer_one() -> None:
    loop = asyncio.new_event_loop()
    ports, subscriber, accepted, counters = ports_with_inputs(loop)
    large = json.dumps({"values": [1.0], "pad": " " * FAST_DECODE}).encode()
    try:
        subscriber.put(large)
        ports.take_inputs()  # too large for the cycle: handed to the loop, which has not run yet
        subscriber.put(b'{"values": [2.0]}')
        ports.take_inputs()  # the newer, small one is handed over at once
        loop.run_until_complete(asyncio.sleep(0.2))  # the loop decodes the large one: it is no longer the newest
        assert accepted == [{"values": [2.0]}]
        assert counters.loop.superseded == 1 and counters.accepted == 1
        subscriber.put(large)
        ports.take_inputs()
        loop.run_until_complete(asyncio.sleep(0.2))  # alone, it is handed over
        assert accepted[-1]["values"] == [1.0] and counters.accepted == 2 and counters.commands == 3
    finally:
        loop.run_until_complete(asyncio.sleep(0))
        loop.close()


def test_an_oversized_sample_is_refused_unread_by_take_inputs() -> None:
    loop = asyncio.new_event_loop()
    ports, subscriber, accepted, counters = ports_with_inputs(loop)
    subscriber.put(b" " * (MAX_PAYLOAD + 1))
    ports.take_inputs()
    loop.close()
    assert accepted == [] and counters.rejected == 1
    (event,) = ports.engine.events.emitted  # type: ignore[attr-defined]
    assert event[0] == "warning" and f"exceeds the {MAX_PAYLOAD}-byte limit" in event[2]


# ---- goals -------------------------------------------------------------------------------------------------------
def goal_context() -> GoalContext:
    """Two joints ``a`` and ``b`` with unit limits: enough for parsing goals without a robot."""
    ones = np.ones(2)
    return GoalContext.unchecked(("a", "b"), 1.0, KinematicLimits(ones, ones, ones))


def test_repeated_joint_names_are_counted_in_linear_time() -> None:
    ctx = goal_context()
    start = time.monotonic()
    with pytest.raises(GoalRejected, match=r"joints listed more than once: \['a'\]"):
        parse_goal({"joint_names": ["a"] * 250_000, "positions": []}, ctx)
    assert time.monotonic() - start < 1.0  # list.count per name took ~60 s
    with pytest.raises(GoalRejected) as info:
        parse_goal({"joint_names": ["a", "b"] + [f"z{k}" for k in range(10_000)], "positions": []}, ctx)
    assert "and 9992 more" in str(info.value) and len(str(info.value)) < 300
