"""Literal wire vectors: frames the hand-written codecs built before the message table and the shared reply decoder
replaced them, kept so that a refactoring of a codec cannot change a byte on the bus unnoticed.

Every vector was printed by the old functions (ODrive `encode_*`/`decode_*`, the MIT flavours' `encode_reply`,
`decode_reply` and `special`); the tests only feed them to the codecs of today.
"""

from __future__ import annotations

from typing import Any

import can
import pytest

from drivers.can.protocol import FrameError
from drivers.can.protocol import odrive as od
from drivers.can.protocol.flavours import FLAVOURS
from drivers.can.protocol.mit import MitRanges

NODE = 5

ODRIVE_FRAMES: list[tuple[str, tuple[Any, ...], int, str, Any]] = [
    # (message, encode arguments after the node, arbitration id, data, what decode returns for that data)
    ("heartbeat", (od.Heartbeat(0x0100_0040, 8, 3, True),), 0x0A1, "4000000108030100", (16777280, 8, 3, True)),
    ("heartbeat", (od.Heartbeat(0xFFFF_FFFF, 1, 0, False),), 0x0A1, "ffffffff01000000", (4294967295, 1, 0, False)),
    ("encoder_estimates", (12.375, -0.0625), 0x0A9, "00004641000080bd", (12.375, -0.0625)),
    ("encoder_estimates", (-1e6, 3.0), 0x0A9, "002474c900004040", (-1000000.0, 3.0)),
    ("set_axis_state", (8,), 0x0A7, "08000000", 8),
    ("set_controller_mode", (2, 5), 0x0AB, "0200000005000000", (2, 5)),
    ("set_input_pos", (-2.5, 1.234, -0.5), 0x0AC, "000020c0d2040cfe", (-2.5, 1.234, -0.5)),
    ("set_input_pos", (0.1, 40.0, -40.0), 0x0AC, "cdcccc3dff7f0080", (0.10000000149011612, 32.767, -32.768)),
    ("set_input_pos", (7.0, 0.0004, -0.0006), 0x0AC, "0000e0400000ffff", (7.0, 0.0, -0.001)),
    ("set_input_pos", (7.0,), 0x0AC, "0000e04000000000", (7.0, 0.0, 0.0)),
    ("set_input_vel", (-3.5, 0.75), 0x0AD, "000060c00000403f", (-3.5, 0.75)),
    ("set_input_vel", (1.5,), 0x0AD, "0000c03f00000000", (1.5, 0.0)),
    ("set_input_torque", (0.125,), 0x0AE, "0000003e", 0.125),
    ("set_absolute_position", (-4.25,), 0x0B9, "000088c0", -4.25),
    ("clear_errors", (), 0x0B8, "00", False),
    ("clear_errors", (True,), 0x0B8, "01", True),
    ("reboot", (), 0x0B6, "00", 0),
    ("reboot", (od.RebootAction.ENTER_DFU,), 0x0B6, "03", 3),
    ("estop", (), 0x0A2, "", None),
    ("temperature", (41.5, 36.25), 0x0B5, "0000264200001142", (41.5, 36.25)),
    ("error", (0x0400_0010, 0x2000), 0x0A3, "1000000400200000", (67108880, 8192)),
    ("bus_voltage_current", (24.5, -1.75), 0x0B7, "0000c4410000e0bf", (24.5, -1.75)),
]

ODRIVE_DECODED: list[tuple[str, str, Any]] = [
    ("heartbeat", "0100000008000200", (1, 8, 0, False)),  # only bit 0 of the flags byte is trajectory_done
    ("heartbeat", "0000000001040309", (0, 1, 4, True)),
    ("set_input_pos", "0000803f0080ff7f", (1.0, -32.768, 32.767)),
    ("clear_errors", "", False),
    ("clear_errors", "07", True),
    ("reboot", "", od.RebootAction.REBOOT),
    ("reboot", "02", 2),
]

ODRIVE_ERRORS: list[tuple[str, str, str]] = [
    ("heartbeat", "00000000000000", "odrive heartbeat needs 8 data bytes, got 7"),
    ("encoder_estimates", "000000000000000000", "odrive encoder estimates needs 8 data bytes, got 9"),
    ("set_axis_state", "0000000000000000", "odrive Set_Axis_State needs 4 data bytes, got 8"),
    ("set_input_pos", "00000000", "odrive Set_Input_Pos needs 8 data bytes, got 4"),
    ("clear_errors", "0000", "odrive Clear_Errors carries at most 1 byte, got 2"),
    ("reboot", "000000", "odrive Reboot carries at most 1 byte, got 3"),
    ("temperature", "", "odrive Get_Temperature needs 8 data bytes, got 0"),
    ("set_input_torque", "0000000000000000", "odrive Set_Input_Torque needs 4 data bytes, got 8"),
]


