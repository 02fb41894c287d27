"""Emulated MIT-protocol drives: Damiao, T-Motor/CubeMars AK and MyActuator motion mode.

They share the control law τ = kp·(p − q) + kd·(v − q̇) + t_ff (clamped to ±t_max, applied only when enabled)
and quantised feedback through the same codec the host uses; they differ in ids, housekeeping frames, fault
reporting and what their watchdog does (Damiao latches 0xD and disables, T-Motor zeroes the command, MyActuator
cuts the output until commands flow again).
"""

from __future__ import annotations

import math
import struct
from typing import ClassVar, Self

import can

from drivers.can.emulator.base import MotorFirmware, ThermalModel
from drivers.can.protocol import damiao_registers as reg
from drivers.can.protocol.errors import FrameError
from drivers.can.protocol.flavours import DAMIAO, MYACTUATOR, TMOTOR, MitFlavour
from drivers.can.protocol.mit import MitCommand, MitRanges, decode_command, special_kind
from drivers.can.wiring import MotorWiring

_NO_TORQUE = MitCommand(0.0, 0.0, 0.0, 0.0, 0.0)


def _wrap_to_pi(angle: float) -> float:
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


class MitFirmware(MotorFirmware):
    """State and law common to the MIT flavours.

    Reported position is the shaft position minus `zero_offset` (set by the zero frame). With
    `multi_turn_lost_on_reboot` the position after a reboot comes back within ±π of zero, like drives whose
    multi-turn count lives in RAM; otherwise it is preserved. `timeout` (s, 0 = off) is the watchdog where it is a
    setting (a Damiao drive keeps it in a register); `short_replies` selects a flavour's short reply (T-Motor's
    older 6-byte layout).
    """

    flavour: ClassVar[MitFlavour]

    def __init__(
        self,
        motor_id: int,
        ranges: MitRanges,
        *,
        seed: int = 0,
        thermal: ThermalModel | None = None,
        master_id: int = 0,
        timeout: float = 0.0,
        short_replies: bool = False,
    ) -> None:
        super().__init__(rated_torque=ranges.t_max / 3.0, seed=seed, thermal=thermal)
        self.motor_id = motor_id
        self.master_id = master_id
        self.ranges = ranges
        self.zero_offset = 0.0
        self.multi_turn_lost_on_reboot = False
        self.short_replies = short_replies
        self._timeout = timeout
        self._enabled = False
        self._fault = 0
        self._command = _NO_TORQUE
        self._last_command_time = 0.0
        self.command_step = 0.0
        """Largest step of the commanded position since the drive was last enabled (rad, stiff commands only; the
        first one is measured from the shaft): a jump guard on the drive's side of the bus, which outlives hosts."""
        self.longest_command_gap = 0.0
        """Longest silence the watchdog saw since the drive was last enabled (s, at the emulator's service times,
        the watchdog's own resolution): how close the host, and the bus between, came to the timeout."""

    @classmethod
    def for_motor(cls, motor: MotorWiring, *, seed: int = 0) -> Self:
        """The drive a host wired as `motor` expects to find."""
        return cls(motor.id, motor.ranges, master_id=motor.reply_id, seed=seed)

    @property
    def timeout(self) -> float:
        """Watchdog period in seconds (0 = off): commands must arrive this often while the drive is enabled."""
        return self._timeout

    @timeout.setter
    def timeout(self, seconds: float) -> None:
        self._timeout = seconds

    @property
    def enabled(self) -> bool:
        return self._enabled

    @property
    def fault(self) -> int:
        return self._fault

    @property
    def command(self) -> MitCommand:
        """The command the law currently uses (as the drive decoded it)."""
        return self._command

    @property
    def reported_position(self) -> float:
        return self.position - self.zero_offset

    def torque(self, position: float, velocity: float) -> float:
        if not self._enabled:
            self.applied_torque = 0.0
            return 0.0
        p, v, kp, kd, t = self._command
        tau = kp * (p - (position - self.zero_offset)) + kd * (v - velocity) + t
        limit = self.ranges.t_max
        self.applied_torque = limit if tau > limit else -limit if tau < -limit else tau
        return self.applied_torque

    def inject_fault(self, code: int) -> None:
        if code == 0:
            raise ValueError("fault code 0 means healthy; use clear_fault()")
        self._fault = code
        self._disable()

    def clear_fault(self) -> None:
        self._fault = 0

    def reboot(self) -> None:
        self._fault = 0
        self._disable()
        self._pending.clear()
        if self.multi_turn_lost_on_reboot:
            reported = self.reported_position
            self.zero_offset += reported - _wrap_to_pi(reported)

    def _expire(self, now: float) -> None:
        if not self._enabled:
            return
        silence = now - self._last_command_time
        if silence > self.longest_command_gap:
            self.longest_command_gap = silence
        timeout = self.timeout
        if timeout > 0.0 and silence > timeout:
            self._watchdog_fired()

    def _watchdog_fired(self) -> None:
        """What the firmware does when commands stop arriving in time."""
        raise NotImplementedError

    def _enable(self, now: float) -> None:
        if self._fault:
            return  # a latched fault keeps the drive off until it is cleared
        self._enabled = True
        self._command = _NO_TORQUE  # entering motor mode starts limp, never from a stale command
        self._last_command_time = now
        self.command_step = 0.0
        self.longest_command_gap = 0.0

    def _special(self, kind: str | None, now: float) -> bool:
        """Enable, disable or set zero as every MIT firmware does; False for any other frame (left to the caller)."""
        if kind == "enable":
            self._enable(now)
        elif kind == "disable":
            self._disable()
        elif kind == "zero":
            self.zero_offset = self.position
        else:
            return False
        return True

    def _take_command(self, data: bytes | bytearray) -> None:
        """Decode an MIT command into the law, keeping `command_step` up to date."""
        command = decode_command(data, self.ranges)
        if command.kp > 0.0:
            last = self._command.p if self._command.kp > 0.0 else self.reported_position
            step = abs(command.p - last)
            if step > self.command_step:
                self.command_step = step
        self._command = command

    def _disable(self) -> None:
        self._enabled = False
        self._command = _NO_TORQUE
        self.applied_torque = 0.0

    def _feedback(self) -> can.Message:
        return self.flavour.encode_reply(
            self.motor_id,
            self.master_id,
            self.glitch.corrupt(0, self.reported_position) if self.glitch.active else self.reported_position,
            self.velocity,
            self.applied_torque,
            self.ranges,
            enabled=self._enabled,
            fault=self._fault,
            t_mos=self.temperature_mos,
            t_rotor=self.temperature_rotor,
            short=self.short_replies,
        )

    @staticmethod
    def _standard_data(msg: can.Message) -> bool:
        return not (msg.is_extended_id or msg.is_error_frame or msg.is_remote_frame)


