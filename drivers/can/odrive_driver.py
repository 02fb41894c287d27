"""``odrive_can``: ODrive axes (firmware 0.6, ODrive Pro / S1) over CAN Simple, one node id per axis.

The servo command maps onto the drive's own cascaded controller, chosen per cycle from the gains the supervisor
filled in (the same convention as an MIT drive: kp > 0 is position control, kp = 0 with kd > 0 velocity control,
kp = kd = 0 torque control):

* position → ``Set_Input_Pos`` (rev) with velocity (rev/s) and torque (Nm) feed-forward;
* velocity → ``Set_Input_Vel`` with torque feed-forward;
* effort → ``Set_Input_Torque``.

``kp`` and ``kd`` themselves are **not sent**: the drive uses its own position/velocity gains (``pos_gain``,
``vel_gain``, tuned on the drive), so ``COMMAND_FIELDS`` offers position, velocity and effort only. A mode change
sends ``Set_Controller_Mode`` once (passthrough input mode). Actuator space is the drive's: radians of its encoder
(rev × 2π).

Feedback: encoder estimates (rev → rad) requested by RTR every cycle, or sent cyclically by the drive
(``encoder_rate_ms``); the heartbeat carries the axis error bits and state. An axis whose heartbeat stops for
``heartbeat_timeout`` is stale; error bits are its fault code, and an axis that leaves closed-loop control while it
should be in it (disarmed by a fault, watchdog or reboot) gets ``FAULT_NOT_CLOSED_LOOP`` with the state it reports.
``clear_faults`` (operator reset) sends ``Clear_Errors`` and never re-arms: closed loop is requested at activate and
by the explicit operator command ``enable``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import can

from drivers.can.bus import bits_per_second, rtr_bits
from drivers.can.component import CanComponent, FeedForwardClamp, coverage_problems
from drivers.can.params import ODriveCanParams
from drivers.can.protocol import odrive
from drivers.can.protocol.errors import FrameError
from drivers.can.protocol.odrive import AxisState, Cmd, ControlMode, InputMode
from hild.arrays import JointState, ServoCommand
from hild.config.params import Params
from hild.hardware import BusUsage, Finding, HardwareContext, HardwareError

__all__ = ["FAULT_NOT_CLOSED_LOOP", "ODriveCanDriver"]

TAU = 2.0 * math.pi
FAULT_NOT_CLOSED_LOOP = 1 << 32
"""Fault bit: the axis is not in CLOSED_LOOP_CONTROL although it should be; bits 33.. carry the reported state."""
_STATE_SHIFT = 33
_ERROR_MASK = 0xFFFF_FFFF
_NO_MODE = -1
_USED_CMDS = frozenset({Cmd.HEARTBEAT, Cmd.GET_ENCODER_ESTIMATES, Cmd.GET_TEMPERATURE, Cmd.GET_TORQUES})
# Frames an axis sends on its own or as getter answers; the ones not used above are skipped, not counted as bad.
_DRIVE_CMDS = _USED_CMDS | {
    Cmd.GET_VERSION,
    Cmd.GET_ERROR,
    Cmd.TX_SDO,
    Cmd.ADDRESS,
    Cmd.GET_IQ,
    Cmd.GET_BUS_VOLTAGE_CURRENT,
    Cmd.GET_POWERS,
}
_INF = math.inf
_ESTIMATES = odrive.ENCODER_ESTIMATES.layout.unpack
_PACK_INPUT_POS, _PACK_INPUT_VEL = odrive.SET_INPUT_POS.pack, odrive.SET_INPUT_VEL.pack
_PACK_INPUT_TORQUE = odrive.SET_INPUT_TORQUE.pack
# Plain ints for the cycle (an IntEnum member is a class-attribute lookup and compares through int anyway).
_POSITION_CONTROL = int(ControlMode.POSITION_CONTROL)
_VELOCITY_CONTROL = int(ControlMode.VELOCITY_CONTROL)
_TORQUE_CONTROL = int(ControlMode.TORQUE_CONTROL)
_CLOSED_LOOP = int(AxisState.CLOSED_LOOP_CONTROL)


def _all_grew(counts: list[int], before: list[int]) -> bool:
    return all(now > then for now, then in zip(counts, before, strict=True))


def _problems(params: ODriveCanParams, joints: Sequence[str]) -> list[str]:
    problems = coverage_problems("axis", "axes", params.axes, joints)
    seen: dict[int, str] = {}
    for joint, axis in params.axes.items():
        if axis.node_id in seen:
            problems.append(f"{joint}: node id {axis.node_id} is also used by {seen[axis.node_id]}")
        seen.setdefault(axis.node_id, joint)
    if params.bus.fd:
        problems.append("bus.fd: ODrive CAN Simple runs on classic CAN frames")
    if params.heartbeat_timeout * 1000.0 <= params.heartbeat_rate_ms:
        problems.append(
            f"heartbeat_timeout_ms {params.heartbeat_timeout * 1000.0:g} must exceed heartbeat_rate_ms "
            f"{params.heartbeat_rate_ms:g}"
        )
    return problems


class ODriveCanDriver(CanComponent):
    """ODrive axes on one CAN bus; the drive runs its own gains (kp/kd of the servo command are not sent)."""

    Params = ODriveCanParams
    COMMAND_FIELDS = frozenset({"position", "velocity", "effort"})
    APPLIES_GAINS = False  # position mode runs the axis's own pos_gain/vel_gain: hild's kp/kd never reach it

    # ---- config review (class level) -----------------------------------------------------------------------
    @classmethod
    def review(cls, params: Params, joints: Sequence[str], update_rate: float) -> list[Finding]:
        assert isinstance(params, ODriveCanParams)
        findings = [Finding("error", p) for p in _problems(params, joints)]
        period_ms = 1000.0 / update_rate
        if params.encoder_rate_ms > period_ms * 1.0001:
            findings.append(
                Finding(
                    "warning",
                    f"encoder_rate_ms {params.encoder_rate_ms:g} is slower than the cycle ({period_ms:g} ms): "
                    "feedback is reused between estimates",
                )
            )
        return findings

    @classmethod
    def bus_usage(cls, params: Params, joints: Sequence[str], update_rate: float) -> list[BusUsage]:
        """Per axis and cycle one 8-byte input frame plus the estimates (RTR + reply, or cyclic); heartbeats."""
        assert isinstance(params, ODriveCanParams)
        n = len(params.axes)
        frames = [(8, n * update_rate), (8, n * 1000.0 / params.heartbeat_rate_ms)]
        if params.encoder_rate_ms > 0.0:
            frames.append((8, n * 1000.0 / params.encoder_rate_ms))
            rtr = 0.0
        else:
            frames.append((8, n * update_rate))
            rtr = n * update_rate * rtr_bits()
        bps = bits_per_second(params.bus, frames) + rtr
        ids = frozenset(
            odrive.arbitration_id(a.node_id, cmd) for a in params.axes.values() for cmd in range(1 << odrive.CMD_BITS)
        )
        return [BusUsage(params.bus.name, bps, float(params.bus.bitrate), ids)]

    # ---- construction --------------------------------------------------------------------------------------
    def __init__(self, context: HardwareContext, params: ODriveCanParams) -> None:
        problems = _problems(params, context.joints)
        if problems:
            raise HardwareError(f"{context.name}: " + "; ".join(problems))
        super().__init__(context, params, len(context.joints))
        self.params: ODriveCanParams = params
        self.nodes = [params.axes[j].node_id for j in context.joints]
        self._axis_of = {node: k for k, node in enumerate(self.nodes)}
        n = len(self.nodes)
        self._request_estimates = params.encoder_rate_ms == 0.0
        self._estimate_window = params.encoder_rate_ms / 1000.0 + context.period
        self._heartbeat_timeout = params.heartbeat_timeout
        # Per-axis bookkeeping as plain lists: frames update single elements, which a list does far cheaper than
        # a numpy array; read copies them into the state once per cycle.
        self.position = [0.0] * n
        self.velocity = [0.0] * n
        self.effort = [math.nan] * n  # only known when the drive sends Get_Torques
        self.temperature = [math.nan] * n
        self.axis_error = [0] * n
        self.axis_state = [0] * n
        self.heartbeats = [0] * n
        self.estimates = [0] * n
        self.expect_closed_loop = [False] * n
        self._heartbeat_age = [math.inf] * n
        self._estimate_age = [math.inf] * n
        self._new_estimate = [False] * n
        self._fresh = [False] * n
        self._fault = [0] * n
        self._mode = [_NO_MODE] * n
        self._rtr = [odrive.request(node, Cmd.GET_ENCODER_ESTIMATES) for node in self.nodes]
        # One frame per axis and input command, refilled in place by write.
        self._input_pos = [odrive.SET_INPUT_POS.frame(node) for node in self.nodes]
        self._input_vel = [odrive.SET_INPUT_VEL.frame(node) for node in self.nodes]
        self._input_torque = [odrive.SET_INPUT_TORQUE.frame(node) for node in self.nodes]
        # Set_Input_Pos carries torque_ff as int16 × 0.001: ±32.767 N·m, saturated silently by the codec.
        ff_max = odrive.FEED_FORWARD.hi * odrive.FEED_FORWARD.scale
        self._ff = FeedForwardClamp(context.emit_event, list(context.joints), [ff_max] * n, "Set_Input_Pos torque_ff")
        self._estimate_ids = {
            odrive.arbitration_id(node, Cmd.GET_ENCODER_ESTIMATES): k for k, node in enumerate(self.nodes)
        }

    @property
    def _wait(self) -> float:
        """Heartbeats are cyclic, so a lifecycle wait must span at least one heartbeat timeout."""
        return max(self.params.reply_timeout_ms / 1000.0, self._heartbeat_timeout)

    # ---- lifecycle -------------------------------------------------------------------------------------------
    def on_configure(self) -> None:
        """Open the bus, see a heartbeat from every axis and read where each one is. Nothing is armed."""
        self.link.open()
        try:
            self.link.drain()
            before_hb = list(self.heartbeats)
            before_est = list(self.estimates)
            for k, node in enumerate(self.nodes):  # the heartbeat is cyclic; asking only shortens the wait
                self.link.send_wait(odrive.request(node, Cmd.HEARTBEAT))
                self.link.send_wait(self._rtr[k])
            ok = self.link.collect(
                self._accept,
                lambda: _all_grew(self.heartbeats, before_hb) and _all_grew(self.estimates, before_est),
                self._wait,
            )
            if not ok:
                silent = []
                for k, joint in enumerate(self.joints):
                    seen = (
                        ("heartbeat", self.heartbeats[k] > before_hb[k]),
                        ("estimates", self.estimates[k] > before_est[k]),
                    )
                    missing = [what for what, arrived in seen if not arrived]
                    if missing:
                        silent.append(f"{joint} (node {self.nodes[k]}: no {' and no '.join(missing)})")
                raise HardwareError(f"ODrive axes did not answer on {self.params.bus.name}: {', '.join(silent)}")
            self._heartbeat_age[:] = [0.0] * len(self.nodes)
            for k, joint in enumerate(self.joints):
                if self.axis_error[k]:
                    errors = odrive.describe_errors(int(self.axis_error[k]))
                    self.context.emit_event("error", f"{joint}: axis reports errors at start-up: {errors}")
        except BaseException:
            self.link.close()
            raise

    def on_activate(self) -> None:
        """Request closed-loop control on every axis, holding where it is; wait for the heartbeats to confirm."""
        self.expect_closed_loop[:] = [True] * len(self.nodes)
        targets = []
        for k, joint in enumerate(self.joints):
            if self.axis_error[k]:
                self.context.emit_event(
                    "error",
                    f"{joint}: not armed, axis errors {odrive.describe_errors(int(self.axis_error[k]))}: reset clears "
                    "them, then enable it explicitly",
                )
                continue
            self._arm(k, self.link.send_wait)
            targets.append(k)
        before = list(self.heartbeats)
        for k in targets:
            self.link.send_wait(odrive.request(self.nodes[k], Cmd.HEARTBEAT))

        def armed(k: int) -> bool:
            return bool(
                self.heartbeats[k] > before[k]
                and self.axis_state[k] == AxisState.CLOSED_LOOP_CONTROL
                and self.axis_error[k] == 0
            )

        self.link.collect(self._accept, lambda: all(armed(k) for k in targets), self._wait)
        failed = [
            f"{self.joints[k]} (node {self.nodes[k]}: state {_state_name(int(self.axis_state[k]))}, errors "
            f"{odrive.describe_errors(int(self.axis_error[k]))})"
            for k in targets
            if not armed(k)
        ]
        if failed:
            raise HardwareError(f"ODrive axes did not enter closed-loop control: {', '.join(failed)}")

    def _arm(self, k: int, send: Callable[[can.Message], object]) -> None:
        """Position mode at the measured position, then closed loop: the axis holds where it is."""
        node = self.nodes[k]
        send(odrive.encode_set_controller_mode(node, ControlMode.POSITION_CONTROL, InputMode.PASSTHROUGH))
        send(odrive.encode_set_input_pos(node, float(self.position[k]) / TAU, 0.0, 0.0))
        send(odrive.encode_set_axis_state(node, AxisState.CLOSED_LOOP_CONTROL))
        self._mode[k] = ControlMode.POSITION_CONTROL
        self.expect_closed_loop[k] = True

    def on_deactivate(self) -> None:
        if not self._stopping_limp("axes left in closed loop at their last input"):
            return
        self.expect_closed_loop[:] = [False] * len(self.nodes)
        for node in self.nodes:
            try:
                self.link.send_wait(odrive.encode_set_axis_state(node, AxisState.IDLE))
            except HardwareError as exc:
                self.context.emit_event("error", f"node {node}: idle request not sent: {exc}")

    # ---- cycle -------------------------------------------------------------------------------------------------
    def read(self, t: float, dt: float, state: JointState) -> None:
        hb_age, est_age = self._heartbeat_age, self._estimate_age
        for k in range(len(hb_age)):
            hb_age[k] += dt
            est_age[k] += dt
        self.drain(self._accept)
        state.position[:] = self.position
        state.velocity[:] = self.velocity
        state.effort[:] = self.effort
        state.temperature[:] = self.temperature
        fresh, fault, new_estimate = self._fresh, self._fault, self._new_estimate
        hb_limit = self._heartbeat_timeout
        window = -1.0 if self._request_estimates else self._estimate_window
        for k, (error, axis_state, closed_loop) in enumerate(
            zip(self.axis_error, self.axis_state, self.expect_closed_loop, strict=True)
        ):
            fresh[k] = (new_estimate[k] or est_age[k] <= window) and hb_age[k] <= hb_limit
            if closed_loop and axis_state != _CLOSED_LOOP:
                error |= FAULT_NOT_CLOSED_LOOP | axis_state << _STATE_SHIFT
            fault[k] = error
            new_estimate[k] = False
        state.fresh[:] = fresh
        state.fault[:] = fault
        self.bad_frames.report(t)

    def write(self, t: float, dt: float, command: ServoCommand) -> None:
        send, modes, clamp = self.link.send, self._mode, self._ff
        rtr = self._rtr if self._request_estimates else None
        input_pos, input_vel, input_torque = self._input_pos, self._input_vel, self._input_torque
        pack_pos, pack_vel, pack_torque = _PACK_INPUT_POS, _PACK_INPUT_VEL, _PACK_INPUT_TORQUE
        for k, (node, p, v, ff, kp, kd) in enumerate(
            zip(
                self.nodes,
                command.position.tolist(),
                command.velocity.tolist(),
                command.effort.tolist(),
                command.kp.tolist(),
                command.kd.tolist(),
                strict=True,
            )
        ):
            mode = _POSITION_CONTROL if kp > 0.0 else _VELOCITY_CONTROL if kd > 0.0 else _TORQUE_CONTROL
            if mode != modes[k]:
                sent = send(odrive.encode_set_controller_mode(node, mode, InputMode.PASSTHROUGH))
                modes[k] = mode if sent else _NO_MODE
            if mode == _POSITION_CONTROL:
                msg = input_pos[k]
                pack_pos(msg.data, p / TAU, v / TAU, clamp(k, ff))
            elif mode == _VELOCITY_CONTROL:
                msg = input_vel[k]
                pack_vel(msg.data, v / TAU, ff)
            else:
                msg = input_torque[k]
                pack_torque(msg.data, ff)
            send(msg)
            if rtr is not None:
                send(rtr[k])
        self.link.end_cycle()

    def _accept(self, msg: can.Message) -> None:
        """Encoder estimates, the per-cycle frame, straight away; every other frame through `_accept_other`."""
        k = self._estimate_ids.get(msg.arbitration_id)
        data = msg.data
        if k is None or msg.is_extended_id or msg.is_remote_frame or len(data) != 8:
            self._accept_other(msg)
            return
        position, velocity = _ESTIMATES(data)
        if not (-_INF < position < _INF and -_INF < velocity < _INF):  # NaN fails every comparison
            self.bad_frames.note("corrupted", msg.arbitration_id)
            return
        self.position[k] = position * TAU
        self.velocity[k] = velocity * TAU
        self._estimate_age[k] = 0.0
        self._new_estimate[k] = True
        self.estimates[k] += 1

    def _accept_other(self, msg: can.Message) -> None:
        if msg.is_extended_id:
            self.bad_frames.note("unexpected frame type", msg.arbitration_id)
            return
        node, cmd = odrive.split_id(msg.arbitration_id)
        k = self._axis_of.get(node)
        if k is None:
            self.bad_frames.note("unknown id", msg.arbitration_id)
            return
        if msg.is_remote_frame:
            return  # another host's request; the answer is what we use
        if cmd not in _USED_CMDS:
            if cmd not in _DRIVE_CMDS:  # a command to our axis from another host
                self.bad_frames.note("unexpected command", msg.arbitration_id)
            return
        try:
            if cmd == Cmd.HEARTBEAT:
                hb = odrive.decode_heartbeat(msg.data)
                self.axis_error[k] = hb.axis_error
                self.axis_state[k] = hb.axis_state
                self._heartbeat_age[k] = 0.0
                self.heartbeats[k] += 1
            elif cmd == Cmd.GET_ENCODER_ESTIMATES:  # `_accept` took every 8-byte one: this decode raises
                odrive.ENCODER_ESTIMATES.decode(msg.data)
            elif cmd == Cmd.GET_TEMPERATURE:
                self.temperature[k] = max(odrive.GET_TEMPERATURE.decode(msg.data))  # (FET, motor) °C
            else:
                self.effort[k] = odrive.GET_TORQUES.decode(msg.data)[1]  # (torque target, torque estimate) N·m
        except FrameError as exc:
            kind = "wrong length" if "bytes" in str(exc) else "corrupted"
            self.bad_frames.note(kind, msg.arbitration_id)

    # ---- reporting and operator commands ------------------------------------------------------------------------
    def describe_fault(self, code: int) -> str:
        parts = []
        errors = code & _ERROR_MASK
        if errors:
            parts.append(f"axis errors {odrive.describe_errors(errors)}")
        if code & FAULT_NOT_CLOSED_LOOP:
            state = _state_name((code >> _STATE_SHIFT) & 0xFF)
            parts.append(
                f"axis in {state}, not CLOSED_LOOP_CONTROL (disarmed or rebooted); it is not re-armed "
                "automatically: enable it explicitly"
            )
        return "; ".join(parts) or "no fault"

    def clear_faults(self) -> None:
        """Operator reset: recover the bus per ``bus_recovery``; Clear_Errors to axes with errors. Never re-arms."""
        self.recover_bus(self._accept)
        for k, node in enumerate(self.nodes):
            if self.axis_error[k]:
                self.link.send(odrive.encode_clear_errors(node))
                self.axis_error[k] = 0  # the next heartbeat says what is left

    def enable(self, joint: str | None = None) -> list[str]:
        """Operator command: request closed loop (holding where the axis is) on one axis or all. Never automatic."""
        targets = self._joint_indices(joint)
        faulted = [self.joints[k] for k in targets if self.axis_error[k]]
        if faulted:
            raise HardwareError(f"axes {faulted} report errors: reset first (it sends Clear_Errors)")
        for k in targets:
            sent: list[bool] = []
            self._arm(k, lambda msg, sent=sent: sent.append(self.link.send(msg)))
            if not all(sent):
                raise HardwareError(
                    f"{self.joints[k]}: arming frames not sent ({self.link.problem or 'send queue full'})"
                )
        return [self.joints[k] for k in targets]


def _state_name(state: int) -> str:
    try:
        return AxisState(state).name
    except ValueError:
        return f"state {state}"
