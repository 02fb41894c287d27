"""Per-vendor framing around the shared MIT codec: every fact in which Damiao, T-Motor and MyActuator differ.

The command frame is identical everywhere; the flavours differ in ids (where a command goes, where its reply
arrives), what the first and last bytes of a reply carry (Damiao status nibble, T-Motor temperature and error
byte), which housekeeping frames exist, and how a host learns about faults. A host driver reads these facts from
the flavour object and never asks for a vendor by name.

Each flavour has one reply decoder: `reply_decoder` builds the host's per-cycle decoder for one motor (the data
bytes of a frame the host already routed, ranges resolved once); `decode_reply` checks what routing would have
checked (frame type, DLC, arbitration id) and hands the data to that same decoder. Both raise `FrameError` with
the reason, so a host counts a bad frame instead of acting on it.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar, Literal

import can

from drivers.can.protocol import damiao_registers as reg
from drivers.can.protocol.errors import FrameError
from drivers.can.protocol.mit import (
    FIELD_STEPS,
    POSITION_STEPS,
    SPECIAL_FRAMES,
    MitRanges,
    encode_command,
    encode_state,
    state_scales,
)

SpecialKind = Literal["enable", "disable", "zero", "clear"]
ReplyTail = Literal["temperatures", "temperature_and_error", "unused"]
"""What bytes D6–D7 of an 8-byte reply carry: MOS and rotor temperature (°C), temperature and error code, nothing."""

ReplyFields = tuple[float, float, float, bool | None, int, float | None, float | None]
"""(position, velocity, torque, enabled, fault, temperature_mos, temperature_rotor): a `MitReply` minus the id."""
ReplyDecoder = Callable[[bytes | bytearray], ReplyFields]
FrameMaker = Callable[[int, bytes], can.Message]
"""(arbitration id, data) → a frame with the host bus's flags (classic or FD)."""

# D0 | p16 | v12 t12 | two tail bytes. The 12-bit fields straddle D4, so they are taken apart by hand.
_REPLY_8 = struct.Struct(">BHBBBBB").unpack
_REPLY_6 = struct.Struct(">BHBBB").unpack


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


def _reply_tail_bytes(tail: ReplyTail, fault: int, t_mos: float | None, t_rotor: float | None) -> bytes:
    if tail == "temperatures":
        return bytes([_temperature_byte(t_mos), _temperature_byte(t_rotor)])
    if tail == "temperature_and_error":
        return bytes([_temperature_byte(t_mos), fault & 0xFF])
    return b"\x00\x00"


