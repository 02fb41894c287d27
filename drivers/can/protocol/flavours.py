"""Per-vendor framing around the shared MIT codec: arbitration ids, special frames and reply tails.

The command frame is identical everywhere; the flavours differ in where a reply arrives, what its first and last
bytes carry (Damiao status nibble, T-Motor temperature and error byte) and which housekeeping frames exist.
Decoders check everything they can (DLC, frame type, id bytes, status codes) and raise `FrameError` with the
reason, so a host counts a bad frame instead of acting on it.

`decode_reply` returns a `MitReply` and is the reference (emulators, tests, tools). `reply_decoder` builds the
host's per-cycle decoder for one motor: plain tuples from the data bytes, ranges resolved once, and identical values.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar, Literal

import can

from drivers.can.protocol.errors import FrameError
from drivers.can.protocol.mit import (
    FIELD_STEPS,
    POSITION_STEPS,
    SPECIAL_FRAMES,
    MitRanges,
    decode_state,
    encode_command,
    encode_state,
    state_scales,
)

SpecialKind = Literal["enable", "disable", "zero", "clear"]

ReplyFields = tuple[float, float, float, bool | None, int, float | None, float | None]
"""(position, velocity, torque, enabled, fault, temperature_mos, temperature_rotor): a `MitReply` minus the id."""
ReplyDecoder = Callable[[bytes | bytearray], ReplyFields]

# D0 | p16 | v12 t12 | two tail bytes. The 12-bit fields straddle D4, so they are taken apart by hand.
_STATE_8 = struct.Struct(">BHBBBBB").unpack
_STATE_6 = struct.Struct(">BHBBB").unpack
_STATE_HEAD = struct.Struct(">BHBBB").unpack_from


@dataclass(frozen=True, slots=True)
class MitReply:
    """One decoded feedback frame. `enabled` is None where the flavour does not report it; fault 0 = healthy."""

    motor_id: int
    position: float
    velocity: float
    torque: float
    enabled: bool | None
    fault: int
    temperature_mos: float | None
    temperature_rotor: float | None


def _standard_frame(arbitration_id: int, data: bytes, fd: bool = False) -> can.Message:
    return can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False, is_fd=fd)


def _check_data_frame(msg: can.Message, flavour: str) -> None:
    if msg.is_error_frame:
        raise FrameError(f"{flavour}: error frame, not a reply")
    if msg.is_remote_frame:
        raise FrameError(f"{flavour}: remote frame, not a reply")
    if msg.is_extended_id:
        raise FrameError(f"{flavour}: extended id 0x{msg.arbitration_id:X}, replies use standard ids")


def _temperature_byte(celsius: float | None) -> int:
    if celsius is None:
        return 0
    return min(255, max(0, round(celsius)))


class MitFlavour:
    """Framing of one vendor's MIT mode. Stateless; one shared instance per vendor."""

    name: ClassVar[str]
    reports_enabled: ClassVar[bool]
    """True when every reply says whether the drive is enabled (lets a host notice a silent reboot)."""
    fault_names: ClassVar[dict[int, str]]

    def command_id(self, motor_id: int) -> int:
        return motor_id

    def reply_id(self, motor_id: int, master_id: int) -> int:
        return master_id

    def command(
        self, motor_id: int, p: float, v: float, kp: float, kd: float, t: float, ranges: MitRanges, *, fd: bool = False
    ) -> can.Message:
        """The MIT command frame for one motor."""
        return _standard_frame(self.command_id(motor_id), encode_command(p, v, kp, kd, t, ranges), fd)

    def special(self, motor_id: int, kind: SpecialKind, *, fd: bool = False) -> can.Message | None:
        """The enable/disable/zero/clear frame, or None when this firmware has no such frame."""
        data = SPECIAL_FRAMES.get(kind)
        if data is None:
            raise ValueError(f"unknown special frame kind {kind!r}; expected one of {sorted(SPECIAL_FRAMES)}")
        return _standard_frame(self.command_id(motor_id), data, fd)

    def is_ack(self, msg: can.Message, motor_id: int) -> bool:
        """True for a housekeeping acknowledgement that carries no state (a host should skip it, not count it)."""
        return False

    def decode_reply(
        self, msg: can.Message, ranges: MitRanges, expected_motor_id: int, *, master_id: int | None = None
    ) -> MitReply:
        """Decode a feedback frame; with `master_id` also check the arbitration id it arrived on."""
        raise NotImplementedError

    def reply_decoder(self, ranges: MitRanges, motor_id: int) -> ReplyDecoder:
        """`decode_reply` specialised for one motor, on the data bytes only: the host's per-cycle decoder.

        The caller has checked the frame type, the arbitration id and that the DLC is one this flavour uses (the
        host routes on them); the decoder checks the rest exactly like `decode_reply` (motor byte, status) and
        raises `FrameError` where it would. The values are bit-identical to `decode_reply`'s.
        """
        raise NotImplementedError

    def encode_reply(
        self,
        motor_id: int,
        master_id: int,
        p: float,
        v: float,
        t: float,
        ranges: MitRanges,
        *,
        enabled: bool,
        fault: int,
        t_mos: float | None,
        t_rotor: float | None,
        short: bool = False,
    ) -> can.Message:
        """The feedback frame the drive sends (emulator side). `short` selects T-Motor's 6-byte variant."""
        raise NotImplementedError

    def describe_fault(self, code: int) -> str:
        if code == 0:
            return "no fault"
        return self.fault_names.get(code, f"unknown fault 0x{code:X}")

    def _check_master(self, msg: can.Message, master_id: int | None, motor_id: int) -> None:
        if master_id is not None and msg.arbitration_id != self.reply_id(motor_id, master_id):
            raise FrameError(
                f"{self.name}: reply on id 0x{msg.arbitration_id:X}, expected 0x{self.reply_id(motor_id, master_id):X}"
            )

    def __repr__(self) -> str:
        return f"<MitFlavour {self.name}>"


