"""Emulated ODrive axis speaking CAN Simple, firmware 0.6.

Behaviour copied from the firmware: boots IDLE; heartbeat and encoder estimates go out cyclically at their
configured periods without being asked; getters answer RTR frames; Set_Axis_State(CLOSED_LOOP_CONTROL) arms only
when no error is active and latches input_pos to the current position (so arming never jumps); Set_Input_* write
the input registers the cascaded controller reads according to its control mode; the watchdog, fed by every
frame addressed to the axis, disarms with WATCHDOG_TIMER_EXPIRED; errors stay until Clear_Errors and never re-arm
the axis by themselves.

Units: the plant works in rad and rad/s; the axis reports turns (rev) and rev/s, torque in Nm.
"""

from __future__ import annotations

import math

import can

from drivers.can.emulator.base import MotorFirmware, ThermalModel
from drivers.can.protocol import odrive as od
from drivers.can.protocol.odrive import AxisState, Cmd, ControlMode, InputMode, ODriveError, ProcedureResult

_TAU = 2.0 * math.pi
_TIME_TOLERANCE = 1e-9
_CALIBRATION_STATES = frozenset(
    {
        AxisState.STARTUP_SEQUENCE,
        AxisState.FULL_CALIBRATION_SEQUENCE,
        AxisState.MOTOR_CALIBRATION,
        AxisState.ENCODER_INDEX_SEARCH,
        AxisState.ENCODER_OFFSET_CALIBRATION,
        AxisState.ENCODER_DIR_FIND,
        AxisState.ENCODER_HALL_POLARITY_CALIBRATION,
        AxisState.ENCODER_HALL_PHASE_CALIBRATION,
    }
)


