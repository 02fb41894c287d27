"""ODrive "CAN Simple" as spoken by firmware 0.6 (ODrive Pro / S1): ids, enums, error bits and payloads.

arbitration id = node_id << 5 | cmd_id on standard frames; every multi-byte field is little-endian. Getters are
answered when the host sends a remote (RTR) frame with the same id; heartbeat and encoder estimates are also sent
cyclically. Firmware 0.5 reuses some ids with other meanings, so this module is only valid for 0.6.

The ``encode_*`` functions build a new frame each; the host's cycle instead keeps one frame per axis and command
(``empty_frame``) and refills its data with the ``pack_*`` functions, which write the same bytes.
"""

from __future__ import annotations

import enum
import struct
from typing import NamedTuple

import can

from drivers.can.protocol.errors import FrameError

NODE_BITS = 6
CMD_BITS = 5
MAX_NODE = (1 << NODE_BITS) - 1


class Cmd(enum.IntEnum):
    GET_VERSION = 0x00
    HEARTBEAT = 0x01
    ESTOP = 0x02
    GET_ERROR = 0x03
    RX_SDO = 0x04
    TX_SDO = 0x05
    ADDRESS = 0x06
    SET_AXIS_STATE = 0x07
    GET_ENCODER_ESTIMATES = 0x09
    SET_CONTROLLER_MODE = 0x0B
    SET_INPUT_POS = 0x0C
    SET_INPUT_VEL = 0x0D
    SET_INPUT_TORQUE = 0x0E
    SET_LIMITS = 0x0F
    SET_TRAJ_VEL_LIMIT = 0x11
    SET_TRAJ_ACCEL_LIMITS = 0x12
    SET_TRAJ_INERTIA = 0x13
    GET_IQ = 0x14
    GET_TEMPERATURE = 0x15
    REBOOT = 0x16
    GET_BUS_VOLTAGE_CURRENT = 0x17
    CLEAR_ERRORS = 0x18
    SET_ABSOLUTE_POSITION = 0x19
    SET_POS_GAIN = 0x1A
    SET_VEL_GAINS = 0x1B
    GET_TORQUES = 0x1C
    GET_POWERS = 0x1D
    ENTER_DFU = 0x1F


class AxisState(enum.IntEnum):
    UNDEFINED = 0
    IDLE = 1
    STARTUP_SEQUENCE = 2
    FULL_CALIBRATION_SEQUENCE = 3
    MOTOR_CALIBRATION = 4
    ENCODER_INDEX_SEARCH = 6
    ENCODER_OFFSET_CALIBRATION = 7
    CLOSED_LOOP_CONTROL = 8
    LOCKIN_SPIN = 9
    ENCODER_DIR_FIND = 10
    HOMING = 11
    ENCODER_HALL_POLARITY_CALIBRATION = 12
    ENCODER_HALL_PHASE_CALIBRATION = 13
    ANTICOGGING_CALIBRATION = 14


class ControlMode(enum.IntEnum):
    VOLTAGE_CONTROL = 0
    TORQUE_CONTROL = 1
    VELOCITY_CONTROL = 2
    POSITION_CONTROL = 3


class InputMode(enum.IntEnum):
    INACTIVE = 0
    PASSTHROUGH = 1
    VEL_RAMP = 2
    POS_FILTER = 3
    MIX_CHANNELS = 4
    TRAP_TRAJ = 5
    TORQUE_RAMP = 6
    MIRROR = 7
    TUNING = 8


class ProcedureResult(enum.IntEnum):
    SUCCESS = 0
    BUSY = 1
    CANCELLED = 2
    DISARMED = 3
    NO_RESPONSE = 4


class RebootAction(enum.IntEnum):
    REBOOT = 0
    SAVE_CONFIGURATION = 1
    ERASE_CONFIGURATION = 2
    ENTER_DFU = 3


class ODriveError(enum.IntFlag):
    """Axis error bits of firmware 0.6 (0.5 numbers them differently)."""

    INITIALIZING = 0x1
    SYSTEM_LEVEL = 0x2
    TIMING_ERROR = 0x4
    MISSING_ESTIMATE = 0x8
    BAD_CONFIG = 0x10
    DRV_FAULT = 0x20
    MISSING_INPUT = 0x40
    DC_BUS_OVER_VOLTAGE = 0x100
    DC_BUS_UNDER_VOLTAGE = 0x200
    DC_BUS_OVER_CURRENT = 0x400
    DC_BUS_OVER_REGEN_CURRENT = 0x800
    CURRENT_LIMIT_VIOLATION = 0x1000
    MOTOR_OVER_TEMP = 0x2000
    INVERTER_OVER_TEMP = 0x4000
    VELOCITY_LIMIT_VIOLATION = 0x8000
    POSITION_LIMIT_VIOLATION = 0x10000
    WATCHDOG_TIMER_EXPIRED = 0x0100_0000
    ESTOP_REQUESTED = 0x0200_0000
    SPINOUT_DETECTED = 0x0400_0000
    BRAKE_RESISTOR_DISARMED = 0x0800_0000
    THERMISTOR_DISCONNECTED = 0x1000_0000
    CALIBRATION_ERROR = 0x4000_0000


