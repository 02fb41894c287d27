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
import struct
from collections.abc import Callable, Sequence

import can
import numpy as np

from drivers.can.bus import bits_per_second, rtr_bits
from drivers.can.component import CanComponent
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
_GET_TORQUES = struct.Struct("<ff")  # 0.6 Get_Torques: torque target, torque estimate (Nm)


def _mode_for(kp: float, kd: float) -> int:
    if kp > 0.0:
        return ControlMode.POSITION_CONTROL
    if kd > 0.0:
        return ControlMode.VELOCITY_CONTROL
    return ControlMode.TORQUE_CONTROL


def _problems(params: ODriveCanParams, joints: Sequence[str]) -> list[str]:
    problems = []
    missing = [j for j in joints if j not in params.axes]
    if missing:
        problems.append(f"no axis configured for joints {missing}")
    extra = [j for j in params.axes if j not in joints]
    if extra:
        problems.append(f"axes configured for joints this component does not drive: {extra}")
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
        self.position = np.zeros(n)
        self.velocity = np.zeros(n)
        self.effort = np.full(n, np.nan)  # only known when the drive sends Get_Torques
        self.temperature = np.full(n, np.nan)
        self.axis_error = np.zeros(n, dtype=np.int64)
        self.axis_state = np.zeros(n, dtype=np.int64)
        self.heartbeats = np.zeros(n, dtype=np.int64)
        self.estimates = np.zeros(n, dtype=np.int64)
        self.expect_closed_loop = np.zeros(n, dtype=bool)
        self._heartbeat_age = np.full(n, np.inf)
        self._estimate_age = np.full(n, np.inf)
        self._new_estimate = np.zeros(n, dtype=bool)
        self._mode = [_NO_MODE] * n
        self._rtr = [odrive.request(node, Cmd.GET_ENCODER_ESTIMATES) for node in self.nodes]

    @property
    def _wait(self) -> float:
        """Heartbeats are cyclic, so a lifecycle wait must span at least one heartbeat timeout."""
        return max(self.params.reply_timeout_ms / 1000.0, self._heartbeat_timeout)

    # ---- lifecycle -------------------------------------------------------------------------------------------
    def configure(self) -> None:
        """Open the bus, see a heartbeat from every axis and read where each one is. Nothing is armed."""
        self.link.open()
        try:
            self.link.drain()
            before_hb = self.heartbeats.copy()
            before_est = self.estimates.copy()
            for k, node in enumerate(self.nodes):  # the heartbeat is cyclic; asking only shortens the wait
                self.link.send_wait(odrive.request(node, Cmd.HEARTBEAT))
                self.link.send_wait(self._rtr[k])
            ok = self.link.collect(
                self._accept,
                lambda: bool(np.all(self.heartbeats > before_hb) and np.all(self.estimates > before_est)),
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
            self._heartbeat_age.fill(0.0)
            for k, joint in enumerate(self.joints):
                if self.axis_error[k]:
                    errors = odrive.describe_errors(int(self.axis_error[k]))
                    self.context.emit_event("error", f"{joint}: axis reports errors at start-up: {errors}")
        except BaseException:
            self.link.close()
            raise

    def activate(self) -> None:
        """Request closed-loop control on every axis, holding where it is; wait for the heartbeats to confirm."""
        self.expect_closed_loop[:] = True
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
        before = self.heartbeats.copy()
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

    def deactivate(self) -> None:
        if self.link.bus is None:
            return
        if self.params.on_deactivate == "hold":
            self.context.emit_event("info", "axes left in closed loop at their last input (on_deactivate: hold)")
            return
        self.expect_closed_loop[:] = False
        for node in self.nodes:
            try:
                self.link.send_wait(odrive.encode_set_axis_state(node, AxisState.IDLE))
            except HardwareError as exc:
                self.context.emit_event("error", f"node {node}: idle request not sent: {exc}")

    # ---- cycle -------------------------------------------------------------------------------------------------
    def read(self, t: float, dt: float, state: JointState) -> None:
        self._heartbeat_age += dt
        self._estimate_age += dt
        self.drain(self._accept)
        np.copyto(state.position, self.position)
        np.copyto(state.velocity, self.velocity)
        np.copyto(state.effort, self.effort)
        np.copyto(state.temperature, self.temperature)
        fresh, hb_limit = state.fresh, self._heartbeat_timeout
        window = -1.0 if self._request_estimates else self._estimate_window
        for k in range(len(self.nodes)):
            estimate_ok = self._new_estimate.item(k) or self._estimate_age.item(k) <= window
            fresh[k] = estimate_ok and self._heartbeat_age.item(k) <= hb_limit
            state.fault[k] = self._fault_code(k)
        self._new_estimate.fill(False)
        self.bad_frames.report(t)

    def _fault_code(self, k: int) -> int:
        code = self.axis_error.item(k)
        axis_state = self.axis_state.item(k)
        if self.expect_closed_loop.item(k) and axis_state != AxisState.CLOSED_LOOP_CONTROL:
            code |= FAULT_NOT_CLOSED_LOOP | axis_state << _STATE_SHIFT
        return code

    def write(self, t: float, dt: float, command: ServoCommand) -> None:
        send, modes = self.link.send, self._mode
        p, v, ff, kp, kd = command.position, command.velocity, command.effort, command.kp, command.kd
        for k, node in enumerate(self.nodes):
            mode = _mode_for(kp.item(k), kd.item(k))
            if mode != modes[k]:
                sent = send(odrive.encode_set_controller_mode(node, mode, InputMode.PASSTHROUGH))
                modes[k] = mode if sent else _NO_MODE
            if mode == ControlMode.POSITION_CONTROL:
                send(odrive.encode_set_input_pos(node, p.item(k) / TAU, v.item(k) / TAU, ff.item(k)))
            elif mode == ControlMode.VELOCITY_CONTROL:
                send(odrive.encode_set_input_vel(node, v.item(k) / TAU, ff.item(k)))
            else:
                send(odrive.encode_set_input_torque(node, ff.item(k)))
            if self._request_estimates:
                send(self._rtr[k])
        self.link.end_cycle()

    def _accept(self, msg: can.Message) -> None:
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
            elif cmd == Cmd.GET_ENCODER_ESTIMATES:
                est = odrive.decode_encoder_estimates(msg.data)
                if not (math.isfinite(est.position) and math.isfinite(est.velocity)):
                    raise FrameError("non-finite encoder estimate")
                self.position[k] = est.position * TAU
                self.velocity[k] = est.velocity * TAU
                self._estimate_age[k] = 0.0
                self._new_estimate[k] = True
                self.estimates[k] += 1
            elif cmd == Cmd.GET_TEMPERATURE:
                temp = odrive.decode_temperature(msg.data)
                self.temperature[k] = max(temp.fet, temp.motor)
            else:
                if len(msg.data) != _GET_TORQUES.size:
                    raise FrameError(f"odrive Get_Torques needs 8 data bytes, got {len(msg.data)}")
                self.effort[k] = _GET_TORQUES.unpack(msg.data)[1]
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
        if self.link.problem is not None:
            if self.params.bus_recovery == "reopen":
                try:
                    self.link.reopen()
                except HardwareError as exc:
                    self.link.latch(str(exc))
            else:
                self.link.clear()
        for _ in range(self._frame_budget):  # heartbeats already received must not re-report the cleared errors
            msg = self.link.poll()
            if msg is None:
                break
            self._accept(msg)
        for k, node in enumerate(self.nodes):
            if self.axis_error[k]:
                self.link.send(odrive.encode_clear_errors(node))
                self.axis_error[k] = 0  # the next heartbeat says what is left

    def enable(self, joint: str | None = None) -> list[str]:
        """Operator command: request closed loop (holding where the axis is) on one axis or all. Never automatic."""
        targets = list(range(len(self.nodes))) if joint is None else [self._index(joint)]
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

    def _index(self, joint: str) -> int:
        try:
            return self.joints.index(joint)
        except ValueError:
            raise HardwareError(
                f"{self.context.name} drives no joint {joint!r} (joints: {', '.join(self.joints)})"
            ) from None


def _state_name(state: int) -> str:
    try:
        return AxisState(state).name
    except ValueError:
        return f"state {state}"