class DamiaoFirmware(MitFirmware):
    """Damiao DM-J in MIT mode (CTRL_MODE 1).

    Power-up disabled (status 0). FC enables (refused while a fault is latched), FD disables, FE makes the current
    position zero, FB clears a latched fault back to disabled. Every MIT, special and refresh frame is answered
    with feedback on MST_ID. The TIMEOUT register (×50 µs, 0 = off) arms a watchdog while enabled: if no MIT or
    special frame arrives in time the drive latches 0xD and disables, and only clear + enable bring it back.
    Registers are read/written over 0x7FF; PMAX/VMAX/TMAX rescale the codec at once, ESC_ID/MST_ID take effect at
    once too (flagged in `ids_changed_in_ram`, since real drives may need store + power cycle). Frames for other
    control modes (0x100/0x200/0x300 + ESC_ID) are not emulated and are counted as ignored.
    """

    flavour = DAMIAO
    READ_ONLY: ClassVar[frozenset[int]] = frozenset({*range(11, 21), 36, *range(50, 66), reg.P_M, reg.XOUT})

    def __init__(
        self,
        esc_id: int,
        master_id: int,
        ranges: MitRanges,
        *,
        timeout_counts: int = 0,
        seed: int = 0,
        thermal: ThermalModel | None = None,
    ) -> None:
        super().__init__(esc_id, ranges, master_id=master_id, seed=seed, thermal=thermal)
        self.registers: dict[int, float] = {
            reg.UV_VALUE: 15.0,
            reg.KT_VALUE: 1.0,
            reg.OT_VALUE: 120.0,
            reg.OC_VALUE: 0.98,
            reg.MST_ID: master_id,
            reg.ESC_ID: esc_id,
            reg.TIMEOUT: timeout_counts,
            reg.CTRL_MODE: reg.CTRL_MODE_MIT,
            reg.SW_VER: 5013,
            reg.PMAX: ranges.p_max,
            reg.VMAX: ranges.v_max,
            reg.TMAX: ranges.t_max,
            reg.OV_VALUE: 52.0,
            reg.CAN_BR: 4,
        }
        self.ids_changed_in_ram = False
        self._stored = dict(self.registers)
        self._apply_registers()

    @classmethod
    def for_motor(cls, motor: MotorWiring, *, seed: int = 0) -> Self:
        return cls(motor.id, motor.reply_id, motor.ranges, seed=seed)

    @property
    def timeout(self) -> float:
        """Watchdog period in seconds (0 = off): the TIMEOUT register."""
        return self.registers[reg.TIMEOUT] * reg.TIMEOUT_UNIT_S

    def accepts(self, msg: can.Message) -> bool:
        if not self._standard_data(msg):
            return False
        arb = msg.arbitration_id
        if arb == reg.REGISTER_REQUEST_ID:
            return len(msg.data) >= 2 and msg.data[0] | msg.data[1] << 8 == self.motor_id
        return arb in (self.motor_id, self.motor_id + 0x100, self.motor_id + 0x200, self.motor_id + 0x300)

    def reboot(self) -> None:
        super().reboot()
        self.registers = dict(self._stored)
        self.ids_changed_in_ram = False
        self._apply_registers()

    def _over_temperature_fault(self, rotor: bool) -> int:
        return 0xC if rotor else 0xB

    def inject_fault(self, code: int) -> None:
        if code not in DAMIAO.fault_names:
            raise ValueError(f"damiao fault codes are {sorted(DAMIAO.fault_names)}, got 0x{code:X}")
        super().inject_fault(code)

    def _watchdog_fired(self) -> None:
        self.inject_fault(DAMIAO.LOST_COMM)

    def _receive(self, msg: can.Message, now: float) -> list[can.Message]:
        if msg.arbitration_id == reg.REGISTER_REQUEST_ID:
            return self._register_frame(msg)
        if msg.arbitration_id != self.motor_id:
            return self._ignore()  # POS_VEL / VEL / FORCE_POS frames: not emulated
        data = msg.data
        if len(data) != 8:
            raise FrameError(f"damiao: MIT frame needs DLC 8, got {len(data)}")
        kind = special_kind(data)
        if kind is None and self.registers[reg.CTRL_MODE] != reg.CTRL_MODE_MIT:
            return self._ignore()
        self._last_command_time = now
        if kind == "clear":
            if not self._still_hot():  # an over-temperature cannot be cleared while the drive is still hot
                self._fault = 0
            self._disable()
        elif not self._special(kind, now) and self._enabled:
            self._take_command(data)
        return [self._feedback()]

    def _still_hot(self) -> bool:
        """The latched fault is an over-temperature whose cause is still there (the firmware keeps it)."""
        if self._fault == self._over_temperature_fault(rotor=True):
            return self.temperature_rotor > self.over_temperature
        if self._fault == self._over_temperature_fault(rotor=False):
            return self.temperature_mos > self.over_temperature
        return False

    def _register_frame(self, msg: can.Message) -> list[can.Message]:
        esc_id, op, rid, raw = reg.decode_request(msg)
        if op == reg.OP_REFRESH:
            return [self._feedback()]
        if op == reg.OP_STORE:
            self._stored = dict(self.registers)
            return []
        if op == reg.OP_READ:
            value = self._read_register(rid)
            if value is None:
                return self._ignore()
            return [reg.encode_register_reply(self.master_id, esc_id, rid, value)]
        if op == reg.OP_WRITE:
            if rid not in self.registers or rid in self.READ_ONLY:
                return self._ignore()
            value = reg.unpack_value(rid, raw)
            if not self._valid_register_value(rid, value):
                return self._ignore()
            self.registers[rid] = value
            if rid in (reg.ESC_ID, reg.MST_ID):
                self.ids_changed_in_ram = True
            self._apply_registers()
            return [reg.encode_register_reply(self.master_id, esc_id, rid, value, op=reg.OP_WRITE)]
        return self._ignore()

    def _read_register(self, rid: int) -> float | None:
        if rid in (reg.P_M, reg.XOUT):
            return self.reported_position
        return self.registers.get(rid)

    @staticmethod
    def _valid_register_value(rid: int, value: float) -> bool:
        if rid == reg.CTRL_MODE:
            return value in (1, 2, 3, 4)
        if rid in (reg.ESC_ID, reg.MST_ID):
            return 0 <= value <= 0x7FF
        if rid in (reg.PMAX, reg.VMAX, reg.TMAX):
            return math.isfinite(value) and value > 0.0
        return math.isfinite(value)

    def _apply_registers(self) -> None:
        self.motor_id = int(self.registers[reg.ESC_ID])
        self.master_id = int(self.registers[reg.MST_ID])
        self.ranges = MitRanges(self.registers[reg.PMAX], self.registers[reg.VMAX], self.registers[reg.TMAX])
        self.over_temperature = self.registers[reg.OT_VALUE]