class DamiaoFlavour(MitFlavour):
    """Damiao DM-J: commands on ESC_ID, replies on MST_ID with D0 = status << 4 | ESC_ID & 0xF."""

    name = "damiao"
    reports_enabled = True
    STATUS_DISABLED: ClassVar[int] = 0x0
    STATUS_ENABLED: ClassVar[int] = 0x1
    LOST_COMM: ClassVar[int] = 0xD
    fault_names: ClassVar[dict[int, str]] = {
        0x5: "sensor error",
        0x6: "parameter error",
        0x8: "over-voltage",
        0x9: "under-voltage",
        0xA: "over-current",
        0xB: "MOS over-temperature",
        0xC: "rotor over-temperature",
        0xD: "communication lost (CAN timeout)",
        0xE: "overload",
    }

    def decode_reply(
        self, msg: can.Message, ranges: MitRanges, expected_motor_id: int, *, master_id: int | None = None
    ) -> MitReply:
        _check_data_frame(msg, self.name)
        data = msg.data
        if len(data) != 8:
            raise FrameError(f"damiao: feedback needs DLC 8, got {len(data)}")
        self._check_master(msg, master_id, expected_motor_id)
        if data[0] & 0xF != expected_motor_id & 0xF:
            raise FrameError(
                f"damiao: feedback names motor nibble 0x{data[0] & 0xF:X}, expected 0x{expected_motor_id & 0xF:X}"
            )
        status = data[0] >> 4
        if status == self.STATUS_ENABLED:
            enabled, fault = True, 0
        elif status == self.STATUS_DISABLED:
            enabled, fault = False, 0
        elif status in self.fault_names:
            enabled, fault = False, status
        else:
            raise FrameError(f"damiao: unknown status nibble 0x{status:X}")
        p, v, t = decode_state(data[1:6], ranges)
        return MitReply(expected_motor_id, p, v, t, enabled, fault, float(data[6]), float(data[7]))

    def reply_decoder(self, ranges: MitRanges, motor_id: int) -> ReplyDecoder:
        p_lo, p_span, v_lo, v_span, t_lo, t_span = state_scales(ranges)
        p_steps, steps, unpack = POSITION_STEPS, FIELD_STEPS, _STATE_8
        nibble = motor_id & 0xF
        # D0 = status << 4 | id nibble: one lookup checks both and yields (enabled, fault).
        statuses = {self.STATUS_ENABLED: (True, 0), self.STATUS_DISABLED: (False, 0)}
        statuses.update((code, (False, code)) for code in self.fault_names)
        by_d0 = {status << 4 | nibble: state for status, state in statuses.items()}

        def decode(data: bytes | bytearray) -> ReplyFields:
            d0, up, d3, d4, d5, t_mos, t_rotor = unpack(data)
            state = by_d0.get(d0)
            if state is None:
                if d0 & 0xF != nibble:
                    raise FrameError(f"damiao: feedback names motor nibble 0x{d0 & 0xF:X}, expected 0x{nibble:X}")
                raise FrameError(f"damiao: unknown status nibble 0x{d0 >> 4:X}")
            return (
                up * p_span / p_steps + p_lo,
                (d3 << 4 | d4 >> 4) * v_span / steps + v_lo,
                ((d4 & 0xF) << 8 | d5) * t_span / steps + t_lo,
                state[0],
                state[1],
                float(t_mos),
                float(t_rotor),
            )

        return decode

    def encode_reply(
        self,
        motor_id: int,
        master_id: int,
        p: float,
        v: float,
        t: float,
        ranges: MitRanges,
        *,
        enabled: bool,
        fault: int,
        t_mos: float | None,
        t_rotor: float | None,
        short: bool = False,
    ) -> can.Message:
        status = fault if fault else (self.STATUS_ENABLED if enabled else self.STATUS_DISABLED)
        if not 0 <= status <= 0xF:
            raise ValueError(f"damiao status must fit a nibble, got 0x{status:X}")
        data = (
            bytes([status << 4 | motor_id & 0xF])
            + encode_state(p, v, t, ranges)
            + bytes([_temperature_byte(t_mos), _temperature_byte(t_rotor)])
        )
        return _standard_frame(master_id, data)