class MitFlavour:
    """Framing of one vendor's MIT mode. Stateless; one shared instance per vendor."""

    name: ClassVar[str]
    reports_enabled: ClassVar[bool]
    """True when every reply says whether the drive is enabled (lets a host notice a silent reboot)."""
    fault_names: ClassVar[dict[int, str]]
    motor_ids: ClassVar[range]
    """The motor ids the firmware accepts."""
    reply_lengths: ClassVar[tuple[int, ...]] = (8,)
    """The DLCs of a feedback frame."""
    reply_tail: ClassVar[ReplyTail]
    motor_key_mask: ClassVar[int] = 0xFF
    """The bits of D0 that name the motor: replies of motors sharing a reply id differ there."""
    replies_on_master_id: ClassVar[bool] = True
    """Replies arrive on the host's id (`reply_id` ignores the motor id), not on one derived from the motor id."""
    own_reply_ids: ClassVar[bool] = False
    """Each motor may be given its own reply id (a drive register), instead of the shared master id."""
    reserved_ids: ClassVar[dict[int, str]] = {}
    """Ids the flavour uses for other traffic, which no reply may use: id → what it is."""
    registers: ClassVar[bool] = False
    """The drive keeps its ranges, control mode and CAN watchdog in registers a host can read and write: configure
    checks the ranges and mode against the config and writes the watchdog."""
    polls_status: ClassVar[bool] = False
    """Replies carry no fault: a host polls a native status frame for error flags and temperature."""

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

    def feedback_request(self, motor_id: int, ranges: MitRanges, frame: FrameMaker) -> can.Message:
        """A frame the motor answers with one feedback frame without acting on it (start-up, before any enable).

        Here an MIT frame with kp = kd = 0 and zero feed-forward: a drive in rest mode only answers it, and one that
        runs every motion frame produces no torque (≤ 1 LSB, t_max/4095: 0 Nm is not representable).
        """
        return frame(self.command_id(motor_id), encode_command(0.0, 0.0, 0.0, 0.0, 0.0, ranges))

    def is_ack(self, msg: can.Message, motor_id: int) -> bool:
        """True for a housekeeping acknowledgement that carries no state (a host should skip it, not count it)."""
        return False

    def native_ids(self, motor_id: int) -> tuple[int, ...]:
        """Ids of the motor's traffic besides commands and replies (housekeeping, status polls)."""
        return ()

    def status_request(self, motor_id: int) -> tuple[int, bytes]:
        """(arbitration id, data) of the status poll, for a flavour that `polls_status`."""
        raise NotImplementedError(f"{self.name} replies carry the status; it is not polled")

    def status_reply_id(self, motor_id: int) -> int:
        """The id the answer to `status_request` arrives on."""
        raise NotImplementedError(f"{self.name} replies carry the status; it is not polled")

    def decode_status(self, data: bytes | bytearray) -> tuple[float, int] | None:
        """(temperature °C, error flags) from a frame on `status_reply_id`; None for an acknowledgement there."""
        raise NotImplementedError(f"{self.name} replies carry the status; it is not polled")

    # ---- feedback ----------------------------------------------------------------------------------------------
    def reply_decoder(self, ranges: MitRanges, motor_id: int) -> ReplyDecoder:
        """The decoder of one motor's replies, on the data bytes only: the host's per-cycle decoder.

        The caller has checked the frame type, the arbitration id and that the DLC is in `reply_lengths` (the host
        routes on them; `decode_reply` checks them itself). D0 must name the motor (and, for Damiao, a known
        status), else `FrameError`. The arithmetic is `decode_state`'s with the ranges resolved once, so the values
        are bit-identical to it.
        """
        p_lo, p_span, v_lo, v_span, t_lo, t_span = state_scales(ranges)
        p_steps, steps, unpack_8, unpack_6 = POSITION_STEPS, FIELD_STEPS, _REPLY_8, _REPLY_6
        heads = self._reply_heads(motor_id)  # D0 → (enabled, fault): one lookup checks the motor and the status
        wrong_head = self._wrong_head
        no_tail, temperatures = self.reply_tail == "unused", self.reply_tail == "temperatures"
        one_length = self.reply_lengths == (8,)  # spares the others T-Motor's len() per frame

        def decode(data: bytes | bytearray) -> ReplyFields:
            if one_length or len(data) == 8:
                d0, up, d3, d4, d5, d6, d7 = unpack_8(data)
            else:  # T-Motor's older firmware: no tail, marked by d6 = -1
                d0, up, d3, d4, d5 = unpack_6(data)
                d6 = d7 = -1
            try:
                enabled, fault = heads[d0]
            except KeyError:
                raise FrameError(wrong_head(d0, motor_id)) from None
            p = up * p_span / p_steps + p_lo
            v = (d3 << 4 | d4 >> 4) * v_span / steps + v_lo
            t = ((d4 & 0xF) << 8 | d5) * t_span / steps + t_lo
            if temperatures:
                return p, v, t, enabled, fault, float(d6), float(d7)
            if no_tail or d6 < 0:
                return p, v, t, enabled, fault, None, None
            return p, v, t, enabled, d7, float(d6), None  # temperature and error byte

        return decode

    def decode_reply(
        self, msg: can.Message, ranges: MitRanges, expected_motor_id: int, *, master_id: int | None = None
    ) -> MitReply:
        """Check a whole feedback frame, then decode it with `reply_decoder`.

        The arbitration id is checked where it is known: always when it derives from the motor id, and against
        `master_id` when given for a flavour that replies on the host's id.
        """
        _check_data_frame(msg, self.name)
        data = msg.data
        if len(data) not in self.reply_lengths:
            lengths = " or ".join(str(n) for n in self.reply_lengths)
            raise FrameError(f"{self.name}: reply needs DLC {lengths}, got {len(data)}")
        if master_id is not None or not self.replies_on_master_id:
            expected = self.reply_id(expected_motor_id, 0 if master_id is None else master_id)
            if msg.arbitration_id != expected:
                raise FrameError(f"{self.name}: reply on id 0x{msg.arbitration_id:X}, expected 0x{expected:X}")
        return MitReply(expected_motor_id, *self.reply_decoder(ranges, expected_motor_id)(data))

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
        data = bytes([self._reply_head(motor_id, enabled, fault)]) + encode_state(p, v, t, ranges)
        if not (short and 6 in self.reply_lengths):
            data += _reply_tail_bytes(self.reply_tail, fault, t_mos, t_rotor)
        return _standard_frame(self.reply_id(motor_id, master_id), data)

    def _reply_heads(self, motor_id: int) -> dict[int, tuple[bool | None, int]]:
        """Every D0 a reply of this motor may carry → (enabled, fault). Here D0 is the motor id."""
        return {motor_id: (None, 0)}

    def _wrong_head(self, d0: int, motor_id: int) -> str:
        return f"{self.name}: reply names motor {d0}, expected {motor_id}"

    def _reply_head(self, motor_id: int, enabled: bool, fault: int) -> int:
        return motor_id & 0xFF

    # ---- faults ------------------------------------------------------------------------------------------------
    def describe_fault(self, code: int) -> str:
        if code == 0:
            return "no fault"
        return self.fault_names.get(code, f"unknown fault 0x{code:X}")

    def explain_fault(self, code: int) -> str:
        """The fault as an operator reads it: vendor, code and name."""
        return f"{self.name} fault {code:#x}: {self.describe_fault(code)}"

    def __repr__(self) -> str:
        return f"<MitFlavour {self.name}>"


