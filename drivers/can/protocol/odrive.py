"""ODrive "CAN Simple" as spoken by firmware 0.6 (ODrive Pro / S1): ids, enums, error bits and payloads.

arbitration id = node_id << 5 | cmd_id on standard frames; every multi-byte field is little-endian. Getters are
answered when the host sends a remote (RTR) frame with the same id; heartbeat and encoder estimates are also sent
cyclically. Firmware 0.5 reuses some ids with other meanings, so this module is only valid for 0.6.

Every message is one row of a table (`Message`: command id, payload layout, field names, wire conversions); its
encoder, in-place packer (the host's cycle keeps one frame per axis and command and refills its data) and checked
decoder are derived from that row. The ``encode_*``/``decode_*``/``pack_*`` names are the rows' methods.
"""

from __future__ import annotations

import enum
import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

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


def empty_frame(node: int, cmd: int, size: int) -> can.Message:
    """A zeroed data frame of ``size`` bytes for ``cmd``, to be refilled in place every cycle by a ``pack``."""
    return can.Message(arbitration_id=arbitration_id(node, cmd), data=bytearray(size), is_extended_id=False)


def request(node: int, cmd: int) -> can.Message:
    """A remote (RTR) frame asking `node` for getter `cmd`."""
    return can.Message(arbitration_id=arbitration_id(node, cmd), is_remote_frame=True, is_extended_id=False, dlc=8)


# ---- field conversions -------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class FixedPoint:
    """A float sent as an integer count of `scale`, rounded and saturated at `lo`..`hi`."""

    scale: float
    lo: int
    hi: int

    def to_wire(self, value: float) -> int:
        count = round(value / self.scale)
        return self.lo if count < self.lo else self.hi if count > self.hi else count

    def from_wire(self, raw: int) -> float:
        return raw * self.scale


class LowBit:
    """A flag in bit 0 of a byte whose other bits are reserved."""

    to_wire = staticmethod(lambda value: 1 if value else 0)
    from_wire = staticmethod(lambda raw: bool(raw & 1))


FEED_FORWARD_SCALE = 0.001
FEED_FORWARD = FixedPoint(FEED_FORWARD_SCALE, -32768, 32767)
"""Set_Input_Pos carries its velocity and torque feed-forward as int16 in units of 0.001: ±32.767, saturated."""
WireConversion = FixedPoint | LowBit


# ---- the message table ---------------------------------------------------------------------------------------------

Packer = Callable[..., None]


class Message:
    """One CAN Simple message, everything derived from its row: command id, payload layout and fields.

    `fields` is a NamedTuple class (decode returns one; its defaults are encode's) or a tuple of names (decode
    returns the bare value of a one-field message, else a plain tuple; `defaults` are the trailing fields' defaults).
    A message whose every field has a default may arrive empty (older hosts send Clear_Errors and Reboot that way).
    """

    def __init__(
        self,
        name: str,
        cmd: Cmd,
        layout: str,
        fields: type[tuple[Any, ...]] | tuple[str, ...],
        *,
        wire: dict[str, WireConversion] | None = None,
        defaults: tuple[Any, ...] = (),
    ) -> None:
        self.name = name
        self.cmd = cmd
        self.layout = struct.Struct(layout)
        self.size = self.layout.size
        if isinstance(fields, tuple):
            self.fields, self.defaults, self._result = fields, defaults, None
        else:
            self.fields, self.defaults, self._result = fields._fields, tuple(fields._field_defaults.values()), fields
        self.optional = 0 < len(self.fields) == len(self.defaults)
        self.wire = wire or {}
        self._from_wire = [(i, self.wire[f].from_wire) for i, f in enumerate(self.fields) if f in self.wire]
        self.pack: Packer = _packer(self.layout.pack_into, [self.wire.get(f) for f in self.fields])
        """pack(buffer, *values): the payload written into `buffer` in place (the same bytes `encode` sends)."""

    def encode(self, node: int, *values: Any) -> can.Message:
        """A new frame for `node`; trailing fields with defaults may be left out."""
        missing = len(self.fields) - len(values)
        if missing:
            if not 0 < missing <= len(self.defaults):
                raise TypeError(f"{self.name} takes {len(self.fields)} values {self.fields}, got {len(values)}")
            values += self.defaults[len(self.defaults) - missing :]
        frame = empty_frame(node, self.cmd, self.size)
        self.pack(frame.data, *values)
        return frame

    def decode(self, data: bytes | bytearray) -> Any:
        """The fields of a payload; `FrameError` when its length does not fit."""
        if len(data) != self.size:
            if self.optional and not data:
                return self._shaped(self.defaults)
            if self.optional:
                raise FrameError(f"odrive {self.name} carries at most {self.size} byte, got {len(data)}")
            raise FrameError(f"odrive {self.name} needs {self.size} data bytes, got {len(data)}")
        values: Sequence[Any] = self.layout.unpack(data)
        if self._from_wire:
            values = list(values)
            for i, from_wire in self._from_wire:
                values[i] = from_wire(values[i])
        return self._shaped(values)

    def frame(self, node: int) -> can.Message:
        """A zeroed frame of this message for `node`, for the cycle to refill with `pack`."""
        return empty_frame(node, self.cmd, self.size)

    def _shaped(self, values: Sequence[Any]) -> Any:
        if self._result is not None:
            return tuple.__new__(self._result, values)  # the NamedTuple without a Python-level __new__ call
        return values[0] if len(values) == 1 else tuple(values)