class TMotorFlavour(MitFlavour):
    """T-Motor / CubeMars AK in MIT mode: replies on the master id (default 0), matched on the id in D0.

    Older firmware replies with 6 bytes; newer appends a temperature byte (°C) and an error byte.
    There is no clear-error frame.
    """

    name = "tmotor"
    reports_enabled = False
    fault_names: ClassVar[dict[int, str]] = {
        1: "over-temperature",
        2: "over-current",
        3: "over-voltage",
        4: "under-voltage",
        5: "encoder fault",
        6: "phase-current unbalance",
    }

    def special(self, motor_id: int, kind: SpecialKind, *, fd: bool = False) -> can.Message | None:
        if kind == "clear":
            return None
        return super().special(motor_id, kind, fd=fd)

    def decode_reply(
        self, msg: can.Message, ranges: MitRanges, expected_motor_id: int, *, master_id: int | None = None
    ) -> MitReply:
        _check_data_frame(msg, self.name)
        data = msg.data
        if len(data) not in (6, 8):
            raise FrameError(f"tmotor: reply needs DLC 6 or 8, got {len(data)}")
        self._check_master(msg, master_id, expected_motor_id)
        if data[0] != expected_motor_id:
            raise FrameError(f"tmotor: reply names motor {data[0]}, expected {expected_motor_id}")
        p, v, t = decode_state(data[1:6], ranges)
        if len(data) == 6:
            return MitReply(expected_motor_id, p, v, t, None, 0, None, None)
        return MitReply(expected_motor_id, p, v, t, None, data[7], float(data[6]), None)

    def reply_decoder(self, ranges: MitRanges, motor_id: int) -> ReplyDecoder:
        p_lo, p_span, v_lo, v_span, t_lo, t_span = state_scales(ranges)
        p_steps, steps, unpack_long, unpack_short = POSITION_STEPS, FIELD_STEPS, _STATE_8, _STATE_6

        def decode(data: bytes | bytearray) -> ReplyFields:
            if len(data) == 8:
                d0, up, d3, d4, d5, temperature, fault = unpack_long(data)
                t_mos: float | None = float(temperature)
            else:
                d0, up, d3, d4, d5 = unpack_short(data)
                t_mos, fault = None, 0
            if d0 != motor_id:
                raise FrameError(f"tmotor: reply names motor {d0}, expected {motor_id}")
            return (
                up * p_span / p_steps + p_lo,
                (d3 << 4 | d4 >> 4) * v_span / steps + v_lo,
                ((d4 & 0xF) << 8 | d5) * t_span / steps + t_lo,
                None,
                fault,
                t_mos,
                None,
            )

        return decode

    def encode_reply(
        self,
        motor_id: int,
        master_id: int,
        p: float,
        v: float,
        t: float,
        ranges: MitRanges,
        *,
        enabled: bool,
        fault: int,
        t_mos: float | None,
        t_rotor: float | None,
        short: bool = False,
    ) -> can.Message:
        data = bytes([motor_id & 0xFF]) + encode_state(p, v, t, ranges)
        if not short:
            data += bytes([_temperature_byte(t_mos), fault & 0xFF])
        return _standard_frame(master_id, data)


