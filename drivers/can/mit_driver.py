"""``mit_can``: MIT-protocol CAN servos — Damiao DM-J, T-Motor/CubeMars AK (MIT mode), MyActuator motion mode.

One component owns one bus. Every cycle ``write`` sends one MIT command frame per motor (hild's servo command is
the drive's native command, quantised with the motor's ranges: docs/architecture.md, "The servo command") and
``read`` drains the replies without blocking: newest reply per motor wins, a motor without a reply this cycle is
reported ``fresh = False`` (the supervisor turns that into a stale-feedback fault after
``safety.stale_feedback_cycles``), drive faults become fault codes, and frames that fit nothing are counted and
summarised in rate-limited events.

Start-up never moves the arm:
* configure opens the bus; on Damiao it reads PMAX/VMAX/TMAX and CTRL_MODE of every motor and refuses to start on
  a mismatch with the configured ranges (both ends must scale identically), then writes the TIMEOUT watchdog.
* It then asks every motor for one feedback frame before anything is enabled: Damiao gets the register-channel
  refresh (0x7FF, 0xCC), which only answers. T-Motor gets an MIT frame with kp = kd = 0 and zero feed-forward,
  which a drive in rest mode answers without acting on (and which would mean "no torque" if it were in motor
  mode). MyActuator motion mode has no rest mode — every motion frame runs the motor — so the same zero-gain frame
  makes it produce no torque (≤ 1 LSB, t_max/4095, since 0 Nm is not representable): what a disabled drive does.
  Motors that do not answer are listed in the HardwareError.
* activate sends the enable frame (Damiao/T-Motor 0xFC; MyActuator motion mode has none) and waits for replies.

Faults: a drive fault (Damiao status nibble, T-Motor error byte, MyActuator error flags read with the native
status command every ``status_poll_ms``) is reported as its code; a Damiao motor that reports *disabled* while it
should be enabled (it rebooted, or its fault was cleared) is ``FAULT_DISABLED``. T-Motor and MyActuator replies do
not say whether the drive is enabled, so their reboots cannot be seen in the replies. ``clear_faults`` (operator
reset) sends clear-error where the firmware has one and never re-enables: that is the separate, explicit
``enable`` operator command, like ``set_zero``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import can
import numpy as np

from drivers.can.bus import bits_per_second
from drivers.can.component import CanComponent, FeedForwardClamp
from drivers.can.params import MitCanParams
from drivers.can.protocol import damiao_registers as reg
from drivers.can.protocol.errors import FrameError
from drivers.can.protocol.flavours import FLAVOURS, MitFlavour
from drivers.can.protocol.mit import command_encoder
from drivers.can.wiring import MotorWiring, wire_motors
from hild.arrays import JointState, ServoCommand
from hild.config.params import Params
from hild.hardware import ALL_COMMAND_FIELDS, BusUsage, Finding, GainRange, HardwareContext, HardwareError

__all__ = ["FAULT_DISABLED", "MitCanDriver", "MotorWiring", "wire_motors"]

FAULT_DISABLED = 0x1_0000
"""Fault code: the motor reports disabled while it should be enabled (above every vendor's own 16-bit codes)."""

DEFAULT_TIMEOUT_MS = 100.0
"""The CAN watchdog written to drives that keep it in a register (``timeout_ms``)."""
DEFAULT_STATUS_POLL_MS = 100.0
"""How often each motor's status is polled where replies do not carry it (``status_poll_ms``)."""
# Commands that change a drive's state (enable, clear-error; disable at shutdown) are repeated until its replies
# confirm them, as the vendors' own examples do (Damiao: 5× at 2 ms): a lost frame must not leave a drive on.
REPEAT_TRIES = 5
# Between two tries: the replies that may still show the old state (queued in the adapter and the kernel, or sent
# before the frame reached the drive: tens of ms on a USB adapter or the loopback bus), or this many cycles when
# the drive does not answer. A drive that still reports a cleared error after every try did not clear it.
REPLIES_PER_TRY = 10
CYCLES_PER_TRY = 10


@dataclass(slots=True)
class Repeated:
    """A state-changing frame sent to one motor and repeated until its replies confirm it (or the tries run out)."""

    kind: str  # "clear-error" or "enable"
    frame: can.Message
    tries_left: int
    code: int = 0  # clear-error: the code being cleared
    replies: int = 0  # replies since the last send
    cycles: int = 0  # write cycles since the last send


class MitCanDriver(CanComponent):
    """MIT-protocol servos on one CAN bus. All five servo-command fields go to the drive."""

    Params = MitCanParams
    COMMAND_FIELDS = ALL_COMMAND_FIELDS

    # ---- config review (class level) -----------------------------------------------------------------------
    @classmethod
    def review(cls, params: Params, joints: Sequence[str], update_rate: float) -> list[Finding]:
        assert isinstance(params, MitCanParams)
        _, problems = wire_motors(params, joints)
        findings = [Finding("error", p) for p in problems]
        if FLAVOURS[params.flavour].registers:
            timeout_ms = _timeout_ms(params)
            period_ms = 1000.0 / update_rate
            if timeout_ms == 0.0:
                findings.append(
                    Finding("warning", "timeout_ms 0 disables the Damiao watchdog: a dead host leaves motors running")
                )
            elif timeout_ms < 2.0 * period_ms:
                findings.append(
                    Finding("error", f"timeout_ms {timeout_ms:g} is below two cycles ({2 * period_ms:g} ms)")
                )
            elif timeout_ms < 5.0 * period_ms:
                findings.append(Finding("warning", f"timeout_ms {timeout_ms:g} leaves under 5 cycles of slack"))
            if params.on_deactivate == "hold" and timeout_ms > 0.0:
                findings.append(
                    Finding("warning", "on_deactivate: hold lasts only until the Damiao watchdog disables the motors")
                )
        return findings

    @classmethod
    def gain_ranges(cls, params: Params, joints: Sequence[str]) -> dict[str, GainRange]:
        """The MIT frame carries kp and kd on 12 bits up to the model's kp_max / kd_max: beyond, the codec clamps."""
        assert isinstance(params, MitCanParams)
        wiring, _ = wire_motors(params, joints)
        return {m.joint: GainRange(m.ranges.kp_max, m.ranges.kd_max) for m in wiring}

    @classmethod
    def bus_usage(cls, params: Params, joints: Sequence[str], update_rate: float) -> list[BusUsage]:
        """One command and one (worst case 8-byte) reply per motor per cycle; status polls on top."""
        assert isinstance(params, MitCanParams)
        flavour = FLAVOURS[params.flavour]
        wiring, _ = wire_motors(params, joints)
        n = len(wiring)
        frames = [(8, n * update_rate), (8, n * update_rate)]
        poll_ms = _status_poll_ms(params)
        if poll_ms > 0.0:
            frames.append((8, 2 * n * 1000.0 / poll_ms))  # request + reply per motor per poll period
        bps = bits_per_second(params.bus, frames)
        ids = {m.command_id for m in wiring} | {m.reply_id for m in wiring}
        ids |= {native for m in wiring for native in flavour.native_ids(m.id)}
        return [BusUsage(params.bus.name, bps, float(params.bus.bitrate), frozenset(ids))]

    # ---- construction --------------------------------------------------------------------------------------
    def __init__(self, context: HardwareContext, params: MitCanParams) -> None:
        wiring, problems = wire_motors(params, context.joints)
        if problems:
            raise HardwareError(f"{context.name}: " + "; ".join(problems))
        super().__init__(context, params, len(wiring))
        self.params: MitCanParams = params
        self.flavour: MitFlavour = FLAVOURS[params.flavour]
        self.motors = wiring
        n = len(wiring)
        self._lengths = self.flavour.reply_lengths
        mask = self.flavour.motor_key_mask
        self._key_mask = mask
        self._routes: dict[int, dict[int, int]] = {}  # reply id → motor key (D0 & mask) → motor index
        for k, m in enumerate(wiring):
            self._routes.setdefault(m.reply_id, {})[m.id & mask] = k
        # The same routes under one int key (reply id << 8 | motor key): one dict lookup per frame in the cycle.
        self._route = {reply_id << 8 | key: k for reply_id, keys in self._routes.items() for key, k in keys.items()}
        self._decoders = [self.flavour.reply_decoder(m.ranges, m.id) for m in wiring]
        self._encoders = [command_encoder(m.ranges) for m in wiring]
        joints = [m.joint for m in wiring]
        self._ff = FeedForwardClamp(context.emit_event, joints, [m.ranges.t_max for m in wiring], "t_ff field")
        self._status_replies: dict[int, int] = {}  # status reply id → motor, where the status is polled
        self._status_requests: list[can.Message] = []
        poll_ms = _status_poll_ms(params)
        self._status_interval = poll_ms / 1000.0 / n if poll_ms > 0.0 else 0.0  # one motor per interval
        self._status_due = 0.0
        self._status_next = 0
        if self.flavour.polls_status:
            self._status_replies = {self.flavour.status_reply_id(m.id): k for k, m in enumerate(wiring)}
            self._status_requests = [self.link.make_message(*self.flavour.status_request(m.id)) for m in wiring]
        # Newest feedback per motor (actuator space), written by _accept, copied into the state by read. Plain
        # lists, not numpy arrays: a frame updates single elements, where a list store costs a fraction of a numpy
        # scalar store; read copies each list into the state array once per cycle.
        self.position = [0.0] * n
        self.velocity = [0.0] * n
        self.effort = [0.0] * n
        self.temperature = [math.nan] * n
        self.fault = [0] * n
        self.status_fault = [0] * n  # error flags from the latest status poll
        # Enable / clear-error frames being repeated until the replies confirm them; errors that outlived them.
        self._repeating: list[Repeated | None] = [None] * n
        self._persistent: dict[int, str] = {}  # motor → a drive error still present after every clear-error
        self._replies = [0] * n  # replies accepted per motor since configure
        self.reported_enabled: list[bool | None] = [None] * n  # None: the flavour's replies do not say
        self.expect_enabled = [False] * n
        self._rezero_replies = [0] * n  # replies still due to set-zero's frames, per motor
        self._fresh = [False] * n  # a reply arrived since the last read
        self._all_stale = [False] * n
        # One preallocated command frame per motor; write encodes into its data in place every cycle.
        self._commands = [self.link.make_message(m.command_id, bytes(8)) for m in wiring]

    @property
    def replies(self) -> np.ndarray:
        """Replies accepted per motor since the driver was built (a copy, for tools and tests)."""
        return np.array(self._replies, dtype=np.int64)

    @property
    def _timeout(self) -> float:
        return self.params.reply_timeout_ms / 1000.0

    # ---- lifecycle -------------------------------------------------------------------------------------------
    def on_configure(self) -> None:
        self.link.open()
        try:
            self.link.drain()
            if self.flavour.registers:
                self._check_registers()
            self._read_start_positions()
        except BaseException:
            self.link.close()
            raise

    def _check_registers(self) -> None:
        """Refuse to start when a motor's PMAX/VMAX/TMAX differ from the config or it is not in MIT mode; then
        write the TIMEOUT watchdog (Damiao's register channel)."""
        silent: list[str] = []
        problems: list[str] = []
        counts = reg.timeout_counts(_timeout_ms(self.params) / 1000.0)
        for m in self.motors:
            values = self._register_exchange(m, [reg.read_request(m.id, r) for r in (reg.PMAX, reg.VMAX, reg.TMAX)])
            if values is None:
                silent.append(f"{m.joint} (id {m.id:#x}, reply {m.reply_id:#x})")
                continue
            for rid, name, configured in (
                (reg.PMAX, "PMAX", m.ranges.p_max),
                (reg.VMAX, "VMAX", m.ranges.v_max),
                (reg.TMAX, "TMAX", m.ranges.t_max),
            ):
                device = float(values[rid])
                if not math.isclose(device, configured, rel_tol=1e-5, abs_tol=1e-6):
                    problems.append(
                        f"{m.joint} (id {m.id:#x}): {name} is {device:g} on the motor but {configured:g} in the config "
                        f"(model or ranges); fix the config or the motor's register"
                    )
            mode = self._register_exchange(m, [reg.read_request(m.id, reg.CTRL_MODE)])
            if mode is None:
                silent.append(f"{m.joint} (id {m.id:#x}) for CTRL_MODE")
            elif int(mode[reg.CTRL_MODE]) != reg.CTRL_MODE_MIT:
                problems.append(
                    f"{m.joint} (id {m.id:#x}): CTRL_MODE is {int(mode[reg.CTRL_MODE])}, not MIT (1); "
                    "the motor would ignore MIT commands"
                )
        if silent:
            raise HardwareError(
                f"Damiao motors did not answer register reads: {', '.join(silent)} "
                "(check power, wiring, bitrate, the id and reply_id = the motor's MST_ID)"
            )
        if problems:
            raise HardwareError("; ".join(problems))
        for m in self.motors:
            done = self._register_exchange(m, [reg.write_request(m.id, reg.TIMEOUT, counts)])
            if done is None or int(done[reg.TIMEOUT]) != counts:
                found = "no answer" if done is None else f"it answered {int(done[reg.TIMEOUT])}"
                raise HardwareError(f"{m.joint} (id {m.id:#x}): writing TIMEOUT = {counts} failed ({found})")

    def _register_exchange(self, m: MotorWiring, requests: list[can.Message]) -> dict[int, float] | None:
        """Send register requests one by one; the values answered, or None when the motor stays silent."""
        values: dict[int, float] = {}
        for request in requests:
            rid = request.data[3]

            def handle(msg: can.Message, rid: int = rid) -> None:
                if msg.arbitration_id != m.reply_id or not reg.is_register_reply(msg, m.id):
                    return
                try:
                    esc_id, got, value = reg.decode_register_reply(msg)
                except FrameError:
                    self.bad_frames.note("corrupted register reply", msg.arbitration_id)
                    return
                if esc_id == m.id and got == rid:
                    values[rid] = value

            self.link.send_wait(request)
            if not self.link.collect(handle, lambda rid=rid: rid in values, self._timeout):
                return None
        return values

    def _read_start_positions(self) -> None:
        """One feedback frame per motor before anything is enabled, so hold starts where the arm is."""
        silent = []
        for k, m in enumerate(self.motors):
            before = self._replies[k]
            self.link.send_wait(self.flavour.feedback_request(m.id, m.ranges, self.link.make_message))
            if not self.link.collect(self._accept, lambda k=k, before=before: self._replies[k] > before, self._timeout):
                silent.append(f"{m.joint} (id {m.id:#x}, reply {m.reply_id:#x})")
        if silent:
            raise HardwareError(
                f"motors did not answer on {self.params.bus.name}: {', '.join(silent)} "
                "(check power, wiring, bitrate and ids)"
            )
        for k, m in enumerate(self.motors):
            code = int(self.fault[k])
            if code:
                self.context.emit_event("error", f"{m.joint}: motor reports {self.describe_fault(code)} at start-up")

    def on_activate(self) -> None:
        """Enable every motor and wait for its reply; a motor already reporting a fault is left disabled."""
        self.expect_enabled[:] = [True] * len(self.motors)
        failed = []
        for k, m in enumerate(self.motors):
            code = int(self.fault[k])
            if code and code != FAULT_DISABLED:
                self.context.emit_event(
                    "error",
                    f"{m.joint}: not enabled, the motor reports {self.describe_fault(code)}: reset clears the drive "
                    "error, then enable it explicitly",
                )
                continue
            if not self._enable(k, wait=True):
                failed.append(f"{m.joint} (id {m.id:#x})")
        if failed:
            raise HardwareError(f"motors did not confirm enable: {', '.join(failed)}")

    def _enable(self, k: int, *, wait: bool) -> bool:
        msg = self.flavour.special(self.motors[k].id, "enable", fd=self.params.bus.fd)
        self.expect_enabled[k] = True
        if msg is None:  # MyActuator motion mode: every command frame is obeyed; nothing to switch on
            return True
        if not wait:
            return self._start_repeating(k, "enable", msg)
        reports = self.flavour.reports_enabled
        for _ in range(REPEAT_TRIES):
            before = self._replies[k]
            self.link.send_wait(msg)

            def confirmed(before: int = before) -> bool:
                if self._replies[k] <= before:
                    return False
                return not reports or self.reported_enabled[k] is True or self.fault[k] != 0

            if self.link.collect(self._accept, confirmed, self._timeout / REPEAT_TRIES):
                return self.fault[k] == 0
        return False

    def on_deactivate(self) -> None:
        if not self._stopping_limp("motors left enabled at their last command"):
            return
        self.expect_enabled[:] = [False] * len(self.motors)
        unconfirmed = []
        for k, m in enumerate(self.motors):
            msg = self.flavour.special(m.id, "disable", fd=self.params.bus.fd)
            if msg is None:
                continue
            if not self._disable(k, msg):
                unconfirmed.append(m.joint)
        if unconfirmed:
            self.context.emit_event(
                "error",
                f"disable not confirmed by {unconfirmed} after {REPEAT_TRIES} tries: their own watchdogs must act",
            )

    def _disable(self, k: int, msg: can.Message) -> bool:
        """Send disable until the replies say so, REPEAT_TRIES times at most; a flavour whose replies cannot say
        gets every try (as its vendor's examples do). True when confirmed (or sent every time, unconfirmable)."""
        reports = self.flavour.reports_enabled
        sent = 0
        for _ in range(REPEAT_TRIES):
            before = self._replies[k]
            try:
                self.link.send_wait(msg)
            except HardwareError:
                continue
            sent += 1
            if reports and self.link.collect(
                self._accept,
                lambda before=before: self._replies[k] > before and self.reported_enabled[k] is not True,
                self._timeout / REPEAT_TRIES,
            ):
                return True
        return not reports and sent == REPEAT_TRIES

    # ---- cycle -------------------------------------------------------------------------------------------------
    def read(self, t: float, dt: float, state: JointState) -> None:
        self.drain(self._accept)
        state.position[:] = self.position
        state.velocity[:] = self.velocity
        state.effort[:] = self.effort
        state.temperature[:] = self.temperature
        state.fault[:] = self.fault
        fresh = self._fresh
        state.fresh[:] = fresh
        fresh[:] = self._all_stale
        self.bad_frames.report(t)

    def write(self, t: float, dt: float, command: ServoCommand) -> None:
        send, clamp = self.link.send, self._ff
        for k, (msg, encode, rezeroing, p, v, kp, kd, ff) in enumerate(
            zip(
                self._commands,
                self._encoders,
                self._rezero_replies,
                command.position.tolist(),
                command.velocity.tolist(),
                command.kp.tolist(),
                command.kd.tolist(),
                command.effort.tolist(),
                strict=True,
            )
        ):
            if rezeroing:  # the command was computed in the drive's old frame: no torque until it reports
                encode(msg.data, 0.0, 0.0, 0.0, 0.0, 0.0)
            else:
                encode(msg.data, p, v, kp, kd, clamp(k, ff))
            send(msg)
        if self._repeats:
            self._repeat()
        if self._status_interval:
            self._status_due -= dt
            if self._status_due <= 0.0:
                self._status_due += self._status_interval
                k = self._status_next
                self._status_next = (k + 1) % len(self._status_requests)
                send(self._status_requests[k])
        self.link.end_cycle()

    @property
    def _repeats(self) -> bool:
        return self._repeating.count(None) < len(self._repeating)  # no allocation: this runs every cycle

    def _repeat(self) -> None:
        """Send each unconfirmed frame again once its replies (or cycles) for this try are in; give up after
        REPEAT_TRIES: a clear-error whose code stays is a persistent drive error, named from then on."""
        for k, repeating in enumerate(self._repeating):
            if repeating is None:
                continue
            repeating.cycles += 1
            if repeating.replies < REPLIES_PER_TRY and repeating.cycles < CYCLES_PER_TRY:
                continue
            if repeating.tries_left > 0:
                self.link.send(repeating.frame)
                repeating.tries_left -= 1
                repeating.replies = repeating.cycles = 0
                continue
            self._repeating[k] = None
            joint = self.motors[k].joint
            if repeating.kind == "clear-error":
                words = f"{self.describe_fault(repeating.code)}, still present after clear-error ({REPEAT_TRIES} tries)"
                self._persistent[k] = words
                self.fault[k] = repeating.code
                self.context.emit_event("error", f"{joint}: {words}")
            else:  # the engine's enable confirmation reports the joint; this says how hard the driver tried
                self.context.emit_event("error", f"{joint}: enable not confirmed after {REPEAT_TRIES} tries")

    def _start_repeating(self, k: int, kind: str, frame: can.Message, code: int = 0) -> bool:
        """Send ``frame`` now and keep repeating it from ``write`` until the replies confirm it."""
        self._repeating[k] = Repeated(kind, frame, REPEAT_TRIES - 1, code)
        return self.link.send(frame)

    def confirming(self) -> bool:
        return self._repeats

    def persistent_errors(self) -> dict[str, str]:
        return {self.motors[k].joint: words for k, words in self._persistent.items()}

    def _accept(self, msg: can.Message) -> None:
        """Decode one received frame into the newest-feedback lists, or count why it was ignored.

        The common case, a well-formed reply of one of our motors, costs one dict lookup and the motor's decoder;
        everything else goes to `_sort_out`, which names the reason.
        """
        data = msg.data
        if msg.is_extended_id or msg.is_remote_frame or len(data) not in self._lengths:
            self._sort_out(msg)
            return
        k = self._route.get(msg.arbitration_id << 8 | data[0] & self._key_mask)
        if k is None:
            self._sort_out(msg)
            return
        try:
            p, v, t, enabled, fault, t_mos, t_rotor = self._decoders[k](data)
        except FrameError:
            self.bad_frames.note("corrupted", msg.arbitration_id)
            return
        self.position[k] = p
        self.velocity[k] = v
        self.effort[k] = t
        if t_mos is not None:
            self.temperature[k] = t_mos if t_rotor is None or t_mos >= t_rotor else t_rotor  # the hotter one limits
        elif t_rotor is not None:
            self.temperature[k] = t_rotor
        self.reported_enabled[k] = enabled
        rezero = self._rezero_replies[k]
        if rezero:
            rezero -= 1
            self._rezero_replies[k] = rezero
        repeating = self._repeating[k]
        clearing = False
        if repeating is not None:  # confirmed by this reply, or still waiting (decided in write)
            repeating.replies += 1
            clearing = repeating.kind == "clear-error"
            if clearing:
                if fault == repeating.code:
                    fault = 0  # in flight from before the clear, or still there: known when the tries run out
                else:
                    self._repeating[k] = repeating = None
            elif enabled is not False:  # enabled (or a flavour whose replies cannot say: any reply)
                self._repeating[k] = repeating = None
        elif fault == 0 and self._persistent:
            self._persistent.pop(k, None)
        code = fault or self.status_fault[k]
        if not code and enabled is False and self.expect_enabled[k] and not rezero and not clearing:
            # Off while it should be on (set-zero passes "off" on purpose; a cleared Damiao drive comes back off,
            # which is said once the clear-error is decided). A repeated enable is confirmed by this going away.
            code = FAULT_DISABLED
        self.fault[k] = code
        self._replies[k] += 1
        self._fresh[k] = True

    def _sort_out(self, msg: can.Message) -> None:
        """A frame that is not a well-formed reply of one of our motors: handle it, or count why it was ignored."""
        arbitration_id = msg.arbitration_id
        if msg.is_extended_id or msg.is_remote_frame:
            self.bad_frames.note("unexpected frame type", arbitration_id)
            return
        routes = self._routes.get(arbitration_id)
        if routes is None:
            polled = self._status_replies.get(arbitration_id)
            if polled is not None:
                self._accept_status(polled, msg)
            elif not any(self.flavour.is_ack(msg, m.id) for m in self.motors):
                self.bad_frames.note("unknown id", arbitration_id)
            return
        data = msg.data
        if len(data) not in self._lengths:
            self.bad_frames.note("wrong length", arbitration_id)
            return
        self.bad_frames.note("unexpected motor id", arbitration_id)

    def _accept_status(self, k: int, msg: can.Message) -> None:
        """A frame on a polled motor's status channel: the status (error flags, temperature) or an acknowledgement."""
        try:
            status = self.flavour.decode_status(msg.data)
        except FrameError:
            self.bad_frames.note("wrong length", msg.arbitration_id)
            return
        if status is None:
            return
        self.temperature[k], flags = status
        self.status_fault[k] = flags
        if flags:
            self.fault[k] = flags

    # ---- reporting and operator commands ------------------------------------------------------------------------
    def describe_fault(self, code: int) -> str:
        if code == FAULT_DISABLED:
            return (
                "motor reports disabled while it should be enabled (rebooted, zeroed, or its fault was cleared); "
                "it is not re-enabled automatically: enable it explicitly"
            )
        return self.flavour.explain_fault(code)

    def clear_faults(self) -> None:
        """Operator reset: recover the bus per ``bus_recovery`` and send clear-error to faulted drives.

        A cleared Damiao drive comes back *disabled* and is then reported as ``FAULT_DISABLED`` until the operator
        enables it explicitly: nothing here enables a motor.
        """
        self.recover_bus(self._accept)
        for k, m in enumerate(self.motors):
            code = int(self.fault[k])
            if not code or code == FAULT_DISABLED:
                continue
            msg = self.flavour.special(m.id, "clear", fd=self.params.bus.fd)
            if msg is None:
                self.context.emit_event(
                    "warning", f"{m.joint}: {self.flavour.name} has no clear-error frame; the drive must clear it"
                )
            else:
                self._start_repeating(k, "clear-error", msg, code)
                self._persistent.pop(k, None)
            self.fault[k] = 0  # the drive's replies (or status poll) say what is left once the tries are done
            self.status_fault[k] = 0

    def enable(self, joint: str | None = None) -> list[str]:
        """Operator command: send the enable frame to one motor (or all). Never called automatically.

        Refused for a motor that reports a drive fault (reset first). Returns the joints enabled; the replies of the
        next cycles confirm it (a motor that stays disabled keeps reporting ``FAULT_DISABLED``).
        """
        targets = self._joint_indices(joint)
        stuck = [f"{self.motors[k].joint}: {self._persistent[k]}" for k in targets if k in self._persistent]
        if stuck:
            raise HardwareError(
                f"{'; '.join(stuck)}: it must clear on the drive itself (let it cool, remove the cause), "
                "then reset and enable"
            )
        faulted = [self.motors[k].joint for k in targets if self.fault[k] not in (0, FAULT_DISABLED)]
        if faulted:
            raise HardwareError(f"motors {faulted} report a drive fault: reset first (it clears the drive error)")
        for k in targets:
            if self.flavour.registers:  # a power-cycled drive forgot its RAM watchdog: write it again, unacknowledged
                m = self.motors[k]
                counts = reg.timeout_counts(_timeout_ms(self.params) / 1000.0)
                self.link.send(reg.write_request(m.id, reg.TIMEOUT, counts))
            if not self._enable(k, wait=False):
                raise HardwareError(f"{self.motors[k].joint}: enable frame not sent ({self.link.problem or 'bus'})")
        return [self.motors[k].joint for k in targets]

    def set_zero(self, joint: str) -> None:
        """Operator command: make the motor's present position its zero. Never called automatically.

        Sends *disable*, *zero* and — if the motor was enabled — *enable* back to back: firmwares re-zero only at
        rest (Ben Katz lineage) and a drive that stayed enabled would pull toward its old target in the new frame.
        Every drive answers each of these frames; until those replies are in, the motor gets zero-gain frames
        (no torque) instead of the command, because that command was computed from a reading in the old frame.
        Then hold continues where the joint is, read in the new frame. If the enable does not take, the next
        reply reports ``FAULT_DISABLED``.
        """
        (k,) = self._joint_indices(joint)
        m = self.motors[k]
        fd = self.params.bus.fd
        zero = self.flavour.special(m.id, "zero", fd=fd)
        if zero is None:
            raise HardwareError(f"{joint}: {self.flavour.name} has no set-zero frame")
        frames = [self.flavour.special(m.id, "disable", fd=fd), zero]
        if self.expect_enabled[k]:
            frames.append(self.flavour.special(m.id, "enable", fd=fd))
        pending = 0
        for frame in frames:
            if frame is None:
                continue
            if not self.link.send(frame):
                self._rezero_replies[k] = pending
                why = self.link.problem or "send queue full"
                raise HardwareError(f"{joint}: set-zero interrupted after {pending} of its frames ({why})")
            pending += 1
        self._rezero_replies[k] = pending


def _timeout_ms(params: MitCanParams) -> float:
    return DEFAULT_TIMEOUT_MS if params.timeout_ms is None else params.timeout_ms


def _status_poll_ms(params: MitCanParams) -> float:
    if not FLAVOURS[params.flavour].polls_status:
        return 0.0
    return DEFAULT_STATUS_POLL_MS if params.status_poll_ms is None else params.status_poll_ms