def _packer(pack_into: Callable[..., None], conversions: list[WireConversion | None]) -> Packer:
    """`pack(buffer, *values)` at offset 0, each value through its field's conversion.

    Spelled out for the shapes of the messages the cycle packs, where `*values` would cost an argument tuple per
    frame and a conversion a call: one or two fields sent as they are (Set_Input_Torque, Set_Input_Vel), and a value
    followed by two fixed-point fields (Set_Input_Pos), rounded and saturated inline exactly as `FixedPoint.to_wire`
    does. Every other message takes the general form.
    """
    plain = not any(conversions)
    if plain and len(conversions) == 1:
        return lambda buffer, a: pack_into(buffer, 0, a)
    if plain and len(conversions) == 2:
        return lambda buffer, a, b: pack_into(buffer, 0, a, b)
    first, second, third = (*conversions, None, None, None)[:3]
    if len(conversions) == 3 and first is None and isinstance(second, FixedPoint) and isinstance(third, FixedPoint):
        s1, lo1, hi1, s2, lo2, hi2 = second.scale, second.lo, second.hi, third.scale, third.lo, third.hi

        def pack_fixed(buffer: bytearray, a: Any, b: float, c: float) -> None:
            count_b, count_c = round(b / s1), round(c / s2)
            count_b = lo1 if count_b < lo1 else hi1 if count_b > hi1 else count_b
            count_c = lo2 if count_c < lo2 else hi2 if count_c > hi2 else count_c
            pack_into(buffer, 0, a, count_b, count_c)

        return pack_fixed
    to_wire = [c.to_wire if c else None for c in conversions]

    def pack(buffer: bytearray, *values: Any) -> None:
        pack_into(buffer, 0, *[v if w is None else w(v) for w, v in zip(to_wire, values, strict=True)])

    return pack


class Heartbeat(NamedTuple):
    axis_error: int
    axis_state: int
    procedure_result: int
    trajectory_done: bool


class EncoderEstimates(NamedTuple):
    position: float
    """rev"""
    velocity: float
    """rev/s"""


class InputPos(NamedTuple):
    position: float
    """rev"""
    vel_ff: float = 0.0
    """rev/s"""
    torque_ff: float = 0.0
    """Nm"""