@pytest.mark.parametrize(("message", "args", "arbitration_id", "data", "decoded"), ODRIVE_FRAMES)
def test_odrive_frames_keep_their_bytes(
    message: str, args: tuple[Any, ...], arbitration_id: int, data: str, decoded: Any
) -> None:
    msg = getattr(od, f"encode_{message}")(NODE, *args)
    assert (msg.arbitration_id, bytes(msg.data).hex(), msg.is_extended_id, msg.is_remote_frame) == (
        arbitration_id,
        data,
        False,
        False,
    )
    if decoded is not None:
        assert getattr(od, f"decode_{message}")(msg.data) == decoded


@pytest.mark.parametrize(("message", "data", "decoded"), ODRIVE_DECODED)
def test_odrive_decoders_keep_their_values(message: str, data: str, decoded: Any) -> None:
    assert getattr(od, f"decode_{message}")(bytes.fromhex(data)) == decoded


@pytest.mark.parametrize(("message", "data", "reason"), ODRIVE_ERRORS)
def test_odrive_decoders_keep_their_reasons(message: str, data: str, reason: str) -> None:
    with pytest.raises(FrameError) as caught:
        getattr(od, f"decode_{message}")(bytes.fromhex(data))
    assert str(caught.value) == reason


# ---- MIT flavours ------------------------------------------------------------------------------------------------

RANGES = {
    "damiao": MitRanges(12.5, 30.0, 10.0),
    "tmotor": MitRanges(12.5, 50.0, 18.0),
    "myactuator": MitRanges(12.5, 45.0, 24.0),
}

MIT_REPLIES: list[tuple[Any, ...]] = [
    # flavour, motor, master, p, v, t, enabled, fault, t_mos, t_rotor, short → arbitration id, data, and
    # decode_reply's (position, velocity, torque, enabled, fault, temperature_mos, temperature_rotor)
    ("damiao", 0x3, 0x13, 1.25, -4.5, 2.0, True, 0x0, 31.0, 45.6, False, 0x013, "138ccc6cc9991f2e",
     (1.2499046311131448, -4.505494505494507, 2.0, True, 0, 31.0, 46.0)),
    ("damiao", 0x23, 0x11, -12.5, 30.0, -10.0, False, 0x0, None, 300.0, False, 0x011, "030000fff00000ff",
     (-12.5, 30.0, -10.0, False, 0, 0.0, 255.0)),
    ("damiao", 0x2, 0x12, 0.0, 0.0, 0.0, True, 0xD, 25.0, 25.0, False, 0x012, "d27fff7ff7ff1919",
     (-0.0001907377737087046, -0.0073260073260073, -0.0024420024420024333, False, 13, 25.0, 25.0)),
    ("damiao", 0x7, 0x17, 100.0, -100.0, 0.3, False, 0x5, -3.0, 80.4, False, 0x017, "57ffff00083c0050",
     (12.5, -30.0, 0.2954822954822962, False, 5, 0.0, 80.0)),
    ("tmotor", 0x2, 0x0, 1.5, -3.0, 2.0, True, 0x0, 40.0, None, False, 0x000, "028f5b7848e32800",
     (1.4997711146715496, -3.0158730158730194, 2.0, None, 0, 40.0, None)),
    ("tmotor", 0x9, 0x7F, -7.0, 49.0, -17.9, True, 0x3, 120.6, 50.0, False, 0x07F, "093851fd600b7903",
     (-7.000267032883192, 48.998778998779, -17.903296703296704, None, 3, 121.0, None)),
    ("tmotor", 0x9, 0x7F, -7.0, 49.0, -17.9, True, 0x3, 120.6, 50.0, True, 0x07F, "093851fd600b",
     (-7.000267032883192, 48.998778998779, -17.903296703296704, None, 0, None, None)),
    ("tmotor", 0xFF, 0x0, 12.5, 0.01, 0.0, False, 0x0, None, None, False, 0x000, "ffffff7ff7ff0000",
     (12.5, -0.012210012210012167, -0.00439560439560438, None, 0, 0.0, None)),
    ("myactuator", 0x1, 0x0, -1.0, 0.5, -2.0, True, 0x0, None, None, False, 0x501, "0175c28167540000",
     (-1.0000381475547417, 0.4945054945054963, -2.01025641025641, None, 0, None, None)),
    ("myactuator", 0x20, 0x5, 3.3, -44.0, 23.0, False, 0x7, 60.0, 70.0, True, 0x520, "20a1ca02dfa90000",
     (3.2999542229343106, -44.01098901098901, 22.99194139194139, None, 0, None, None)),
]  # fmt: skip