class TMotorFirmware(MitFirmware):
    """T-Motor / CubeMars AK in MIT mode (Ben Katz lineage).

    FC enters motor mode, FD exits, FE zeroes; any other 8-byte frame (FF…FB included) is an MIT command.
    Every frame is answered on the master id with D0 = motor id: 8 bytes with temperature and error byte, or the
    older 6-byte layout when `short_replies` is set. `timeout` (s, 0 = off) zeroes the command when MIT commands
    stop — the drive goes limp but stays in motor mode. A fault (error byte 1–6) cuts torque and latches until
    reboot: there is no clear frame.
    """

    flavour = TMOTOR

    def accepts(self, msg: can.Message) -> bool:
        return self._standard_data(msg) and msg.arbitration_id == self.motor_id

    def inject_fault(self, code: int) -> None:
        if code not in TMOTOR.fault_names:
            raise ValueError(f"T-Motor error codes are {sorted(TMOTOR.fault_names)}, got {code}")
        super().inject_fault(code)

    def _over_temperature_fault(self, rotor: bool) -> int:
        return 1

    def _watchdog_fired(self) -> None:
        self._command = _NO_TORQUE

    def _receive(self, msg: can.Message, now: float) -> list[can.Message]:
        data = msg.data
        if len(data) != 8:
            raise FrameError(f"tmotor: command needs DLC 8, got {len(data)}")
        if not self._special(special_kind(data), now):  # FF…FB is an ordinary command here: no clear frame
            self._last_command_time = now
            if self._enabled:
                self._take_command(data)
        return [self._feedback()]


