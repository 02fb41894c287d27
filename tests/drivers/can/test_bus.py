"""drivers/can/bus.py: opening buses from config, non-blocking link, error latching, bad-frame events, bit budget."""

from __future__ import annotations

import errno
import itertools
import uuid

import can
import pytest
from pydantic import ValidationError

from drivers.can.bus import (
    ERR_BUS_OFF,
    ERR_CONTROLLER,
    BadFrames,
    BusSpec,
    CanLink,
    bits_per_second,
    frame_bits,
    open_bus,
    rtr_bits,
)
from hild.hardware import HardwareError


def channel() -> str:
    return f"test-bus-{uuid.uuid4().hex[:8]}"


class FlakyBus(can.BusABC):
    """A bus whose send can be made to fail like socketcan's (ENOBUFS, interface down) and that reports a state."""

    def __init__(self, channel: str = "", **kwargs: object) -> None:
        super().__init__(channel=channel)
        self.fail_with: can.CanError | None = None
        self.sent: list[can.Message] = []
        self.inbox: list[can.Message] = []
        self.bus_state = can.BusState.ACTIVE
        self.kwargs = kwargs
        self.recv_error: can.CanError | None = None

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        assert timeout == 0, "cycle sends must never wait"
        if self.fail_with is not None:
            raise self.fail_with
        self.sent.append(msg)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if self.recv_error is not None:
            raise self.recv_error
        return (self.inbox.pop(0) if self.inbox else None), False

    @property
    def state(self) -> can.BusState:
        return self.bus_state


