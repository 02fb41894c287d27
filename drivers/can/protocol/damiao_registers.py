"""Damiao register protocol: read, write, store and refresh frames on id 0x7FF, replies on MST_ID.

Request layout: D0–D1 = target ESC_ID (little-endian), D2 = operation, D3 = register id, D4–D7 = value (LE).
The drive answers a read or write with the same layout carrying the register's value. Registers 7–10, 13–16 and
35–36 hold uint32, all others float32.
"""

from __future__ import annotations

import struct

import can

from drivers.can.protocol.errors import FrameError

REGISTER_REQUEST_ID = 0x7FF

OP_READ = 0x33
OP_WRITE = 0x55
OP_STORE = 0xAA
OP_REFRESH = 0xCC

UV_VALUE = 0
KT_VALUE = 1
OT_VALUE = 2
OC_VALUE = 3
ACC = 4
DEC = 5
MAX_SPD = 6
MST_ID = 7
ESC_ID = 8
TIMEOUT = 9
CTRL_MODE = 10
DAMP = 11
INERTIA = 12
HW_VER = 13
SW_VER = 14
SN = 15
NPP = 16
GR = 20
PMAX = 21
VMAX = 22
TMAX = 23
KP_ASR = 25
KI_ASR = 26
KP_APR = 27
KI_APR = 28
OV_VALUE = 29
CAN_BR = 35
SUB_VER = 36
P_M = 80
XOUT = 81

TIMEOUT_UNIT_S = 50e-6
"""One TIMEOUT register count is 50 µs."""

CTRL_MODE_MIT = 1
CTRL_MODE_POS_VEL = 2
CTRL_MODE_VEL = 3
CTRL_MODE_FORCE_POS = 4

_UINT32_REGISTERS = frozenset({7, 8, 9, 10, 13, 14, 15, 16, 35, 36})


def is_uint32(rid: int) -> bool:
    return rid in _UINT32_REGISTERS


def timeout_counts(seconds: float) -> int:
    """The TIMEOUT register value for a watchdog of `seconds` (0 disables it)."""
    if seconds < 0:
        raise ValueError("timeout must not be negative")
    return round(seconds / TIMEOUT_UNIT_S)


def pack_value(rid: int, value: float) -> bytes:
    """The 4 little-endian value bytes of register `rid`."""
    if is_uint32(rid):
        integer = int(value)
        if integer != value or not 0 <= integer <= 0xFFFF_FFFF:
            raise ValueError(f"register {rid} holds a uint32, got {value!r}")
        return struct.pack("<I", integer)
    return struct.pack("<f", value)


def unpack_value(rid: int, raw: bytes | bytearray) -> float:
    """The value of register `rid` from its 4 little-endian bytes (int for uint32 registers)."""
    return struct.unpack("<I" if is_uint32(rid) else "<f", raw)[0]


def _request(esc_id: int, op: int, rid: int, value: bytes = b"\x00\x00\x00\x00") -> can.Message:
    if not 0 <= esc_id <= 0x7FF:
        raise ValueError(f"ESC_ID must be a standard 11-bit id, got {esc_id}")
    if not 0 <= rid <= 0xFF:
        raise ValueError(f"register id must fit a byte, got {rid}")
    data = bytes([esc_id & 0xFF, esc_id >> 8, op, rid]) + value
    return can.Message(arbitration_id=REGISTER_REQUEST_ID, data=data, is_extended_id=False)


def read_request(esc_id: int, rid: int) -> can.Message:
    return _request(esc_id, OP_READ, rid)


def write_request(esc_id: int, rid: int, value: float) -> can.Message:
    """Write to RAM; lost at power-off unless followed by `store_request`."""
    return _request(esc_id, OP_WRITE, rid, pack_value(rid, value))


def store_request(esc_id: int) -> can.Message:
    """Persist all registers to flash (wears the flash; do it rarely)."""
    return _request(esc_id, OP_STORE, 0x01)


def refresh_request(esc_id: int) -> can.Message:
    """Ask for one feedback frame without commanding anything."""
    return _request(esc_id, OP_REFRESH, 0x00)


def decode_request(msg: can.Message) -> tuple[int, int, int, bytes]:
    """(esc_id, op, rid, value bytes) of a 0x7FF request (emulator side)."""
    if msg.arbitration_id != REGISTER_REQUEST_ID or msg.is_extended_id or msg.is_remote_frame:
        raise FrameError(
            f"damiao register request must be a standard data frame on 0x7FF, got 0x{msg.arbitration_id:X}"
        )
    data = msg.data
    if len(data) != 8:
        raise FrameError(f"damiao register request needs DLC 8, got {len(data)}")
    return data[0] | data[1] << 8, data[2], data[3], bytes(data[4:8])


def is_register_reply(msg: can.Message, esc_id: int) -> bool:
    """True when a frame on MST_ID looks like a register reply for `esc_id` rather than feedback.

    Both arrive on MST_ID; a register reply starts with the ESC_ID bytes and a read/write operation code.
    """
    data = msg.data
    return (
        len(data) == 8
        and data[0] == esc_id & 0xFF
        and data[1] == esc_id >> 8
        and data[2] in (OP_READ, OP_WRITE)
        and not msg.is_remote_frame
    )


def decode_register_reply(msg: can.Message) -> tuple[int, int, float]:
    """(esc_id, rid, value) of a read or write reply."""
    if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
        raise FrameError("damiao register reply must be a standard data frame")
    data = msg.data
    if len(data) != 8:
        raise FrameError(f"damiao register reply needs DLC 8, got {len(data)}")
    if data[2] not in (OP_READ, OP_WRITE):
        raise FrameError(f"damiao register reply has operation 0x{data[2]:02X}, expected 0x33 or 0x55")
    rid = data[3]
    return data[0] | data[1] << 8, rid, unpack_value(rid, data[4:8])


def encode_register_reply(master_id: int, esc_id: int, rid: int, value: float, *, op: int = OP_READ) -> can.Message:
    """The drive's answer to a read (op 0x33) or write (op 0x55), sent on MST_ID (emulator side)."""
    data = bytes([esc_id & 0xFF, esc_id >> 8, op, rid]) + pack_value(rid, value)
    return can.Message(arbitration_id=master_id, data=data, is_extended_id=False)
