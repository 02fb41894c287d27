"""Damiao register frames against bytes worked out by hand."""

from __future__ import annotations

import can
import pytest

from drivers.can.protocol import FrameError
from drivers.can.protocol import damiao_registers as reg


def test_register_ids() -> None:
    ids = (reg.MST_ID, reg.ESC_ID, reg.TIMEOUT, reg.CTRL_MODE, reg.PMAX, reg.VMAX, reg.TMAX)
    assert ids == (7, 8, 9, 10, 21, 22, 23)
    assert reg.is_uint32(9) and reg.is_uint32(35) and not reg.is_uint32(21) and not reg.is_uint32(0)


def test_read_request_by_hand() -> None:
    # esc_id 0x101 -> D0 = 0x01, D1 = 0x01; read 0x33; PMAX = 21 = 0x15
    msg = reg.read_request(0x101, reg.PMAX)
    assert (msg.arbitration_id, msg.is_extended_id) == (0x7FF, False)
    assert bytes(msg.data) == bytes([0x01, 0x01, 0x33, 0x15, 0, 0, 0, 0])


def test_write_requests_by_hand() -> None:
    # TIMEOUT = 200 counts (10 ms / 50 µs) as uint32 LE: C8 00 00 00
    assert reg.timeout_counts(0.010) == 200
    msg = reg.write_request(1, reg.TIMEOUT, 200)
    assert bytes(msg.data) == bytes([0x01, 0x00, 0x55, 0x09, 0xC8, 0x00, 0x00, 0x00])
    # PMAX = 12.5 as float32 = 0x41480000, LE: 00 00 48 41
    msg = reg.write_request(1, reg.PMAX, 12.5)
    assert bytes(msg.data) == bytes([0x01, 0x00, 0x55, 0x15, 0x00, 0x00, 0x48, 0x41])
    with pytest.raises(ValueError, match="uint32"):
        reg.write_request(1, reg.TIMEOUT, 1.5)
    with pytest.raises(ValueError, match="uint32"):
        reg.write_request(1, reg.MST_ID, -1)


def test_store_and_refresh_by_hand() -> None:
    assert bytes(reg.store_request(2).data) == bytes([0x02, 0x00, 0xAA, 0x01, 0, 0, 0, 0])
    assert bytes(reg.refresh_request(2).data) == bytes([0x02, 0x00, 0xCC, 0x00, 0, 0, 0, 0])


def test_register_reply_round_trip_by_hand() -> None:
    # VMAX = 30.0 as float32 = 0x41F00000 -> LE 00 00 F0 41, on MST_ID 0x11
    msg = reg.encode_register_reply(0x11, 1, reg.VMAX, 30.0)
    assert msg.arbitration_id == 0x11
    assert bytes(msg.data) == bytes([0x01, 0x00, 0x33, 0x16, 0x00, 0x00, 0xF0, 0x41])
    assert reg.decode_register_reply(msg) == (1, 22, 30.0)
    assert reg.is_register_reply(msg, 1) and not reg.is_register_reply(msg, 2)
    # uint32 register: CTRL_MODE = 1
    assert reg.decode_register_reply(reg.encode_register_reply(0x11, 1, reg.CTRL_MODE, 1)) == (1, 10, 1)


def test_bad_register_frames() -> None:
    bad_op = can.Message(arbitration_id=0x11, data=bytes([1, 0, 0xAA, 1, 0, 0, 0, 0]), is_extended_id=False)
    with pytest.raises(FrameError, match="operation 0xAA"):
        reg.decode_register_reply(bad_op)
    with pytest.raises(FrameError, match="DLC 8, got 4"):
        reg.decode_register_reply(can.Message(arbitration_id=0x11, data=bytes([1, 0, 0x33, 1]), is_extended_id=False))
    with pytest.raises(FrameError, match="0x7FF"):
        reg.decode_request(can.Message(arbitration_id=0x7FE, data=bytes(8), is_extended_id=False))
    assert reg.decode_request(reg.write_request(3, reg.TIMEOUT, 20)) == (3, 0x55, 9, bytes([20, 0, 0, 0]))