class DamiaoFlavour(MitFlavour):
    """Damiao DM-J: commands on ESC_ID, replies on MST_ID with D0 = status << 4 | ESC_ID & 0xF."""

    name = "damiao"
    reports_enabled = True
    motor_ids = range(1, 0x7FF)
    reply_tail = "temperatures"
    motor_key_mask = 0x0F
    own_reply_ids = True
    reserved_ids: ClassVar[dict[int, str]] = {reg.REGISTER_REQUEST_ID: "Damiao's register channel"}
    registers = True
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

    def feedback_request(self, motor_id: int, ranges: MitRanges, frame: FrameMaker) -> can.Message:
        """The register channel's refresh (0x7FF, 0xCC), which only answers; a classic frame like every register
        request."""
        return reg.refresh_request(motor_id)

    def _reply_heads(self, motor_id: int) -> dict[int, tuple[bool | None, int]]:
        """D0 = status << 4 | id nibble: enabled, disabled, or a fault (which leaves the drive disabled)."""
        states: dict[int, tuple[bool | None, int]] = {self.STATUS_ENABLED: (True, 0), self.STATUS_DISABLED: (False, 0)}
        states.update((code, (False, code)) for code in self.fault_names)
        return {status << 4 | motor_id & 0xF: state for status, state in states.items()}

    def _wrong_head(self, d0: int, motor_id: int) -> str:
        if d0 & 0xF != motor_id & 0xF:
            return f"damiao: feedback names motor nibble 0x{d0 & 0xF:X}, expected 0x{motor_id & 0xF:X}"
        return f"damiao: unknown status nibble 0x{d0 >> 4:X}"

    def _reply_head(self, motor_id: int, enabled: bool, fault: int) -> int:
        status = fault if fault else (self.STATUS_ENABLED if enabled else self.STATUS_DISABLED)
        if not 0 <= status <= 0xF:
            raise ValueError(f"damiao status must fit a nibble, got 0x{status:X}")
        return status << 4 | motor_id & 0xF


