"""The safety layer between controllers and hardware (docs/architecture.md, "Safety"; docs/safety.md).

Every cycle, whatever the controllers do:

* ``check(state, dt)`` (after read) first passes every reading through the plausibility gate
  (``hild.cycle.plausibility``): a non-finite reading, one outside the hard limits and their margin, a jump no joint
  could make in the time since the last accepted one, or a frozen position is *rejected* — the state then carries the
  last accepted reading, marked not fresh, so nothing downstream ever sees it. Then it detects faults: stale or
  implausible feedback (rejected readings count like missing ones), drive fault codes, overspeed. Faults latch
  until ``reset``.
* ``command(state, ctrl, out)`` (after the controllers) builds the final servo command per joint:
  - **controlled** (an active controller claimed and wrote it this cycle): claimed fields from the controller,
    the rest from the joint's mode defaults (position gains for a position claim, kp = 0 for velocity,
    kp = kd = 0 for effort) plus gravity feed-forward; a claimed effort replaces the feed-forward, unless its
    controller asked for gravity on top (``Controller.gravity_joints``: the effort is then its command plus the
    gravity torque, as a real arm's driver adds it);
  - **hold** (nobody commands it): the position latched when it lost its controller (or at start-up), hold
    gains, gravity feed-forward — never a stale command — plus the ``hold_effort`` its controller last wrote
    (a gripper's grasp: 0 for every other controller);
  - **fault / e-stop**: the configured safe action (hold, damp or disable). A fault latches the last *accepted*
    position; a joint whose position cannot be trusted (its readings are being rejected, or it never had one)
    is never held with a spring: it gets damping only (kp 0, hold kd) and gravity feed-forward from the last
    accepted pose.
  Then limits: soft position limits and velocity limits on controller commands, a slew limit so the commanded
  position never steps by more than ``velocity_limit · dt`` (hold latching included; ``dt`` is the engine's
  clamped cycle time, so a late cycle never catches up in one step), and the predicted drive torque kept within
  ``±effort``. The prediction uses only what the drive applies (``applies_gains``: an ODrive never applies
  hild's kp/kd), and the feed-forward trim may only *take torque away* unless the joint's reading is fresh and
  accepted and the joint is not faulted — so no spring seen through a stand-in reading is ever "compensated".
  A limit that engages is reported once, when it engages and when it releases.

The per-cycle work is a plain loop over joints: each input array is read once into a Python list (one
``tolist()`` per array costs less than an ``item()`` per element), and results are written back into preallocated
arrays in place. For the 2–14 joints of an arm that is several times faster than vectorised numpy (each numpy call
on a six-element array is almost pure overhead), and it reads as what it is: for each joint, decide its mode, build
its command, apply its limits. Besides those short-lived lists, only events allocate, and only on changes.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from hild.arrays import JointState, ServoCommand
from hild.controller import JointLimitArrays
from hild.crossing.events import EventLog
from hild.cycle.plausibility import BEYOND_LIMITS, NONE, FeedbackGate
from hild.interfaces import FIELDS, ClaimMasks
from hild.modes import JointMode


class Fault(enum.IntEnum):
    NONE = 0
    STALE_FEEDBACK = 1
    DRIVE = 2
    HARDWARE = 3
    POSITION_LIMIT = 4
    OVERSPEED = 5
    INVALID_FEEDBACK = 6
    OVERRUN = 7
    COLLISION = 8  # the contact observer's collision level (hild/cycle/contact.py): every joint, the reflex


class Action(enum.IntEnum):
    HOLD = 0
    DAMP = 1
    DISABLE = 2


LIMIT_POSITION, LIMIT_VELOCITY, LIMIT_EFFORT = 1, 2, 4
_LIMIT_WORDS = ((LIMIT_POSITION, "position"), (LIMIT_VELOCITY, "velocity"), (LIMIT_EFFORT, "effort"))


# Plain ints for the per-joint loop (enum attribute lookups cost more than the comparisons they feed).
_FAULT, _CONTROLLED, _HOLD_MODE = int(JointMode.FAULT), int(JointMode.CONTROLLED), int(JointMode.HOLD)
_HOLD, _DAMP = int(Action.HOLD), int(Action.DAMP)
_DAMP_GRAVITY = -1  # not configurable: what a hold becomes when no position can be trusted
_REFLEX = -2  # a collision's: hold at the latched position with the reflex's lowered kp, never pushing on


def limit_names(flags: int) -> list[str]:
    return [word for bit, word in _LIMIT_WORDS if flags & bit]


@dataclass(frozen=True)
class JointGains:
    hold_kp: np.ndarray
    hold_kd: np.ndarray
    position_kp: np.ndarray
    position_kd: np.ndarray
    velocity_kd: np.ndarray


@dataclass(frozen=True)
class SafetySettings:
    stale_feedback_cycles: int
    overspeed_factor: float
    fault_action: Action
    estop_action: Action
    stale_feedback_time: float = 0.0  # s without an accepted reading, on top of the cycle count; 0 = cycles only
    plausibility_margin: float = 0.05  # rad beyond the hard limits a reading may still lie (a joint on its stop)
    plausible_speed_factor: float = 3.0  # × velocity limit: the fastest a reading may move from the last accepted
    plausible_step_tolerance: float = 0.002  # rad added to that bound (encoder quantisation and noise)
    plausible_time_slack: float = 0.0  # s added to the time a reading may have moved over (the engine: one period)


GravityFn = Callable[[np.ndarray, np.ndarray], None]
DescribeFn = Callable[[int, int], str]  # (joint index, drive fault code) → words


class Supervisor:
    def __init__(
        self,
        joints: tuple[str, ...],
        limits: JointLimitArrays,
        gains: JointGains,
        safety: SafetySettings,
        events: EventLog,
        gravity: GravityFn | None = None,
        describe_fault: DescribeFn | None = None,
        applies_gains: np.ndarray | None = None,
    ) -> None:
        """Everything the cycle reads or writes is allocated here, once: ``command`` then allocates nothing."""
        n = len(joints)
        self.joints = joints
        self.limits = limits
        self.gains = gains
        self.safety = safety
        self.events = events
        self.gravity = gravity
        self.describe_fault = describe_fault or (lambda i, code: f"drive fault code {code:#x}")
        self.gate = FeedbackGate(
            joints,
            limits.lower,
            limits.upper,
            limits.velocity,
            margin=safety.plausibility_margin,
            factor=safety.plausible_speed_factor,
            tolerance=safety.plausible_step_tolerance,
            emit=lambda level, text: events.emit(level, "supervisor", text),
            slack=safety.plausible_time_slack,
        )

        # Published state (read by status from other threads; written element-wise, only on change).
        self.mode = np.zeros(n, dtype=np.int64)
        self.latched = np.zeros(n)
        self.fault = np.zeros(n, dtype=np.int64)
        self.fault_text: list[str] = [""] * n
        self.limit_flags = np.zeros(n, dtype=np.int64)
        self.hold_effort = np.zeros(n)  # what a held joint keeps pressing with: its controller's last hold_effort
        self.estop = False
        self.change_seq = 0  # bumped on any mode/fault/limit change: the status publisher watches it
        self.bad_command_owners: list[int] = []  # controller slots that produced invalid commands this cycle

        # Per-joint constants as Python floats: the cycle loop reads them without numpy scalar overhead.
        self._lower, self._upper = limits.lower.tolist(), limits.upper.tolist()
        self._soft_lower, self._soft_upper = limits.soft_lower.tolist(), limits.soft_upper.tolist()
        self._vmax, self._emax = limits.velocity.tolist(), limits.effort.tolist()
        self._overspeed = [v * safety.overspeed_factor for v in self._vmax]
        self._hold_kp, self._hold_kd = gains.hold_kp.tolist(), gains.hold_kd.tolist()
        self._hold_target = (self._hold_kp, self._hold_kd)  # where set_hold_gains is ramping them to
        self._hold_steps = 0  # cycles of that ramp still to go
        # Whether the drive applies the command's kp/kd itself (its torque is then predictable from them).
        self._applies_gains = [True] * n if applies_gains is None else [bool(a) for a in applies_gains]

        self._allocate_cycle_state(n)
        self.set_claims(ClaimMasks.empty(n))

    def _allocate_cycle_state(self, n: int) -> None:
        """The per-joint state only the cycle touches, as Python lists (no numpy scalar overhead in its loop)."""
        # Per-joint claim view, rebuilt at each switch (set_claims).
        self._owner = [-1] * n
        self._gravity_on_effort = [False] * n  # the owner's effort gets the gravity torque added (set_claims)
        self._claims: list[tuple[bool, bool, bool, bool, bool]] = [(False,) * 5] * n  # type: ignore[list-item]
        self._default_kp = [0.0] * n
        self._default_kd = [0.0] * n

        self._safe_action = [Action.HOLD] * n
        self._stale = [0] * n
        self._silent = [0.0] * n  # s without an accepted reading
        self.longest_silence = [0.0] * n  # published: the longest such stretch since start (s), per joint
        self._codes = [0] * n  # the drives' fault codes at the last check
        self.all_fresh = False  # every reading of the last check fresh and accepted (the contact observer's gate)
        self._untrusted_fault = [False] * n  # faulted while its readings were untrusted: damped until reset
        self._relatch = [False] * n  # latch at the next command(): after reset and e-stop
        self._new_frame = [False] * n  # the follow window is a set-zero's: re-anchor the gate on every reading
        self._follow = [0] * n  # cycles left during which hold follows the measured position (after set-zero)
        self._prev_position = np.zeros(n)
        self._g = np.zeros(n)
        self.gravity_torque = self._g  # read-only view for controllers: the last cycle's gravity feed-forward
        self._pose = np.zeros(n)  # where gravity is computed: the accepted positions (0 where none is known)
        self._descent = (0.0, 0.0)  # (s left, s total) of a stop descent; (0, 0) when none runs
        self._reflex_kp = [0.0] * n  # the collision reflex's hold kp (collide)
        self.descent_started = False

    # ---- configuration (between cycles) -------------------------------------------------------------------
    def start(self, state: JointState) -> None:
        """Latch every joint where the first read found it: starting the daemon never moves the arm. A joint
        without a plausible start-up reading has no position (NaN latch): it is damped, never pulled anywhere."""
        self.gate.start(state)
        self.latched[:] = self.gate.accepted_position
        self._prev_position[:] = np.where(np.isfinite(self.latched), self.latched, 0.0)
        self._relatch = [False] * len(self.joints)
        self.mode[:] = JointMode.HOLD

    def set_hold_gains(self, kp: list[float], kd: list[float], cycles: int) -> None:
        """New hold gains (an operator tuning hold stiffness), reached linearly over ``cycles``: a held joint's
        target stays where it is latched, and its torque changes smoothly even with an error in the spring."""
        self._hold_target = (list(kp), list(kd))
        self._hold_steps = max(1, cycles)

    def set_command_limits(self, soft_lower: list[float], soft_upper: list[float], velocity_scale: float) -> str:
        """Tuned soft limits and velocity scale, between two cycles; refused (the reason, nothing changed) if a
        joint's position or held target lies outside its new soft range: clamping it there would move the arm."""
        position, commanded = self.gate.accepted_position.tolist(), self._prev_position.tolist()
        for i, name in enumerate(self.joints):
            for what, value in (("is at", position[i]), ("is commanded to", commanded[i])):
                if not soft_lower[i] <= value <= soft_upper[i]:
                    return (
                        f"{name} {what} {value:.4g} rad, outside the new soft range [{soft_lower[i]:.4g}, "
                        f"{soft_upper[i]:.4g}]: move it inside first"
                    )
        self._soft_lower[:], self._soft_upper[:] = soft_lower, soft_upper
        self._vmax[:] = [v * velocity_scale for v in self.limits.velocity.tolist()]
        self.change_seq += 1
        return ""

    def _ramp_hold_gains(self) -> None:
        steps, (kp, kd) = self._hold_steps, self._hold_target
        for i in range(len(kp)):
            self._hold_kp[i] += (kp[i] - self._hold_kp[i]) / steps
            self._hold_kd[i] += (kd[i] - self._hold_kd[i]) / steps
        self._hold_steps = steps - 1
        if not self._hold_steps:
            self.gains.hold_kp[:], self.gains.hold_kd[:] = kp, kd

    def set_claims(self, masks: ClaimMasks) -> None:
        """Recompute per-joint mode defaults from the active claims (called at each switch)."""
        g = self.gains
        self._owner = masks.owner.tolist()
        self._claims = list(zip(*(getattr(masks, f).tolist() for f in FIELDS), strict=True))
        self._gravity_on_effort = masks.gravity.tolist()
        if self.gravity is None and any(self._gravity_on_effort):
            names = ", ".join(j for j, on in zip(self.joints, self._gravity_on_effort, strict=True) if on)
            self.events.emit(
                "warning",
                "supervisor",
                f"joints {names}: their controller asks for gravity on top of its effort, but the robot has no "
                "gravity model (robot.model, safety.gravity_compensation): the effort is the controller's alone",
            )
        for i, (position, velocity, _, _, _) in enumerate(self._claims):
            if position:
                self._default_kp[i], self._default_kd[i] = float(g.position_kp[i]), float(g.position_kd[i])
            elif velocity:
                self._default_kp[i], self._default_kd[i] = 0.0, float(g.velocity_kd[i])
            else:
                self._default_kp[i], self._default_kd[i] = 0.0, 0.0
        self.change_seq += 1

    # ---- fault detection (after read) ---------------------------------------------------------------------
    def check(self, state: JointState, dt: float) -> None:
        """Gate the readings, then detect faults. ``dt`` is the wall time since the last read: how far a joint
        could have moved, and how long it has been silent."""
        gate = self.gate
        if any(self._new_frame):
            for i, moving in enumerate(self._new_frame):
                if moving:
                    gate.reanchor(i)
                    if not self._follow[i]:
                        self._new_frame[i] = False
        gate.filter(state, dt)
        fresh, codes = state.fresh.tolist(), state.fault.tolist()
        self._codes = codes
        self.all_fresh = False not in fresh
        qd_all = state.velocity.tolist()
        stale, silent, fault, longest = self._stale, self._silent, self.fault, self.longest_silence
        stale_limit, stale_time = self.safety.stale_feedback_cycles, self.safety.stale_feedback_time
        overspeed = self._overspeed
        for i, qd in enumerate(qd_all):
            if fresh[i]:
                stale[i] = 0
                silent[i] = 0.0
                if qd > overspeed[i] or qd < -overspeed[i]:
                    factor = self.safety.overspeed_factor
                    self.trip(i, Fault.OVERSPEED, f"speed above {factor:g}× the velocity limit")
            else:
                stale[i] += 1
                silent[i] += dt
                if silent[i] > longest[i]:
                    longest[i] = silent[i]
                if stale[i] >= stale_limit and silent[i] >= stale_time and not fault.item(i):
                    self._trip_stale(i)
            code = codes[i]
            if code:
                self.trip(i, Fault.DRIVE, self.describe_fault(i, code))

    def _trip_stale(self, i: int) -> None:
        cycles = self._stale[i]
        cause = self.gate.cause[i]
        if cause == NONE:
            self.trip(i, Fault.STALE_FEEDBACK, f"no feedback for {cycles} cycles")
            return
        kind = Fault.POSITION_LIMIT if cause == BEYOND_LIMITS else Fault.INVALID_FEEDBACK
        self.trip(i, kind, f"implausible feedback for {cycles} cycles: {self.gate.reason[i]}")

    def trip(self, i: int, kind: Fault, text: str) -> None:
        """Latch a fault on joint ``i`` (no-op if it already has one: the first cause is the one reported).

        The hold target is the last *accepted* position, never the reading that may have caused the fault."""
        if self.fault[i] != Fault.NONE:
            return
        self.fault[i] = kind
        self.fault_text[i] = text
        self.mode[i] = JointMode.FAULT
        self._safe_action[i] = self.safety.estop_action if self.estop else self.safety.fault_action
        self.latched[i] = self.gate.accepted_position.item(i)
        self.change_seq += 1
        self.events.emit("error", "supervisor", f"joint {self.joints[i]} fault: {text}")

    def collide(self, text: str, stiffness: float) -> None:
        """A collision (hild/cycle/contact.py): every joint not already faulted latches ``Fault.COLLISION`` at its
        last accepted position (where the arm is: it never pushes on toward its old target) and gets the reflex —
        hold with kp lowered to ``stiffness`` × its hold kp, hold kd, zero velocity, gravity feed-forward — until
        ``reset``. The setpoint steps back to the measured position in one cycle, the one exception to the slew
        limit: a trajectory's setpoint leads the shaft (by kd·q̇/kp at speed), and slewing it back would keep the
        spring pulling toward the obstacle for tens of cycles. An e-stop's action wins over the reflex."""
        self._reflex_kp = [kp * stiffness for kp in self._hold_kp]
        for i in range(len(self.joints)):
            if self.fault[i] == Fault.NONE:
                self.trip(i, Fault.COLLISION, text)
                if not self.estop:
                    self._safe_action[i] = _REFLEX
                    if math.isfinite(self.latched[i]):  # the setpoint goes back to the shaft at once, not slewed:
                        self._prev_position[i] = self.latched[i]  # a spring toward where it is pushes nothing

    def trip_all(self, kind: Fault, text: str) -> None:
        for i in range(len(self.joints)):
            self.trip(i, kind, text)

    def rename_fault(self, i: int, text: str) -> None:
        """Replace joint ``i``'s fault text with a more precise one (e.g. the drive's own words for an error
        that survived clear-error), so status names the condition the operator must fix."""
        if self.fault[i] != Fault.NONE and self.fault_text[i] != text:
            self.fault_text[i] = text
            self.change_seq += 1
            self.events.emit("error", "supervisor", f"joint {self.joints[i]} fault: {text}")

    # ---- operator actions (between cycles) ----------------------------------------------------------------
    def engage_estop(self) -> None:
        if self.estop:
            return
        self.estop = True
        self._safe_action = [self.safety.estop_action] * len(self.joints)
        self.mode[:] = JointMode.ESTOP
        self._relatch = [True] * len(self.joints)
        self.change_seq += 1
        self.events.emit("error", "supervisor", "e-stop engaged")

    def reset(self) -> list[str]:
        """Clear e-stop and latched faults; every joint restarts in hold where it is. Returns what was cleared.

        Call ``refusal`` first: readings that still glitch must never be made the truth. What it lets through —
        rejected readings that are steady (a drive's frame that moved, or motion while they were rejected), or on
        a drive that reports a fault (it is off) — is re-anchored: the next finite reading inside the limits is
        accepted as it is, and the reply says which joints were."""
        cleared = [f"{self.joints[i]}: {self.fault_text[i]}" for i in np.flatnonzero(self.fault)]
        if self.estop:
            cleared.insert(0, "e-stop")
        n = len(self.joints)
        for i in range(n):
            if self.gate.untrusted(i):
                self.gate.reanchor(i)
                cleared.append(
                    f"{self.joints[i]}: re-anchored at its next reading (rejected: {self.gate.reason[i] or 'none yet'})"
                )
        self.estop = False
        self.fault[:] = Fault.NONE
        self.fault_text = [""] * n
        self.mode[:] = JointMode.HOLD
        self._stale = [0] * n
        self._silent = [0.0] * n
        self._untrusted_fault = [False] * n
        self._relatch = [True] * n
        self.change_seq += 1
        self.events.emit("info", "supervisor", "reset: " + ("; ".join(cleared) if cleared else "nothing to clear"))
        return cleared

    def refusal(self) -> str | None:
        """Why ``reset`` must not run now, or None: a joint whose readings still glitch (non-finite, beyond the
        limits, frozen, or jumping among themselves) while its drive reports no fault — trusting them would move
        the arm toward a bad reading."""
        gate = self.gate
        bad = [
            f"{self.joints[i]} ({gate.reason[i]})"
            for i in range(len(self.joints))
            if gate.cause[i] != NONE and not gate.steady(i) and not self._codes[i]
        ]
        if not bad:
            return None
        return (
            f"readings still implausible on {', '.join(bad)}: the encoder or its readout is wrong; reset would make "
            "a bad reading the truth. Fix the sensor (or power-cycle the drive), then reset"
        )

    def rearm(self, i: int) -> bool:
        """Clear joint ``i``'s drive fault once its drive is enabled again (operator ``enable``); it holds where
        it is now. Other faults stay: they need a ``reset``."""
        if self.estop or self.fault[i] not in (Fault.DRIVE, Fault.STALE_FEEDBACK):
            return False
        self.fault[i] = Fault.NONE
        self.fault_text[i] = ""
        self.mode[i] = JointMode.HOLD
        self._stale[i] = 0
        self._untrusted_fault[i] = False
        self._relatch[i] = True
        self.change_seq += 1
        return True

    def follow_measured(self, i: int, cycles: int, *, new_frame: bool = False) -> None:
        """Hold joint ``i`` with damping and gravity only (kp 0, position = the reading) for ``cycles``, then latch
        the last reading: after a drive's zero moved (the new frame's reading is latched, never a pull toward the
        old one), and while a re-enabled drive confirms (its first commands are where the shaft is).

        ``new_frame``: the drive's frame moves on purpose (set-zero), so the readings jump: the gate re-anchors on
        every reading until the window ends instead of rejecting the jump."""
        self._follow[i] = max(1, cycles)
        self._new_frame[i] = new_frame

    def begin_descent(self, seconds: float) -> None:
        """Stop for an unbraked arm: from the next cycle every joint gets damping only (kp 0, hold kd) and its
        gravity feed-forward fading linearly to zero over ``seconds``; the arm is lowered, not dropped. The
        engine releases the hardware once ``descending`` is False."""
        self._descent = (seconds, seconds)
        self.descent_started = True
        self.events.emit("info", "supervisor", f"stopping: damped descent over {seconds:g} s before release")

    @property
    def descending(self) -> bool:
        return self._descent[0] > 0.0

    # ---- the final command (after the controllers) --------------------------------------------------------
    def command(self, dt: float, state: JointState, ctrl: ServoCommand, out: ServoCommand) -> None:
        """The final command of every joint: its mode's defaults for unclaimed fields, hold for unwritten joints,
        the safe action for faulted ones, then the limits, in one pass over the joints.

        Long on purpose: it is the hottest loop of the cycle, one joint per iteration with everything in locals, so
        splitting it into per-step helpers would cost a call and the lookups per joint per cycle (the module
        docstring says why a plain loop, not numpy)."""
        pos, g, pose = state.position, self._g, self._pose
        if self._hold_steps:
            self._ramp_hold_gains()
        if self.gravity is not None:  # at the accepted pose (the state holds stand-ins for rejected readings)
            if self.gate.all_known:
                self.gravity(pos, g)
            else:  # a joint without any accepted reading yet: its coordinate at 0 (its own feed-forward is dropped)
                np.copyto(pose, pos)
                pose[np.isnan(pose)] = 0.0
                self.gravity(pose, g)
        # One tolist() per array instead of an item() per element, and locals instead of attribute lookups: this
        # loop runs for every joint in every cycle.
        q_all, qd_all, g_all = pos.tolist(), state.velocity.tolist(), g.tolist()
        fresh_all = state.fresh.tolist()
        c_pos, c_vel, c_eff = ctrl.position.tolist(), ctrl.velocity.tolist(), ctrl.effort.tolist()
        c_kp, c_kd, written = ctrl.kp.tolist(), ctrl.kd.tolist(), ctrl.written.tolist()
        c_hold, hold_effort = ctrl.hold_effort.tolist(), self.hold_effort
        kept_all = hold_effort.tolist()
        latched, prev, modes, old_flags = self.latched, self._prev_position, self.mode, self.limit_flags
        mode_all, prev_all, flags_all = modes.tolist(), prev.tolist(), old_flags.tolist()
        o_pos, o_vel, o_eff, o_kp, o_kd = out.position, out.velocity, out.effort, out.kp, out.kd
        was_stiff = o_kp.tolist()  # last cycle's gains: a position with kp 0 held nothing anywhere
        owner, claims, default_kp, default_kd = self._owner, self._claims, self._default_kp, self._default_kd
        gravity_on_effort = self._gravity_on_effort
        hold_kp, hold_kd, soft_lower, soft_upper = self._hold_kp, self._hold_kd, self._soft_lower, self._soft_upper
        vmax_all, emax_all, safe_action = self._vmax, self._emax, self._safe_action
        applies_gains, cause = self._applies_gains, self.gate.cause
        relatch, follow, untrusted_fault = self._relatch, self._follow, self._untrusted_fault
        check_relatch = True in relatch
        check_follow = any(follow)
        left, total = self._descent
        # The gravity share left (0 once the descent ended: never a hold spring again), or -1 when none runs.
        descent = left / total if self.descent_started else -1.0
        isfinite = math.isfinite
        bad_owners: list[int] | None = None
        for i, mode in enumerate(mode_all):
            q, qd, ff_gravity = q_all[i], qd_all[i], g_all[i]
            known = isfinite(q)  # False only for a joint that never had an accepted reading
            if not known:
                ff_gravity = 0.0
            if known and not was_stiff[i] > 0.0:  # no spring held it anywhere: a stiff command starts at the reading
                prev_all[i] = q
            if check_relatch and relatch[i] and known:
                relatch[i] = False
                latched[i] = q
            following = False
            if check_follow and follow[i]:  # the reading is not to be held yet: follow it, re-latch at the end
                follow[i] -= 1
                if known:
                    latched[i] = q
                    prev_all[i] = q
                    following = True
            controlled = False

            # 1. The servo command this joint gets before limits.
            if mode >= _FAULT or descent >= 0.0:
                action = safe_action[i]
                if descent >= 0.0:
                    action, ff_gravity = _DAMP_GRAVITY, ff_gravity * descent
                elif action in (_HOLD, _REFLEX) and (cause[i] != NONE or not known or untrusted_fault[i]):
                    # No position to hold with a spring: damp and carry the arm's weight, until reset (a spring
                    # back to the old latch once readings recover would pull the arm the way it drifted).
                    action = _DAMP_GRAVITY
                    untrusted_fault[i] = True
                if action == _HOLD:  # a grasp is kept: an e-stopped gripper holds what it holds
                    p, v, ff, kp, kd = latched.item(i), 0.0, ff_gravity + kept_all[i], hold_kp[i], hold_kd[i]
                elif action == _REFLEX:  # a collision: compliant, at the latched (or retracting) position
                    p, v, ff, kp, kd = latched.item(i), 0.0, ff_gravity + kept_all[i], self._reflex_kp[i], hold_kd[i]
                else:  # damp or disable: no stiffness, position field where the arm last was
                    p = q if known else prev_all[i]
                    v, kp = 0.0, 0.0
                    ff = ff_gravity if action == _DAMP_GRAVITY else 0.0
                    kd = hold_kd[i] if action in (_DAMP, _DAMP_GRAVITY) else 0.0
                new_mode = mode
            else:
                if written[i] and owner[i] >= 0:
                    has_p, has_v, has_e, has_kp, has_kd = claims[i]
                    p = c_pos[i] if has_p else q
                    v = c_vel[i] if has_v else 0.0
                    ff = (c_eff[i] + ff_gravity if gravity_on_effort[i] else c_eff[i]) if has_e else ff_gravity
                    kp = c_kp[i] if has_kp else default_kp[i]
                    kd = c_kd[i] if has_kd else default_kd[i]
                    # Finite command and non-negative gains (NaN gains compare False, so they fail too).
                    kept = c_hold[i]
                    if isfinite(p) and isfinite(v) and isfinite(ff) and isfinite(kept) and kp >= 0.0 and kd >= 0.0:
                        controlled = True
                        if kept != kept_all[i]:  # a grasp taken or released: rare
                            kept_all[i] = kept
                            hold_effort[i] = kept
                            out.hold_effort[i] = kept  # in the final command: a controller activated next sees it
                            self.change_seq += 1  # and status shows it
                    else:  # a controller bug never reaches a drive: hold, and fail the controller
                        bad_owners = bad_owners or []
                        bad_owners.append(owner[i])
                if not controlled:
                    if mode == _CONTROLLED and known:
                        latched[i] = q  # it just lost its controller: hold where it is now
                        if kept_all[i]:
                            self._report_grasp(i, kept_all[i])
                    p, v, ff, kp, kd = latched.item(i), 0.0, ff_gravity + kept_all[i], hold_kp[i], hold_kd[i]
                    if not isfinite(p):  # never had a position: damp until the gate accepts one
                        p, kp, ff = prev_all[i], 0.0, ff_gravity
                new_mode = _CONTROLLED if controlled else _HOLD_MODE

            if following and not controlled:  # damping and gravity only: no spring toward any position
                p, v, kp = q, 0.0, 0.0

            # 2. Limits.
            flags = 0
            vmax = vmax_all[i]
            if controlled:
                if p < soft_lower[i] or p > soft_upper[i]:
                    p = min(max(p, soft_lower[i]), soft_upper[i])
                    flags |= LIMIT_POSITION
                if v > vmax or v < -vmax:
                    v = vmax if v > 0.0 else -vmax
                    flags |= LIMIT_VELOCITY
            if kp > 0.0:  # slew: a stiff position command moves at most velocity_limit·dt per cycle
                step, last = vmax * dt, prev_all[i]
                if p > last + step or p < last - step:
                    p = last + step if p > last else last - step
                    if controlled:
                        flags |= LIMIT_VELOCITY
            # What the drive will do: its law if it applies our gains, else only the feed-forward is ours.
            tau = kp * (p - q) + kd * (v - qd) + ff if applies_gains[i] else ff
            emax = emax_all[i]
            if tau > emax or tau < -emax:
                trimmed = ff - (tau - (emax if tau > 0.0 else -emax))
                if not fresh_all[i] or mode >= _FAULT:  # a stand-in reading or a fault: only take torque away
                    trimmed = min(max(trimmed, min(ff, 0.0)), max(ff, 0.0))
                ff = trimmed
                flags |= LIMIT_EFFORT
            if ff > emax or ff < -emax:  # never more feed-forward than the joint's effort limit
                ff = emax if ff > 0.0 else -emax
                flags |= LIMIT_EFFORT

            # 3. Out, and remember.
            o_pos[i] = p
            o_vel[i] = v
            o_eff[i] = ff
            o_kp[i] = kp
            o_kd[i] = kd
            prev_all[i] = p
            if new_mode != mode:
                modes[i] = new_mode
                self.change_seq += 1
            if flags != flags_all[i]:
                self._report_limits(i, flags_all[i], flags)
                old_flags[i] = flags
                self.change_seq += 1
        prev[:] = prev_all
        self.bad_command_owners = bad_owners or []
        if left > 0.0:
            self._descent = (max(0.0, left - dt), total)

    def _report_grasp(self, i: int, effort: float) -> None:
        self.events.emit(
            "info",
            "supervisor",
            f"joint {self.joints[i]} holds its grasp: it keeps pressing with {effort:g} (its controller's hold effort)",
        )

    def _report_limits(self, i: int, was: int, now: int) -> None:
        for bit, word in _LIMIT_WORDS:
            if now & bit and not was & bit:
                self.events.emit("warning", "supervisor", f"joint {self.joints[i]}: {word} limit engaged")
            elif was & bit and not now & bit:
                self.events.emit("info", "supervisor", f"joint {self.joints[i]}: {word} limit released")