def describe_errors(bits: int) -> str:
    """Names of the set error bits, e.g. "WATCHDOG_TIMER_EXPIRED|ESTOP_REQUESTED"; unknown bits in hex."""
    if bits == 0:
        return "no error"
    names = [flag.name for flag in ODriveError if bits & flag.value and flag.name]
    unknown = bits & ~sum(flag.value for flag in ODriveError)
    if unknown:
        names.append(f"0x{unknown:X}")
    return "|".join(names)


def arbitration_id(node: int, cmd: int) -> int:
    if not 0 <= node <= MAX_NODE:
        raise ValueError(f"ODrive node id must be 0..{MAX_NODE}, got {node}")
    if not 0 <= cmd < 1 << CMD_BITS:
        raise ValueError(f"ODrive command id must be 0..31, got {cmd}")
    return node << CMD_BITS | cmd


def split_id(arb: int) -> tuple[int, int]:
    """(node, cmd) of a standard arbitration id."""
    return arb >> CMD_BITS & MAX_NODE, arb & ((1 << CMD_BITS) - 1)


def _frame(node: int, cmd: int, data: bytes) -> can.Message:
    return can.Message(arbitration_id=arbitration_id(node, cmd), data=data, is_extended_id=False)


def empty_frame(node: int, cmd: int, size: int) -> can.Message:
    """A zeroed data frame of ``size`` bytes for ``cmd``, to be refilled in place every cycle by a ``pack_*``."""
    return can.Message(arbitration_id=arbitration_id(node, cmd), data=bytearray(size), is_extended_id=False)


def request(node: int, cmd: int) -> can.Message:
    """A remote (RTR) frame asking `node` for getter `cmd`."""
    return can.Message(arbitration_id=arbitration_id(node, cmd), is_remote_frame=True, is_extended_id=False, dlc=8)


def _payload(data: bytes | bytearray, length: int, what: str) -> bytes | bytearray:
    if len(data) != length:
        raise FrameError(f"odrive {what} needs {length} data bytes, got {len(data)}")
    return data


class Heartbeat(NamedTuple):
    axis_error: int
    axis_state: int
    procedure_result: int
    trajectory_done: bool


def encode_heartbeat(node: int, hb: Heartbeat) -> can.Message:
    data = struct.pack("<IBBBx", hb.axis_error, hb.axis_state, hb.procedure_result, 1 if hb.trajectory_done else 0)
    return _frame(node, Cmd.HEARTBEAT, data)


def decode_heartbeat(data: bytes | bytearray) -> Heartbeat:
    error, state, result, flags = struct.unpack_from("<IBBB", _payload(data, 8, "heartbeat"))
    return Heartbeat(error, state, result, bool(flags & 1))


class EncoderEstimates(NamedTuple):
    position: float
    """rev"""
    velocity: float
    """rev/s"""


ENCODER_ESTIMATES = struct.Struct("<ff")
"""Payload of Get_Encoder_Estimates: position (rev), velocity (rev/s); ``.unpack`` needs exactly 8 bytes."""


def encode_encoder_estimates(node: int, position: float, velocity: float) -> can.Message:
    return _frame(node, Cmd.GET_ENCODER_ESTIMATES, struct.pack("<ff", position, velocity))


def decode_encoder_estimates(data: bytes | bytearray) -> EncoderEstimates:
    return EncoderEstimates(*ENCODER_ESTIMATES.unpack(_payload(data, 8, "encoder estimates")))


def encode_set_axis_state(node: int, state: int) -> can.Message:
    return _frame(node, Cmd.SET_AXIS_STATE, struct.pack("<I", state))


def decode_set_axis_state(data: bytes | bytearray) -> int:
    return struct.unpack("<I", _payload(data, 4, "Set_Axis_State"))[0]


def encode_set_controller_mode(node: int, control_mode: int, input_mode: int) -> can.Message:
    return _frame(node, Cmd.SET_CONTROLLER_MODE, struct.pack("<II", control_mode, input_mode))


def decode_set_controller_mode(data: bytes | bytearray) -> tuple[int, int]:
    return struct.unpack("<II", _payload(data, 8, "Set_Controller_Mode"))


FEED_FORWARD_SCALE = 0.001
"""Set_Input_Pos carries its velocity and torque feed-forward as int16 in units of 0.001."""


def _int16_scaled(value: float) -> int:
    return max(-32768, min(32767, round(value / FEED_FORWARD_SCALE)))


class InputPos(NamedTuple):
    position: float
    """rev"""
    vel_ff: float
    """rev/s"""
    torque_ff: float
    """Nm"""


def encode_set_input_pos(node: int, position: float, vel_ff: float = 0.0, torque_ff: float = 0.0) -> can.Message:
    """Feed-forwards are rounded to 0.001 and saturate at ±32.767."""
    data = struct.pack("<fhh", position, _int16_scaled(vel_ff), _int16_scaled(torque_ff))
    return _frame(node, Cmd.SET_INPUT_POS, data)