@pytest.fixture
def flaky(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(can.interfaces.BACKENDS, "flaky", (__name__, "FlakyBus"))
    monkeypatch.setattr(can.util, "VALID_INTERFACES", can.util.VALID_INTERFACES | {"flaky"})


# ---- BusSpec / open_bus ------------------------------------------------------------------------------------------


def test_spec_defaults_and_name() -> None:
    spec = BusSpec(channel="can1")
    assert (spec.interface, spec.bitrate, spec.fd, spec.data_bitrate) == ("socketcan", 1_000_000, False, None)
    assert spec.name == "socketcan:can1"


@pytest.mark.parametrize(
    ("raw", "reason"),
    [
        ({"channel": "c", "data_bitrate": 5_000_000}, "needs fd"),
        ({"channel": "c", "fd": True, "bitrate": 1_000_000, "data_bitrate": 500_000}, "below the nominal"),
        ({"channel": "c", "options": {"bitrate": 5}}, "may not repeat bitrate"),
        ({"channel": "c", "bitrate": 0}, "greater than 0"),
        ({"channel": "c", "unknown": 1}, "Extra inputs"),
    ],
)
def test_spec_rejects_inconsistent_values(raw: dict, reason: str) -> None:
    with pytest.raises(ValidationError, match=reason):
        BusSpec.model_validate(raw)


def test_open_bus_passes_options_and_fd(flaky: None) -> None:
    spec = BusSpec(
        interface="flaky", channel="x", fd=True, bitrate=1_000_000, data_bitrate=5_000_000, options={"index": 3}
    )
    bus = open_bus(spec)
    try:
        assert isinstance(bus, FlakyBus)
        assert bus.kwargs == {
            "bitrate": 1_000_000,
            "receive_own_messages": False,
            "index": 3,
            "fd": True,
            "data_bitrate": 5_000_000,
        }
    finally:
        bus.shutdown()


def test_open_bus_failure_names_the_bus() -> None:
    with pytest.raises(HardwareError, match=r"cannot open CAN bus nosuch:can9"):
        open_bus(BusSpec(interface="nosuch", channel="can9"))


# ---- bit budget ---------------------------------------------------------------------------------------------------


def test_classic_frame_lengths_match_the_stuffing_formula() -> None:
    assert frame_bits(8) == 135  # 111 nominal + 24 worst-case stuff bits
    assert frame_bits(0) == rtr_bits() == 55
    assert frame_bits(4) == 47 + 32 + (34 + 32 - 1) // 4
    assert frame_bits(8, extended=True) == 67 + 64 + (54 + 64 - 1) // 4
    with pytest.raises(ValueError, match="at most 8"):
        frame_bits(9)


def test_fd_frame_with_bit_rate_switch_is_about_56_us_at_1M_5M() -> None:
    bits = frame_bits(8, fd=True, brs_ratio=5.0)
    assert 50.0 <= bits <= 57.0  # µs at 1 Mbit/s nominal
    assert frame_bits(8, fd=True, brs_ratio=1.0) > frame_bits(8)  # FD without BRS is longer than classic
    assert frame_bits(9, fd=True, brs_ratio=5.0) == frame_bits(12, fd=True, brs_ratio=5.0)  # DLC rounds up
    with pytest.raises(ValueError, match="at most 64"):
        frame_bits(65, fd=True)


def test_bits_per_second_sums_frames_and_uses_the_data_rate() -> None:
    classic = BusSpec(channel="c")
    assert bits_per_second(classic, [(8, 1000.0), (8, 2000.0)]) == 3000 * 135
    fd = BusSpec(channel="c", fd=True, data_bitrate=5_000_000)
    assert bits_per_second(fd, [(8, 1000.0)]) == pytest.approx(1000 * frame_bits(8, fd=True, brs_ratio=5.0))


# ---- CanLink on in-process virtual buses --------------------------------------------------------------------------


def test_link_sends_and_polls_without_blocking() -> None:
    ch = channel()
    link = CanLink(BusSpec(interface="virtual", channel=ch))
    link.open()
    peer = can.Bus(interface="virtual", channel=ch)
    try:
        assert link.poll() is None  # nothing waiting: returns at once
        assert link.send(link.make_message(0x12, b"\x01\x02"))
        got = peer.recv(timeout=0)
        assert got is not None and got.arbitration_id == 0x12 and bytes(got.data) == b"\x01\x02"
        peer.send(can.Message(arbitration_id=0x21, data=b"\x05", is_extended_id=False))
        msg = link.poll()
        assert msg is not None and msg.arbitration_id == 0x21
        assert link.poll() is None
        assert (link.frames_sent, link.frames_received) == (1, 1)
        assert link.problem is None
    finally:
        peer.shutdown()
        link.close()


def test_fd_messages_carry_fd_and_brs_flags_but_remote_frames_stay_classic() -> None:
    link = CanLink(BusSpec(interface="virtual", channel=channel(), fd=True, data_bitrate=5_000_000))
    msg = link.make_message(0x1, bytes(8))
    assert msg.is_fd and msg.bitrate_switch
    rtr = link.make_message(0x1, rtr=True)
    assert rtr.is_remote_frame and not rtr.is_fd


def test_error_frames_latch_bus_off_and_count_passive() -> None:
    ch = channel()
    link = CanLink(BusSpec(interface="virtual", channel=ch))
    link.open()
    peer = can.Bus(interface="virtual", channel=ch)
    try:
        peer.send(can.Message(arbitration_id=ERR_CONTROLLER, is_error_frame=True, data=bytes([0, 0x20, 0, 0])))
        peer.send(can.Message(arbitration_id=0x33, data=b"\x00", is_extended_id=False))
        msg = link.poll()  # the error frame is consumed, the data frame comes out
        assert msg is not None and msg.arbitration_id == 0x33
        assert (link.error_frames, link.passive_reports, link.problem) == (1, 1, None)
        peer.send(can.Message(arbitration_id=ERR_BUS_OFF, is_error_frame=True, data=bytes(8)))
        assert link.poll() is None
        assert link.problem == "bus off"
        assert link.check_state() == "bus off"
        link.clear()
        assert link.check_state() is None
    finally:
        peer.shutdown()
        link.close()


def test_receive_feeds_data_frames_up_to_the_budget_and_consumes_error_frames(flaky: None) -> None:
    link = CanLink(BusSpec(interface="flaky", channel="x"))
    link.open()
    bus = link.bus
    assert isinstance(bus, FlakyBus)
    data = [can.Message(arbitration_id=0x10 + i, data=bytes([i]), is_extended_id=False) for i in range(5)]
    passive = can.Message(arbitration_id=ERR_CONTROLLER, is_error_frame=True, data=bytes([0, 0x20, 0, 0]))
    bus.inbox = [data[0], passive, data[1], data[2], data[3], data[4]]
    got: list[can.Message] = []
    link.receive(got.append, 3)  # the error frame is consumed on the way and does not count against the budget
    assert got == data[:3] and bus.inbox == data[3:]
    assert (link.frames_received, link.error_frames, link.passive_reports) == (3, 1, 1)
    link.receive(got.append, 3)  # the rest, then nothing waiting: returns at once
    assert got == data and (link.frames_received, link.problem) == (5, None)
    bus.recv_error = can.CanOperationError("Network is down")
    link.receive(got.append, 3)
    assert link.problem == "bus error: receive failed: Network is down" and len(got) == 5
    link.close()
    link.receive(got.append, 3)  # a closed link has nothing to give
    assert len(got) == 5


def test_full_send_queue_latches_only_after_consecutive_cycles(flaky: None) -> None:
    link = CanLink(BusSpec(interface="flaky", channel="x"), send_failure_cycles=3)
    link.open()
    bus = link.bus
    assert isinstance(bus, FlakyBus)
    msg = link.make_message(0x1, bytes(8))
    bus.fail_with = can.CanOperationError("Failed to transmit: No buffer space available", errno.ENOBUFS)
    for _ in range(2):
        assert not link.send(msg)
        link.end_cycle()
    assert link.problem is None
    bus.fail_with = None
    assert link.send(msg)
    link.end_cycle()  # a good cycle resets the run
    bus.fail_with = can.CanOperationError("Failed to transmit: No buffer space available", errno.ENOBUFS)
    for _ in range(3):
        link.send(msg)
        link.end_cycle()
    assert link.problem is not None and link.problem.startswith("send buffer full for 3 cycles")
    assert link.send_failures == 5


def test_other_send_errors_latch_at_once(flaky: None) -> None:
    link = CanLink(BusSpec(interface="flaky", channel="x"))
    link.open()
    assert isinstance(link.bus, FlakyBus)
    link.bus.fail_with = can.CanOperationError("Failed to transmit: Network is down", errno.ENETDOWN)
    assert not link.send(link.make_message(0x1, bytes(8)))
    assert link.problem == "bus error: send failed: Failed to transmit: Network is down [Error Code 100]"


def test_backend_bus_state_error_reads_as_bus_off(flaky: None) -> None:
    link = CanLink(BusSpec(interface="flaky", channel="x"))
    link.open()
    assert link.check_state() is None
    assert isinstance(link.bus, FlakyBus)
    link.bus.bus_state = can.BusState.ERROR
    assert link.check_state() == "bus off"


def test_reopen_gives_a_fresh_bus_and_clears_the_latch(flaky: None) -> None:
    link = CanLink(BusSpec(interface="flaky", channel="x"))
    link.open()
    first = link.bus
    link.latch("bus off")
    link.reopen()
    assert link.bus is not first and link.problem is None


def test_collect_pumps_until_done_or_timeout() -> None:
    ch = channel()
    link = CanLink(BusSpec(interface="virtual", channel=ch))
    link.open()
    peer = can.Bus(interface="virtual", channel=ch)
    seen: list[int] = []
    ticks = itertools.count()

    def serve_while_waiting() -> None:  # an in-process "device" answering on the third call
        if next(ticks) == 2:
            peer.send(can.Message(arbitration_id=0x40, data=b"", is_extended_id=False))

    try:
        link.serve_while_waiting = serve_while_waiting
        assert link.collect(lambda m: seen.append(m.arbitration_id), lambda: bool(seen), timeout=1.0)
        assert seen == [0x40]
        assert not link.collect(lambda m: None, lambda: False, timeout=0.01)
    finally:
        peer.shutdown()
        link.close()


def test_send_wait_retries_a_full_queue_then_gives_up(flaky: None) -> None:
    link = CanLink(BusSpec(interface="flaky", channel="x"))
    link.open()
    assert isinstance(link.bus, FlakyBus)
    link.bus.fail_with = can.CanOperationError("No buffer space available", errno.ENOBUFS)
    with pytest.raises(HardwareError, match="send failed"):
        link.send_wait(link.make_message(0x1, bytes(8)), timeout=0.005)
    link.bus.fail_with = None
    link.send_wait(link.make_message(0x1, bytes(8)))
    assert len(link.bus.sent) == 1


# ---- BadFrames ----------------------------------------------------------------------------------------------------


def test_bad_frames_are_summarised_at_most_once_per_interval() -> None:
    events: list[tuple[str, str]] = []
    bad = BadFrames(lambda level, msg: events.append((level, msg)), "left", interval=1.0)
    bad.report(0.0)
    assert events == []  # nothing to say
    for _ in range(5):
        bad.note("unknown id", 0x123)
    bad.note("wrong length", 0x11)
    bad.report(0.0)
    assert events == [("warning", "ignored CAN frames: 5 unknown id (last id 0x123); 1 wrong length (last id 0x11)")]
    bad.note("unknown id", 0x124)
    bad.report(0.5)  # within the interval: held back, not lost
    assert len(events) == 1
    bad.report(1.0)
    assert events[-1] == ("warning", "ignored CAN frames: 1 unknown id (last id 0x124)")
    assert bad.totals == {"unknown id": 6, "wrong length": 1} and bad.total == 7