HEARTBEAT = Message("heartbeat", Cmd.HEARTBEAT, "<IBBBx", Heartbeat, wire={"trajectory_done": LowBit()})
ENCODER_ESTIMATES = Message("encoder estimates", Cmd.GET_ENCODER_ESTIMATES, "<ff", EncoderEstimates)
SET_AXIS_STATE = Message("Set_Axis_State", Cmd.SET_AXIS_STATE, "<I", ("state",))
SET_CONTROLLER_MODE = Message("Set_Controller_Mode", Cmd.SET_CONTROLLER_MODE, "<II", ("control_mode", "input_mode"))
SET_INPUT_POS = Message(
    "Set_Input_Pos", Cmd.SET_INPUT_POS, "<fhh", InputPos, wire={"vel_ff": FEED_FORWARD, "torque_ff": FEED_FORWARD}
)
SET_INPUT_VEL = Message("Set_Input_Vel", Cmd.SET_INPUT_VEL, "<ff", ("velocity", "torque_ff"), defaults=(0.0,))
SET_INPUT_TORQUE = Message("Set_Input_Torque", Cmd.SET_INPUT_TORQUE, "<f", ("torque",))
SET_ABSOLUTE_POSITION = Message("Set_Absolute_Position", Cmd.SET_ABSOLUTE_POSITION, "<f", ("position",))
CLEAR_ERRORS = Message("Clear_Errors", Cmd.CLEAR_ERRORS, "<?", ("identify",), defaults=(False,))
REBOOT = Message("Reboot", Cmd.REBOOT, "<B", ("action",), defaults=(RebootAction.REBOOT,))
ESTOP = Message("Estop", Cmd.ESTOP, "<", ())
GET_ERROR = Message("Get_Error", Cmd.GET_ERROR, "<II", ("active_errors", "disarm_reason"))
GET_TEMPERATURE = Message("Get_Temperature", Cmd.GET_TEMPERATURE, "<ff", ("fet", "motor"))
GET_BUS_VOLTAGE_CURRENT = Message("Get_Bus_Voltage_Current", Cmd.GET_BUS_VOLTAGE_CURRENT, "<ff", ("voltage", "current"))
GET_TORQUES = Message("Get_Torques", Cmd.GET_TORQUES, "<ff", ("torque_target", "torque_estimate"))


def encode_heartbeat(node: int, hb: Heartbeat) -> can.Message:
    return HEARTBEAT.encode(node, *hb)


# The functions callers know, each one a row's method.
decode_heartbeat = HEARTBEAT.decode
encode_encoder_estimates, decode_encoder_estimates = ENCODER_ESTIMATES.encode, ENCODER_ESTIMATES.decode
encode_set_axis_state, decode_set_axis_state = SET_AXIS_STATE.encode, SET_AXIS_STATE.decode
encode_set_controller_mode, decode_set_controller_mode = SET_CONTROLLER_MODE.encode, SET_CONTROLLER_MODE.decode
encode_set_input_pos, decode_set_input_pos = SET_INPUT_POS.encode, SET_INPUT_POS.decode
encode_set_input_vel, decode_set_input_vel = SET_INPUT_VEL.encode, SET_INPUT_VEL.decode
encode_set_input_torque, decode_set_input_torque = SET_INPUT_TORQUE.encode, SET_INPUT_TORQUE.decode
pack_set_input_pos, pack_set_input_vel = SET_INPUT_POS.pack, SET_INPUT_VEL.pack
pack_set_input_torque = SET_INPUT_TORQUE.pack
encode_set_absolute_position, decode_set_absolute_position = SET_ABSOLUTE_POSITION.encode, SET_ABSOLUTE_POSITION.decode
encode_clear_errors, decode_clear_errors = CLEAR_ERRORS.encode, CLEAR_ERRORS.decode
encode_reboot, decode_reboot = REBOOT.encode, REBOOT.decode
encode_estop = ESTOP.encode
encode_error, decode_error = GET_ERROR.encode, GET_ERROR.decode
encode_temperature, decode_temperature = GET_TEMPERATURE.encode, GET_TEMPERATURE.decode
encode_bus_voltage_current, decode_bus_voltage_current = GET_BUS_VOLTAGE_CURRENT.encode, GET_BUS_VOLTAGE_CURRENT.decode