class ODriveFirmware(MotorFirmware):
    """One ODrive axis (= one CAN node).

    Controller: vel_setpoint = pos_gain·(input_pos − pos) + input_vel (position mode, clamped to ±vel_limit);
    torque = vel_gain·(vel_setpoint − vel) + input_torque, clamped to ±torque_limit. Calibration requests finish
    at once with SUCCESS. Periods of 0 switch a cyclic message off; `watchdog_timeout` 0 disables the watchdog.
    """

    def __init__(
        self,
        node_id: int,
        *,
        heartbeat_period: float = 0.1,
        encoder_period: float = 0.01,
        watchdog_timeout: float = 0.0,
        control_mode: ControlMode = ControlMode.POSITION_CONTROL,
        input_mode: InputMode = InputMode.PASSTHROUGH,
        pos_gain: float = 20.0,
        vel_gain: float = 0.16,
        vel_limit: float = 10.0,
        torque_limit: float = 10.0,
        keep_position_on_reboot: bool = True,
        seed: int = 0,
        thermal: ThermalModel | None = None,
    ) -> None:
        super().__init__(rated_torque=torque_limit / 3.0, seed=seed, thermal=thermal)
        if not 0 <= node_id <= od.MAX_NODE:
            raise ValueError(f"ODrive node id must be 0..{od.MAX_NODE}, got {node_id}")
        self.node_id = node_id
        self.heartbeat_period = heartbeat_period
        self.encoder_period = encoder_period
        self.watchdog_timeout = watchdog_timeout
        self.configured_modes = (ControlMode(control_mode), InputMode(input_mode))
        self.pos_gain = pos_gain
        self.vel_gain = vel_gain
        self.vel_limit = vel_limit
        self.torque_limit = torque_limit
        self.keep_position_on_reboot = keep_position_on_reboot
        self.bus_voltage = 24.0
        self.position_offset = 0.0
        """rev subtracted from the shaft position (Set_Absolute_Position, reboot without absolute encoder)."""
        self._boot()

    def _boot(self) -> None:
        self.axis_state = AxisState.IDLE
        self.axis_error = 0
        self.disarm_reason = 0
        self.procedure_result = ProcedureResult.SUCCESS
        self.control_mode, self.input_mode = self.configured_modes
        self.input_pos = 0.0
        self.input_vel = 0.0
        self.input_torque = 0.0
        self.applied_torque = 0.0
        self._last_feed = 0.0
        self._next_heartbeat: float | None = None
        self._next_encoder: float | None = None

    # -- MotorFirmware -----------------------------------------------------------------------------------------

    @property
    def enabled(self) -> bool:
        return self.axis_state == AxisState.CLOSED_LOOP_CONTROL

    @property
    def fault(self) -> int:
        return self.axis_error

    @property
    def pos_estimate(self) -> float:
        """rev"""
        return self.position / _TAU - self.position_offset

    @property
    def vel_estimate(self) -> float:
        """rev/s"""
        return self.velocity / _TAU

    def accepts(self, msg: can.Message) -> bool:
        return (
            not msg.is_extended_id
            and not msg.is_error_frame
            and od.split_id(msg.arbitration_id)[0] == self.node_id
            and msg.arbitration_id <= 0x7FF
        )

    def torque(self, position: float, velocity: float) -> float:
        if self.axis_state != AxisState.CLOSED_LOOP_CONTROL:
            self.applied_torque = 0.0
            return 0.0
        pos = position / _TAU - self.position_offset
        vel = velocity / _TAU
        mode = self.control_mode
        if mode == ControlMode.TORQUE_CONTROL:
            tau = self.input_torque
        elif mode in (ControlMode.POSITION_CONTROL, ControlMode.VELOCITY_CONTROL):
            vel_setpoint = self.input_vel
            if mode == ControlMode.POSITION_CONTROL:
                vel_setpoint += self.pos_gain * (self.input_pos - pos)
            limit = self.vel_limit
            vel_setpoint = limit if vel_setpoint > limit else -limit if vel_setpoint < -limit else vel_setpoint
            tau = self.vel_gain * (vel_setpoint - vel) + self.input_torque
        else:
            tau = 0.0  # voltage control is not emulated
        limit = self.torque_limit
        self.applied_torque = limit if tau > limit else -limit if tau < -limit else tau
        return self.applied_torque

    def inject_fault(self, code: int) -> None:
        if code <= 0:
            raise ValueError(f"ODrive errors are a non-zero bit set, got {code}")
        self.axis_error |= code
        self.disarm_reason |= code
        self._disarm()

    def clear_fault(self) -> None:
        self.axis_error = 0
        self.disarm_reason = 0

    def reboot(self) -> None:
        self._pending.clear()
        if not self.keep_position_on_reboot:
            self.position_offset = self.position / _TAU
        self._boot()

    def _over_temperature_fault(self, rotor: bool) -> int:
        return ODriveError.MOTOR_OVER_TEMP if rotor else ODriveError.INVERTER_OVER_TEMP

    def _expire(self, now: float) -> None:
        if self.enabled and self.watchdog_timeout > 0.0 and now - self._last_feed > self.watchdog_timeout:
            self.inject_fault(ODriveError.WATCHDOG_TIMER_EXPIRED)

    def _periodic(self, now: float) -> list[can.Message]:
        out: list[can.Message] = []
        if self.heartbeat_period > 0.0:
            self._next_heartbeat, due = self._schedule(self._next_heartbeat, self.heartbeat_period, now)
            if due:
                out.append(self.heartbeat())
        if self.encoder_period > 0.0:
            self._next_encoder, due = self._schedule(self._next_encoder, self.encoder_period, now)
            if due:
                out.append(self.encoder_estimates())
        return out

    @staticmethod
    def _schedule(next_due: float | None, period: float, now: float) -> tuple[float, bool]:
        """(next due time, send now?) — first message at boot, then every period; a late tick does not burst.

        Due times accumulate in floating point, so a tick within a nanosecond of the due time counts as on time.
        """
        if next_due is None:
            return now + period, True
        if now < next_due - _TIME_TOLERANCE:
            return next_due, False
        next_due += period
        return (next_due if next_due > now else now + period), True

    # -- frames ------------------------------------------------------------------------------------------------

    def heartbeat(self) -> can.Message:
        hb = od.Heartbeat(self.axis_error, int(self.axis_state), int(self.procedure_result), True)
        return od.encode_heartbeat(self.node_id, hb)

    def encoder_estimates(self) -> can.Message:
        pos = self.pos_estimate
        if self.glitch.active:  # a glitching readout, in rad like every other glitch control
            pos = self.glitch.corrupt(0, pos * _TAU) / _TAU
        return od.encode_encoder_estimates(self.node_id, pos, self.vel_estimate)

    def _receive(self, msg: can.Message, now: float) -> list[can.Message]:
        self._last_feed = now
        cmd = od.split_id(msg.arbitration_id)[1]
        if msg.is_remote_frame:
            return self._answer_getter(cmd)
        data = msg.data
        if cmd == Cmd.SET_AXIS_STATE:
            self._request_state(od.decode_set_axis_state(data))
        elif cmd == Cmd.SET_CONTROLLER_MODE:
            control, input_mode = od.decode_set_controller_mode(data)
            if control not in ControlMode._value2member_map_ or input_mode not in InputMode._value2member_map_:
                return self._ignore()
            self.control_mode, self.input_mode = ControlMode(control), InputMode(input_mode)
        elif cmd == Cmd.SET_INPUT_POS:
            self.input_pos, self.input_vel, self.input_torque = od.decode_set_input_pos(data)
        elif cmd == Cmd.SET_INPUT_VEL:
            self.input_vel, self.input_torque = od.decode_set_input_vel(data)
        elif cmd == Cmd.SET_INPUT_TORQUE:
            self.input_torque = od.decode_set_input_torque(data)
        elif cmd == Cmd.CLEAR_ERRORS:
            od.decode_clear_errors(data)
            self.clear_fault()
        elif cmd == Cmd.ESTOP:
            self.inject_fault(ODriveError.ESTOP_REQUESTED)
        elif cmd == Cmd.REBOOT:
            if od.decode_reboot(data) != od.RebootAction.REBOOT:
                return self._ignore()  # save/erase configuration, DFU: nothing to emulate
            self.reboot()
        elif cmd == Cmd.SET_ABSOLUTE_POSITION:
            self.position_offset = self.position / _TAU - od.decode_set_absolute_position(data)
        else:
            return self._ignore()
        return []

    def _answer_getter(self, cmd: int) -> list[can.Message]:
        if cmd == Cmd.HEARTBEAT:
            return [self.heartbeat()]
        if cmd == Cmd.GET_ENCODER_ESTIMATES:
            return [self.encoder_estimates()]
        if cmd == Cmd.GET_ERROR:
            return [od.encode_error(self.node_id, self.axis_error, self.disarm_reason)]
        if cmd == Cmd.GET_TEMPERATURE:
            return [od.encode_temperature(self.node_id, self.temperature_mos, self.temperature_rotor)]
        if cmd == Cmd.GET_BUS_VOLTAGE_CURRENT:
            current = abs(self.applied_torque * self.vel_estimate * _TAU) / self.bus_voltage
            return [od.encode_bus_voltage_current(self.node_id, self.bus_voltage, current)]
        return self._ignore()

    def _request_state(self, requested: int) -> None:
        if requested == AxisState.IDLE:
            self._disarm()
        elif requested == AxisState.CLOSED_LOOP_CONTROL:
            if self.axis_error:
                self.procedure_result = ProcedureResult.DISARMED
                return  # an active error refuses arming; the host must clear errors first
            self.input_pos = self.pos_estimate
            self.input_vel = 0.0
            self.input_torque = 0.0
            self.axis_state = AxisState.CLOSED_LOOP_CONTROL
            self.procedure_result = ProcedureResult.SUCCESS
        elif requested in _CALIBRATION_STATES:
            self._disarm()
            self.procedure_result = ProcedureResult.SUCCESS if not self.axis_error else ProcedureResult.DISARMED
        else:
            self.counters["ignored"] += 1

    def _disarm(self) -> None:
        self.axis_state = AxisState.IDLE
        self.applied_torque = 0.0