_PACK_INPUT_POS = struct.Struct("<fhh").pack_into


def pack_set_input_pos(buffer: bytearray, position: float, vel_ff: float, torque_ff: float) -> None:
    """The data of `encode_set_input_pos`, written into an 8-byte buffer (same rounding, saturation and errors)."""
    vel = round(vel_ff / FEED_FORWARD_SCALE)
    torque = round(torque_ff / FEED_FORWARD_SCALE)
    _PACK_INPUT_POS(
        buffer,
        0,
        position,
        -32768 if vel < -32768 else 32767 if vel > 32767 else vel,
        -32768 if torque < -32768 else 32767 if torque > 32767 else torque,
    )


def decode_set_input_pos(data: bytes | bytearray) -> InputPos:
    position, vel, torque = struct.unpack("<fhh", _payload(data, 8, "Set_Input_Pos"))
    return InputPos(position, vel * FEED_FORWARD_SCALE, torque * FEED_FORWARD_SCALE)


def encode_set_input_vel(node: int, velocity: float, torque_ff: float = 0.0) -> can.Message:
    return _frame(node, Cmd.SET_INPUT_VEL, struct.pack("<ff", velocity, torque_ff))


_PACK_INPUT_VEL = struct.Struct("<ff").pack_into


def pack_set_input_vel(buffer: bytearray, velocity: float, torque_ff: float) -> None:
    """The data of `encode_set_input_vel`, written into an 8-byte buffer."""
    _PACK_INPUT_VEL(buffer, 0, velocity, torque_ff)


def decode_set_input_vel(data: bytes | bytearray) -> tuple[float, float]:
    return struct.unpack("<ff", _payload(data, 8, "Set_Input_Vel"))


def encode_set_input_torque(node: int, torque: float) -> can.Message:
    return _frame(node, Cmd.SET_INPUT_TORQUE, struct.pack("<f", torque))


_PACK_INPUT_TORQUE = struct.Struct("<f").pack_into


def pack_set_input_torque(buffer: bytearray, torque: float) -> None:
    """The data of `encode_set_input_torque`, written into a 4-byte buffer."""
    _PACK_INPUT_TORQUE(buffer, 0, torque)


def decode_set_input_torque(data: bytes | bytearray) -> float:
    return struct.unpack("<f", _payload(data, 4, "Set_Input_Torque"))[0]


def encode_set_absolute_position(node: int, position: float) -> can.Message:
    """Make the current position read `position` rev."""
    return _frame(node, Cmd.SET_ABSOLUTE_POSITION, struct.pack("<f", position))


def decode_set_absolute_position(data: bytes | bytearray) -> float:
    return struct.unpack("<f", _payload(data, 4, "Set_Absolute_Position"))[0]


def encode_clear_errors(node: int, identify: bool = False) -> can.Message:
    return _frame(node, Cmd.CLEAR_ERRORS, bytes([1 if identify else 0]))


def decode_clear_errors(data: bytes | bytearray) -> bool:
    """The identify flag; an empty payload (older hosts) means no identify."""
    if len(data) > 1:
        raise FrameError(f"odrive Clear_Errors carries at most 1 byte, got {len(data)}")
    return bool(data[0]) if data else False


def encode_reboot(node: int, action: int = RebootAction.REBOOT) -> can.Message:
    return _frame(node, Cmd.REBOOT, bytes([action]))


def decode_reboot(data: bytes | bytearray) -> int:
    if len(data) > 1:
        raise FrameError(f"odrive Reboot carries at most 1 byte, got {len(data)}")
    return data[0] if data else RebootAction.REBOOT


def encode_estop(node: int) -> can.Message:
    return _frame(node, Cmd.ESTOP, b"")


class Temperature(NamedTuple):
    fet: float
    motor: float


def encode_temperature(node: int, fet: float, motor: float) -> can.Message:
    return _frame(node, Cmd.GET_TEMPERATURE, struct.pack("<ff", fet, motor))


def decode_temperature(data: bytes | bytearray) -> Temperature:
    return Temperature(*struct.unpack("<ff", _payload(data, 8, "Get_Temperature")))


class ErrorReport(NamedTuple):
    active_errors: int
    disarm_reason: int


def encode_error(node: int, active_errors: int, disarm_reason: int) -> can.Message:
    return _frame(node, Cmd.GET_ERROR, struct.pack("<II", active_errors, disarm_reason))


def decode_error(data: bytes | bytearray) -> ErrorReport:
    return ErrorReport(*struct.unpack("<II", _payload(data, 8, "Get_Error")))


class BusVoltageCurrent(NamedTuple):
    voltage: float
    current: float


def encode_bus_voltage_current(node: int, voltage: float, current: float) -> can.Message:
    return _frame(node, Cmd.GET_BUS_VOLTAGE_CURRENT, struct.pack("<ff", voltage, current))


def decode_bus_voltage_current(data: bytes | bytearray) -> BusVoltageCurrent:
    return BusVoltageCurrent(*struct.unpack("<ff", _payload(data, 8, "Get_Bus_Voltage_Current")))
