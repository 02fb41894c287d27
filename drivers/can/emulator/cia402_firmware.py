"""Emulated CiA 402 servo drive, built from the same EDS and wiring as the host driver.

The CANopen side (NMT, heartbeat, SDO through `canopen`'s `LocalNode`, SYNC-driven PDOs as configured, EMCY, the
communication watchdog's inputs) is `CanopenFirmware` (`canopen_node.py`); this is the device profile: the CiA 402
state machine, its modes and the faults a drive latches.

* State machine: transitions 0–16 from the controlword, fault reset on the rising edge of bit 7 only, quick stop
  per 0x605A (0: disable at once; 1–3: brake, then Switch On Disabled; 5–7: brake and stay in Quick Stop Active),
  the fault reaction is immediate (torque off). Statusword bits 0–6, 9 (remote), 10 (target reached), 11 (internal
  limit: torque clamped), 12/13 (mode specific). 0x6061 follows 0x6060; a mode missing from 0x6502 is refused
  (SDO abort 0x06090030; from an RPDO it is ignored and counted) and the display stays.
* Modes: CSP (PD in actuator space on 0x607A with the internal gains, + 0x60B1 velocity and 0x60B2 torque
  offsets), CSV (velocity loop on 0x60FF + 0x60B1, + 0x60B2), CST (0x6071 + 0x60B2), all limited by 0x6072;
  homing (6) with methods 35/37 (the current position becomes 0x607C) and 33/34 (move at 0x6099:2 to the next
  index pulse below/above, emulated at `index_position` + k·2π of the shaft, which becomes 0x607C).
* CSP following error: |demand − actual| > 0x6065 for longer than 0x6066 ms → FAULT, EMCY 0x8611.
* Watchdog (the analogue of a Damiao CAN timeout), armed only in Operation Enabled: no SYNC and no RPDO while NMT
  operational for more than `sync_timeout_periods` × 0x1006 (when 0x1006 ≠ 0), or the heartbeat of the node in
  0x1016:1 missing for longer than its time (once a first one was heard) → FAULT, EMCY 0x8130.

A fault latches 0x603F, sets 0x1001, pushes 0x1003 and sends its EMCY; a fault reset that clears it sends EMCY
0x0000.
"""

from __future__ import annotations

import math

from canopen.profiles.p402 import State402
from canopen.sdo import SdoAbortedError

from drivers.can.cia402.wiring import DriveWiring
from drivers.can.emulator.base import ThermalModel
from drivers.can.emulator.canopen_node import ABORT_VALUE_RANGE, TIME_TOLERANCE, CanopenFirmware

__all__ = ["Cia402Firmware"]

_TAU = 2.0 * math.pi

# CiA 402 states, named as canopen's State402 names them
NOT_READY = "NOT READY TO SWITCH ON"
SWITCH_ON_DISABLED = "SWITCH ON DISABLED"
READY = "READY TO SWITCH ON"
SWITCHED_ON = "SWITCHED ON"
OPERATION_ENABLED = "OPERATION ENABLED"
QUICK_STOP = "QUICK STOP ACTIVE"
FAULT_REACTION = "FAULT REACTION ACTIVE"
FAULT = "FAULT"
_STATE_BITS = {name: value for name, (_mask, value) in State402.SW_MASK.items()}
_VOLTAGE_ENABLED = 0x0010
_QUICK_STOP_OFF = 0x0020  # statusword bit 5: 1 = quick stop NOT active
_REMOTE = 0x0200
_TARGET_REACHED = 0x0400
_INTERNAL_LIMIT = 0x0800
_BIT12 = 0x1000
_BIT13 = 0x2000

_CW_FAULT_RESET = 0x0080
_CW_HOMING_START = 0x0010
_CW_HALT = 0x0100

# modes of operation (0x6060)
HOMING, CSP, CSV, CST = 6, 8, 9, 10
_MODE_BIT = {HOMING: 1 << 5, CSP: 1 << 7, CSV: 1 << 8, CST: 1 << 9}