class TMotorFlavour(MitFlavour):
    """T-Motor / CubeMars AK in MIT mode: replies on the master id (default 0), matched on the id in D0.

    Older firmware replies with 6 bytes; newer appends a temperature byte (°C) and an error byte.
    There is no clear-error frame.
    """

    name = "tmotor"
    reports_enabled = False
    motor_ids = range(0, 0x100)
    reply_lengths = (6, 8)
    reply_tail = "temperature_and_error"
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


class MyActuatorFlavour(MitFlavour):
    """MyActuator motion mode (protocol V4.3): commands on 0x400 + id, replies on 0x500 + id, D0 = id.

    Motion-mode commands run the motor directly, so there is no enable frame; "disable" is the native motor-off
    command (0x80 on 0x140 + id), acknowledged on 0x240 + id. Faults are not reported in motion-mode replies: the
    native "read status 1" (0x9A) carries the error flags and the temperature.
    """

    name = "myactuator"
    reports_enabled = False
    motor_ids = range(1, 33)
    reply_tail = "unused"
    replies_on_master_id = False
    polls_status = True
    fault_names: ClassVar[dict[int, str]] = {}
    ERROR_FLAGS: ClassVar[dict[int, str]] = {
        0x0002: "stall",
        0x0004: "low voltage",
        0x0008: "over-voltage",
        0x0010: "over-current",
        0x0040: "power overrun",
        0x0080: "calibration parameter write error",
        0x0100: "over-speed",
        0x1000: "over-temperature",
        0x2000: "encoder calibration error",
    }
    COMMAND_BASE: ClassVar[int] = 0x400
    REPLY_BASE: ClassVar[int] = 0x500
    NATIVE_BASE: ClassVar[int] = 0x140
    NATIVE_REPLY_BASE: ClassVar[int] = 0x240
    MOTOR_OFF: ClassVar[int] = 0x80
    READ_STATUS: ClassVar[int] = 0x9A
    """"Read status 1": D1 temperature (int8 °C), D4–D5 voltage (0.1 V), D6–D7 error flags (uint16 LE)."""

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

    def native_ids(self, motor_id: int) -> tuple[int, ...]:
        return self.NATIVE_BASE + motor_id, self.NATIVE_REPLY_BASE + motor_id

    def status_request(self, motor_id: int) -> tuple[int, bytes]:
        return self.NATIVE_BASE + motor_id, bytes([self.READ_STATUS, 0, 0, 0, 0, 0, 0, 0])

    def status_reply_id(self, motor_id: int) -> int:
        return self.NATIVE_REPLY_BASE + motor_id

    def decode_status(self, data: bytes | bytearray) -> tuple[float, int] | None:
        if len(data) != 8:
            raise FrameError(f"myactuator: native reply needs DLC 8, got {len(data)}")
        if data[0] != self.READ_STATUS:
            return None  # the acknowledgement of another native command
        temperature = data[1] - 256 if data[1] > 127 else data[1]
        return float(temperature), data[6] | data[7] << 8

    def describe_fault(self, code: int) -> str:
        """The names of the error flags set in `code`."""
        if code == 0:
            return "no fault"
        names = [name for bit, name in self.ERROR_FLAGS.items() if code & bit]
        unknown = code & ~sum(self.ERROR_FLAGS)
        if unknown:
            names.append(f"unknown flags {unknown:#x}")
        return ", ".join(names)

    def explain_fault(self, code: int) -> str:
        return f"myactuator error flags {code:#06x}: {self.describe_fault(code)}"


DAMIAO = DamiaoFlavour()
TMOTOR = TMotorFlavour()
MYACTUATOR = MyActuatorFlavour()
FLAVOURS: dict[str, MitFlavour] = {f.name: f for f in (DAMIAO, TMOTOR, MYACTUATOR)}