class MyActuatorFlavour(MitFlavour):
    """MyActuator motion mode (protocol V4.3): commands on 0x400 + id, replies on 0x500 + id, D0 = id.

    Motion-mode commands run the motor directly, so there is no enable frame; "disable" is the native motor-off
    command (0x80 on 0x140 + id), acknowledged on 0x240 + id. Faults are not reported in motion-mode replies.
    """

    name = "myactuator"
    reports_enabled = False
    fault_names: ClassVar[dict[int, str]] = {}
    COMMAND_BASE: ClassVar[int] = 0x400
    REPLY_BASE: ClassVar[int] = 0x500
    NATIVE_BASE: ClassVar[int] = 0x140
    NATIVE_REPLY_BASE: ClassVar[int] = 0x240
    MOTOR_OFF: ClassVar[int] = 0x80

    def command_id(self, motor_id: int) -> int:
        return self.COMMAND_BASE + motor_id

    def reply_id(self, motor_id: int, master_id: int) -> int:
        return self.REPLY_BASE + motor_id

    def special(self, motor_id: int, kind: SpecialKind, *, fd: bool = False) -> can.Message | None:
        if kind not in SPECIAL_FRAMES:
            raise ValueError(f"unknown special frame kind {kind!r}; expected one of {sorted(SPECIAL_FRAMES)}")
        if kind != "disable":
            return None
        return _standard_frame(self.NATIVE_BASE + motor_id, bytes([self.MOTOR_OFF, 0, 0, 0, 0, 0, 0, 0]), fd)

    def is_ack(self, msg: can.Message, motor_id: int) -> bool:
        return msg.arbitration_id == self.NATIVE_REPLY_BASE + motor_id and not msg.is_extended_id

    def decode_reply(
        self, msg: can.Message, ranges: MitRanges, expected_motor_id: int, *, master_id: int | None = None
    ) -> MitReply:
        _check_data_frame(msg, self.name)
        data = msg.data
        if len(data) != 8:
            raise FrameError(f"myactuator: motion reply needs DLC 8, got {len(data)}")
        if msg.arbitration_id != self.REPLY_BASE + expected_motor_id:
            raise FrameError(
                f"myactuator: reply on id 0x{msg.arbitration_id:X}, expected 0x{self.REPLY_BASE + expected_motor_id:X}"
            )
        if data[0] != expected_motor_id:
            raise FrameError(f"myactuator: reply names motor {data[0]}, expected {expected_motor_id}")
        p, v, t = decode_state(data[1:6], ranges)
        return MitReply(expected_motor_id, p, v, t, None, 0, None, None)

    def reply_decoder(self, ranges: MitRanges, motor_id: int) -> ReplyDecoder:
        p_lo, p_span, v_lo, v_span, t_lo, t_span = state_scales(ranges)
        p_steps, steps, unpack = POSITION_STEPS, FIELD_STEPS, _STATE_HEAD

        def decode(data: bytes | bytearray) -> ReplyFields:
            d0, up, d3, d4, d5 = unpack(data)
            if d0 != motor_id:
                raise FrameError(f"myactuator: reply names motor {d0}, expected {motor_id}")
            return (
                up * p_span / p_steps + p_lo,
                (d3 << 4 | d4 >> 4) * v_span / steps + v_lo,
                ((d4 & 0xF) << 8 | d5) * t_span / steps + t_lo,
                None,
                0,
                None,
                None,
            )

        return decode

    def encode_reply(
        self,
        motor_id: int,
        master_id: int,
        p: float,
        v: float,
        t: float,
        ranges: MitRanges,
        *,
        enabled: bool,
        fault: int,
        t_mos: float | None,
        t_rotor: float | None,
        short: bool = False,
    ) -> can.Message:
        data = bytes([motor_id & 0xFF]) + encode_state(p, v, t, ranges) + b"\x00\x00"
        return _standard_frame(self.REPLY_BASE + motor_id, data)


DAMIAO = DamiaoFlavour()
TMOTOR = TMotorFlavour()
MYACTUATOR = MyActuatorFlavour()
FLAVOURS: dict[str, MitFlavour] = {f.name: f for f in (DAMIAO, TMOTOR, MYACTUATOR)}