class MyActuatorFirmware(MitFirmware):
    """MyActuator X series in motion mode (protocol V4.3).

    Motion commands (0x400 + id) run the motor directly and are answered on 0x500 + id; there are no special
    frames. Native commands on 0x140 + id (answered on 0x240 + id): 0x80 motor off, 0x81 stop, 0x9A status 1
    (temperature, voltage, error flags), 0xB3 communication timeout in ms, 0x76 system reset. The watchdog cuts
    the output when motion commands stop; the next motion command runs the motor again. Faults (error flag bits)
    cut the output until reboot and are visible only through 0x9A.
    """

    flavour = MYACTUATOR
    bus_voltage = 48.0

    def accepts(self, msg: can.Message) -> bool:
        return self._standard_data(msg) and msg.arbitration_id in (
            MYACTUATOR.command_id(self.motor_id),
            MYACTUATOR.NATIVE_BASE + self.motor_id,
        )

    def inject_fault(self, code: int) -> None:
        if not 0 < code <= 0xFFFF:
            raise ValueError(f"MyActuator error flags are a non-zero uint16, got {code}")
        super().inject_fault(code)

    def _over_temperature_fault(self, rotor: bool) -> int:
        return 0x1000

    def _watchdog_fired(self) -> None:
        self._disable()

    def _receive(self, msg: can.Message, now: float) -> list[can.Message]:
        data = msg.data
        if len(data) != 8:
            raise FrameError(f"myactuator: frame needs DLC 8, got {len(data)}")
        if msg.arbitration_id == MYACTUATOR.command_id(self.motor_id):
            self._last_command_time = now
            if not self._enabled:
                self._enable(now)
            if self._enabled:
                self._take_command(data)
            return [self._feedback()]
        return self._native(data, now)

    def _native(self, data: bytes | bytearray, now: float) -> list[can.Message]:
        code = data[0]
        reply_id = MYACTUATOR.NATIVE_REPLY_BASE + self.motor_id
        if code in (MYACTUATOR.MOTOR_OFF, 0x81):
            self._disable()
            payload = bytes([code, 0, 0, 0, 0, 0, 0, 0])
        elif code == 0x9A:
            temperature = max(-128, min(127, round(self.temperature_rotor)))
            voltage = round(self.bus_voltage * 10)
            payload = struct.pack("<BbBBHH", 0x9A, temperature, 0, 1 if self._enabled else 0, voltage, self._fault)
        elif code == 0xB3:
            self.timeout = struct.unpack_from("<I", data, 4)[0] / 1000.0
            payload = bytes(data)
        elif code == 0x76:
            self.reboot()
            return []
        else:
            return self._ignore()
        return [can.Message(arbitration_id=reply_id, data=payload, is_extended_id=False)]
