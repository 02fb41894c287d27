"""In-process checks of the fixes the bad-input suite led to (no daemon: each runs in milliseconds)."""

from __future__ import annotations

import asyncio
import json
import threading
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest

from hild.action import GoalRejected
from hild.api.codec import FAST_DECODE, MAX_CONTAINERS, MAX_PAYLOAD, PayloadError, decode
from hild.api.keys import Keys
from hild.api.ports import ControllerPorts, Counters, InputSlot
from hild.api.queries import BUSY, BUSY_LARGE, MAX_IN_FLIGHT, MAX_LARGE_IN_FLIGHT, Admitted, Gate, clip
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
    flat = json.dumps(list(range(100_000))).encode()  # one container, many numbers: fine
    assert len(flat) > FAST_DECODE and decode(flat)[-1] == 99_999


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
    gate = Gate()
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


def test_a_burst_on_one_input_keeps_only_the_newest_sample() -> None:
    """While one Zenoh thread delivers a sample (its validation is slow), 1000 more arrive on another: the slot
    holds the newest, the rest are superseded unread, and the deliverer hands over the newest next."""
    loop = asyncio.new_event_loop()  # never run: small samples are delivered on the Zenoh thread
    counters = Counters()
    ports = ControllerPorts(None, FakeEngine(Events()), Keys("r"), loop, counters)  # type: ignore[arg-type]
    accepted: list[Any] = []
    delivering, release = threading.Event(), threading.Event()

    def accept(payload: Any) -> None:
        accepted.append(payload)
        if len(accepted) == 1:
            delivering.set()
            assert release.wait(5.0)

    def sample(k: int) -> FakeSample:
        return FakeSample(FakePayload(json.dumps({"values": [k]}).encode()))

    slot = InputSlot("hild/r/ctrl/fwd/commands", "fwd", accept)  # the handler holds it weakly
    on_sample = ports._sample_handler(slot)
    first = threading.Thread(target=on_sample, args=(sample(-1),))
    first.start()
    try:
        assert delivering.wait(5.0)
        for k in range(1000):
            on_sample(sample(k))  # returns at once: the slot has its deliverer
    finally:
        release.set()
        first.join(5.0)
        loop.close()
    assert accepted == [{"values": [-1]}, {"values": [999]}]
    assert (counters.commands, counters.superseded, counters.dropped, counters.accepted) == (1001, 999, 999, 2)


# ---- goals -------------------------------------------------------------------------------------------------------
def test_repeated_joint_names_are_counted_in_linear_time() -> None:
    ones = np.ones(2)
    ctx = GoalContext(
        joints=("a", "b"),
        soft_lower=-ones,
        soft_upper=ones,
        limits=KinematicLimits(ones, ones, ones),
        allow_partial=False,
        path_position=0 * ones,
        path_velocity=0 * ones,
        goal_position=0 * ones,
        goal_velocity=0 * ones,
        goal_time=1.0,
        start_tolerance=0.01,
    )
    start = time.monotonic()
    with pytest.raises(GoalRejected, match=r"joints listed more than once: \['a'\]"):
        parse_goal({"joint_names": ["a"] * 250_000, "positions": []}, ctx)
    assert time.monotonic() - start < 1.0  # list.count per name took ~60 s
    with pytest.raises(GoalRejected) as info:
        parse_goal({"joint_names": ["a", "b"] + [f"z{k}" for k in range(10_000)], "positions": []}, ctx)
    assert "and 9992 more" in str(info.value) and len(str(info.value)) < 300