# EMCY error codes (CiA 301 / 402)
EMCY_RESET = 0x0000
EMCY_HEARTBEAT = 0x8130
EMCY_FOLLOWING_ERROR = 0x8611
EMCY_OVER_TEMPERATURE = 0x4310

_NO_WINDOW = 0xFFFFFFFF
_STANDSTILL = 0.01  # rad/s: a braking drive counts as stopped below this
_I16 = (-(1 << 15), (1 << 15) - 1)


def _i32(value: float) -> int:
    """A value as a drive's INTEGER32 register holds it (wraps like the counter does)."""
    return ((round(value) + (1 << 31)) & 0xFFFFFFFF) - (1 << 31)


def _i16(value: float) -> int:
    """A value as an INTEGER16 register holds it (saturated)."""
    low, high = _I16
    return low if value < low else high if value > high else round(value)


class Cia402Firmware(CanopenFirmware):
    """One CiA 402 drive (one CANopen node) for the joint `wiring` describes.

    `position_gain` (N·m/rad) and `velocity_gain` (N·m·s/rad) are the drive's own loop gains in actuator space
    (default 30 × and 1 × the rated torque per rad); `sync_timeout_periods` scales 0x1006 into the watchdog
    (default 50: the stale bound the loopback rig allows its two processes);
    `index_position` (rad, shaft) is where the emulated index pulse sits in every revolution.
    """

    def __init__(
        self,
        wiring: DriveWiring,
        *,
        seed: int = 0,
        thermal: ThermalModel | None = None,
        position_gain: float | None = None,
        velocity_gain: float | None = None,
        sync_timeout_periods: float = 50.0,
        index_position: float = 0.0,
    ) -> None:
        self.wiring = wiring
        self.position_gain = 30.0 * wiring.rated_torque if position_gain is None else position_gain
        self.velocity_gain = 1.0 * wiring.rated_torque if velocity_gain is None else velocity_gain
        self.sync_timeout_periods = sync_timeout_periods
        self.index_position = index_position
        self._counts_per_rad = wiring.counts_per_rad
        self._velocity_per_rad_s = wiring.velocity_per_rad_s
        self._permille_per_nm = wiring.permille_per_nm
        super().__init__(wiring.node_id, wiring.eds, rated_torque=wiring.rated_torque, seed=seed, thermal=thermal)
        self.origin = 0.0
        """Shaft position (rad) where the position actual value reads 0 (moved by homing; lost on reboot)."""
        self._reset_application()

    # -- power ---------------------------------------------------------------------------------------------------

    def _reset_application(self) -> None:
        """Power-on or reset node: EDS defaults, INITIALISING until the next timer run sends boot-up."""
        self.origin = 0.0
        self.state = NOT_READY
        self.controlword = 0
        self.mode = 0
        self.mode_display = 0
        self.target_position = 0
        self.target_velocity = 0
        self.target_torque = 0
        self.velocity_offset = 0
        self.torque_offset = 0
        self.error_code = 0
        self.applied_torque = 0.0
        self.limited = False
        self._stopped = False
        self.homing_state = "idle"  # idle, moving, attained, interrupted, error
        self._homing_goal = 0.0
        self._homing_speed = 0.0
        self._hold = 0.0
        self._following_since: float | None = None
        super()._reset_application()
        self.state = SWITCH_ON_DISABLED  # transition 1: self-test passed

    # -- MotorFirmware -----------------------------------------------------------------------------------------

    @property
    def enabled(self) -> bool:
        return self.state in (OPERATION_ENABLED, QUICK_STOP)

    @property
    def fault(self) -> int:
        return self.error_code if self.state in (FAULT, FAULT_REACTION) else 0

    def torque(self, position: float, velocity: float) -> float:
        state = self.state
        if state == OPERATION_ENABLED:
            tau = self._law(position, velocity)
        elif state == QUICK_STOP:  # the velocity loop brakes to standstill, then the position loop holds
            tau = self.position_gain * (self._hold - position) if self._stopped else 0.0
            tau -= self.velocity_gain * velocity
        else:
            self.applied_torque = 0.0
            self.limited = False
            return 0.0
        limit = self.max_torque
        self.limited = not -limit <= tau <= limit
        self.applied_torque = limit if tau > limit else -limit if tau < -limit else tau
        return self.applied_torque

    def _law(self, position: float, velocity: float) -> float:
        mode = self.mode_display
        if mode == CSP:
            demand = self.origin + self.target_position / self._counts_per_rad
            velocity_ff = self.velocity_offset / self._velocity_per_rad_s
            return (
                self.position_gain * (demand - position)
                + self.velocity_gain * (velocity_ff - velocity)
                + self.torque_offset / self._permille_per_nm
            )
        if mode == CSV:
            demand = (self.target_velocity + self.velocity_offset) / self._velocity_per_rad_s
            return self.velocity_gain * (demand - velocity) + self.torque_offset / self._permille_per_nm
        if mode == CST:
            return (self.target_torque + self.torque_offset) / self._permille_per_nm
        if mode == HOMING:
            if self.homing_state == "moving":
                return self.velocity_gain * (self._homing_speed - velocity)
            return self.position_gain * (self._hold - position) - self.velocity_gain * velocity
        return 0.0

    def inject_fault(self, code: int) -> None:
        """Latch the fault an EMCY error code names (e.g. 0x2310 overcurrent, 0x3210 overvoltage, 0x4310 hot)."""
        if not 0 < code <= 0xFFFF:
            raise ValueError(f"a CiA 402 fault is an EMCY error code 0x0001..0xFFFF, got {code:#x}")
        self._fault(code)

    def clear_fault(self) -> None:
        """The cause is gone and the fault acknowledged at the drive (as a fault reset would): Switch On Disabled."""
        if self.state in (FAULT, FAULT_REACTION):
            self._reset_fault()

    def reboot(self) -> None:
        self._pending.clear()
        self._outbox.take()
        self._reset_application()

    def _over_temperature_fault(self, rotor: bool) -> int:
        return EMCY_OVER_TEMPERATURE

    def _expire(self, now: float) -> None:
        self._boot_if_due(now)
        state = self.state
        if state == QUICK_STOP:
            self._brake()
        if self.state != OPERATION_ENABLED:
            self._following_since = None
            return
        if self._watchdog_expired(now, self.sync_timeout_periods):
            self._fault(EMCY_HEARTBEAT)
            return
        mode = self.mode_display
        if mode == CSP:
            self._check_following_error(now)
        elif mode == HOMING and self.homing_state == "moving":
            self._home_step()

    # -- object dictionary ----------------------------------------------------------------------------------------

    def _register_live_objects(self) -> None:
        super()._register_live_objects()
        read, write = self._live_read, self._live_write
        read[(0x6040, 0)] = lambda: self.controlword
        write[(0x6040, 0)] = self._set_controlword
        read[(0x6041, 0)] = self.statusword
        read[(0x6060, 0)] = lambda: self.mode
        write[(0x6060, 0)] = self._set_mode_from_pdo
        self._sdo_checks[(0x6060, 0)] = self._check_mode
        read[(0x6061, 0)] = lambda: self.mode_display
        read[(0x6062, 0)] = self._position_demand
        read[(0x6064, 0)] = self._position_reported
        read[(0x606C, 0)] = lambda: _i32(self.velocity * self._velocity_per_rad_s)
        read[(0x6077, 0)] = lambda: _i16(self.applied_torque * self._permille_per_nm)
        read[(0x60F4, 0)] = lambda: _i32(self._position_demand() - self._position_actual())
        read[(0x603F, 0)] = lambda: self.error_code
        for index, name in (
            (0x607A, "target_position"),
            (0x60FF, "target_velocity"),
            (0x6071, "target_torque"),
            (0x60B1, "velocity_offset"),
            (0x60B2, "torque_offset"),
        ):
            read[(index, 0)] = lambda name=name: getattr(self, name)
            write[(index, 0)] = lambda value, name=name: setattr(self, name, int(value))

    def _load_parameters(self) -> None:
        value = self._value
        self.quick_stop_option = value(0x605A)
        self.max_torque = value(0x6072) / self._permille_per_nm
        self.following_window = value(0x6065)
        self.following_timeout = value(0x6066) / 1000.0
        self.home_offset = value(0x607C)
        self.homing_method = value(0x6098)
        self.homing_speed_zero = value(0x6099, 2) / self._velocity_per_rad_s
        self.supported_modes = value(0x6502)

    # -- CiA 402 ----------------------------------------------------------------------------------------------

    def statusword(self) -> int:
        state = self.state
        word = _STATE_BITS[state] | _REMOTE
        if state in (READY, SWITCHED_ON, OPERATION_ENABLED, QUICK_STOP):
            word |= _VOLTAGE_ENABLED
        if state in (READY, SWITCHED_ON, OPERATION_ENABLED):
            word |= _QUICK_STOP_OFF
        if state == QUICK_STOP and self._stopped:
            word |= _TARGET_REACHED
        if state == OPERATION_ENABLED:
            if self.limited:
                word |= _INTERNAL_LIMIT
            mode = self.mode_display
            if mode in (CSP, CSV, CST):
                word |= _BIT12  # the drive follows the command value
                if mode == CSP and self._following_error():
                    word |= _BIT13
            elif mode == HOMING:
                word |= self._homing_bits()
        return word

    def _homing_bits(self) -> int:
        homing = self.homing_state
        if homing == "moving":
            return 0
        if homing == "attained":
            return _BIT12 | _TARGET_REACHED
        if homing == "error":
            return _BIT13 | (_TARGET_REACHED if abs(self.velocity) < _STANDSTILL else 0)
        return _TARGET_REACHED  # interrupted or not started

    def _set_controlword(self, value: int | float) -> None:
        word = int(value)
        previous, self.controlword = self.controlword, word
        state = self.state
        if state in (FAULT, FAULT_REACTION):
            if word & _CW_FAULT_RESET and not previous & _CW_FAULT_RESET:
                self._reset_fault()
            return
        command = word & 0x0F
        if not command & 0x02:  # disable voltage: 7, 9, 10, 12
            if state != SWITCH_ON_DISABLED:
                self._enter(SWITCH_ON_DISABLED)
        elif not command & 0x04:  # quick stop: 7, 10, 11
            if state == OPERATION_ENABLED:
                self._enter(QUICK_STOP)
            elif state in (READY, SWITCHED_ON):
                self._enter(SWITCH_ON_DISABLED)
        elif not command & 0x01:  # shutdown: 2, 6, 8
            if state in (SWITCH_ON_DISABLED, SWITCHED_ON, OPERATION_ENABLED):
                self._enter(READY)
        elif not command & 0x08:  # switch on / disable operation: 3, 5
            if state in (READY, OPERATION_ENABLED):
                self._enter(SWITCHED_ON)
        else:  # enable operation: 3 + 4, 4, 16
            if state == READY:
                self._enter(SWITCHED_ON)
                state = SWITCHED_ON
            if state == SWITCHED_ON or (state == QUICK_STOP and self.quick_stop_option >= 5):
                self._enter(OPERATION_ENABLED)
        if self.state == OPERATION_ENABLED and self.mode_display == HOMING:
            self._homing_control(previous, word)

    def _enter(self, state: str) -> None:
        leaving = self.state
        self.state = state
        if state == OPERATION_ENABLED and leaving != OPERATION_ENABLED:
            self._rearm_watchdog()
            self._following_since = None
            self._hold = self.position
            if self.mode_display == HOMING:
                self.homing_state = "idle"
        elif state == QUICK_STOP:
            self._stopped = False
            if self.quick_stop_option == 0:
                self.state = SWITCH_ON_DISABLED
        if state != OPERATION_ENABLED and self.homing_state == "moving":
            self.homing_state = "interrupted"

    def _brake(self) -> None:
        """Quick Stop Active: brake to standstill, then hold (options 5–7) or switch off (1–3)."""
        if not self._stopped and abs(self.velocity) < _STANDSTILL:
            self._stopped = True
            self._hold = self.position
            if self.quick_stop_option < 5:
                self.state = SWITCH_ON_DISABLED

    def _supported(self, mode: int) -> bool:
        return mode == 0 or bool(self.supported_modes & _MODE_BIT.get(mode, 0))

    def _check_mode(self, value: int | float) -> None:
        """0x6060 by SDO: a mode 0x6502 does not list is refused, and the display stays."""
        if not self._supported(int(value)):
            raise SdoAbortedError(ABORT_VALUE_RANGE)

    def _set_mode_from_pdo(self, value: int | float) -> None:
        """0x6060 (also by RPDO, which cannot be refused: an unsupported mode is ignored and counted)."""
        mode = int(value)
        if not self._supported(mode):
            self.counters["ignored"] += 1
            return
        self.mode = mode
        if mode != self.mode_display:
            self.mode_display = mode
            self._hold = self.position
            if self.homing_state == "moving":
                self.homing_state = "interrupted"
            if mode == HOMING:
                self.homing_state = "idle"

    # -- homing -------------------------------------------------------------------------------------------------

    def _homing_control(self, previous: int, word: int) -> None:
        start = word & _CW_HOMING_START
        if word & _CW_HALT or not start:
            if self.homing_state == "moving":
                self.homing_state = "interrupted"
                self._hold = self.position
            return
        if previous & _CW_HOMING_START and self.homing_state != "idle":
            return  # only a rising edge of bit 4 starts homing
        method = self.homing_method
        if method in (35, 37):
            self._set_home(self.position)
        elif method in (33, 34):
            turn = (self.position - self.index_position) / _TAU
            k = math.floor(turn - 1e-9) if method == 33 else math.ceil(turn + 1e-9)
            self._homing_goal = self.index_position + k * _TAU
            self._homing_speed = self.homing_speed_zero * (1.0 if method == 34 else -1.0)
            self.homing_state = "moving"
        else:
            self.homing_state = "error"

    def _home_step(self) -> None:
        if (self._homing_speed > 0.0) == (self.position >= self._homing_goal):
            self._set_home(self._homing_goal)

    def _set_home(self, position: float) -> None:
        """The shaft at `position` now reads 0x607C."""
        self.origin = position - self.home_offset / self._counts_per_rad
        self._hold = position
        self.homing_state = "attained"

    # -- positions and faults --------------------------------------------------------------------------------------

    def _position_actual(self) -> int:
        return _i32((self.position - self.origin) * self._counts_per_rad)

    def _position_reported(self) -> int:
        if not self.glitch.active:
            return self._position_actual()
        return _i32((self.glitch.corrupt(0, self.position) - self.origin) * self._counts_per_rad)

    def _position_demand(self) -> int:
        if self.state == OPERATION_ENABLED and self.mode_display == CSP:
            return self.target_position
        return self._position_actual()

    def _following_error(self) -> bool:
        window = self.following_window
        return window != _NO_WINDOW and abs(self.target_position - self._position_actual()) > window

    def _check_following_error(self, now: float) -> None:
        if not self._following_error():
            self._following_since = None
            return
        if self._following_since is None:
            self._following_since = now
        if now - self._following_since >= self.following_timeout - TIME_TOLERANCE and (
            now > self._following_since or self.following_timeout == 0.0
        ):
            self._fault(EMCY_FOLLOWING_ERROR)

    def _fault(self, code: int) -> None:
        self.state = FAULT  # the fault reaction (0x605E) is immediate: torque off
        self.applied_torque = 0.0
        if self.homing_state == "moving":
            self.homing_state = "error"
        self.error_code = code
        self._record_error(code)
        self._rearm_watchdog()
        self._emcy(code)

    def _reset_fault(self) -> None:
        if self.temperature_rotor > self.over_temperature or self.temperature_mos > self.over_temperature:
            return  # the cause persists
        self.state = SWITCH_ON_DISABLED
        self.error_code = 0
        self.error_register = 0
        self._emcy(EMCY_RESET)