MIT_SPECIALS: list[tuple[str, str, tuple[int, str] | None]] = [  # motor 0x12
    ("damiao", "enable", (0x012, "fffffffffffffffc")),
    ("damiao", "disable", (0x012, "fffffffffffffffd")),
    ("damiao", "zero", (0x012, "fffffffffffffffe")),
    ("damiao", "clear", (0x012, "fffffffffffffffb")),
    ("tmotor", "enable", (0x012, "fffffffffffffffc")),
    ("tmotor", "disable", (0x012, "fffffffffffffffd")),
    ("tmotor", "zero", (0x012, "fffffffffffffffe")),
    ("tmotor", "clear", None),
    ("myactuator", "enable", None),
    ("myactuator", "disable", (0x152, "8000000000000000")),
    ("myactuator", "zero", None),
    ("myactuator", "clear", None),
]

MIT_BAD: list[tuple[str, int, str, int, int | None, str]] = [
    # flavour, arbitration id, data, expected motor, master_id → the reason
    ("damiao", 0x011, "117fff7ff7ff1e", 1, 0x11, "DLC 8, got 7"),
    ("damiao", 0x012, "117fff7ff7ff1e1e", 1, 0x11, "damiao: reply on id 0x12, expected 0x11"),
    ("damiao", 0x011, "717fff7ff7ff1e1e", 1, None, "damiao: unknown status nibble 0x7"),
    ("damiao", 0x011, "127fff7ff7ff1e1e", 1, None, "damiao: feedback names motor nibble 0x2, expected 0x1"),
    ("tmotor", 0x000, "02010203040506", 2, None, "tmotor: reply needs DLC 6 or 8, got 7"),
    ("tmotor", 0x001, "020102030405", 2, 0, "tmotor: reply on id 0x1, expected 0x0"),
    ("tmotor", 0x000, "030102030405", 2, 0, "tmotor: reply names motor 3, expected 2"),
    ("myactuator", 0x501, "010102030405", 1, None, "DLC 8, got 6"),
    ("myactuator", 0x502, "0101020304050607", 1, None, "myactuator: reply on id 0x502, expected 0x501"),
    ("myactuator", 0x501, "0201020304050607", 1, None, "myactuator: reply names motor 2, expected 1"),
]


@pytest.mark.parametrize("row", MIT_REPLIES, ids=lambda row: f"{row[0]}-{row[1]:#x}-{row[10]}")
def test_mit_replies_keep_their_bytes_and_values(row: tuple[Any, ...]) -> None:
    name, motor, master, p, v, t, enabled, fault, t_mos, t_rotor, short, arbitration_id, data, decoded = row
    flavour, r = FLAVOURS[name], RANGES[name]
    msg = flavour.encode_reply(
        motor, master, p, v, t, r, enabled=enabled, fault=fault, t_mos=t_mos, t_rotor=t_rotor, short=short
    )
    assert (msg.arbitration_id, bytes(msg.data).hex(), msg.is_extended_id) == (arbitration_id, data, False)
    reply = flavour.decode_reply(msg, r, motor)
    assert (reply.motor_id, reply.position, reply.velocity, reply.torque) == (motor, *decoded[:3])
    assert (reply.enabled, reply.fault, reply.temperature_mos, reply.temperature_rotor) == decoded[3:]


@pytest.mark.parametrize(("name", "kind", "frame"), MIT_SPECIALS)
def test_mit_special_frames_keep_their_bytes(name: str, kind: str, frame: tuple[int, str] | None) -> None:
    msg = FLAVOURS[name].special(0x12, kind)  # type: ignore[arg-type]
    assert (None if msg is None else (msg.arbitration_id, bytes(msg.data).hex())) == frame


@pytest.mark.parametrize(("name", "arbitration_id", "data", "motor", "master_id", "reason"), MIT_BAD)
def test_mit_bad_replies_keep_their_reasons(
    name: str, arbitration_id: int, data: str, motor: int, master_id: int | None, reason: str
) -> None:
    msg = can.Message(arbitration_id=arbitration_id, data=bytes.fromhex(data), is_extended_id=False)
    with pytest.raises(FrameError, match=reason):
        FLAVOURS[name].decode_reply(msg, RANGES[name], motor, master_id=master_id)
