"""The safety layer between controllers and hardware (DESIGN.md §3).

Every cycle, whatever the controllers do:

* ``check(state)`` (after read) detects faults: stale feedback, drive fault codes, non-finite feedback, hard
  position limits, overspeed. Faults latch until ``reset``.
* ``command(state, ctrl, out)`` (after the controllers) builds the final servo command per joint:
  - **controlled** (an active controller claimed and wrote it this cycle): claimed fields from the controller,
    the rest from the joint's mode defaults (position gains for a position claim, kp = 0 for velocity,
    kp = kd = 0 for effort) plus gravity feed-forward;
  - **hold** (nobody commands it): the position latched when it lost its controller (or at start-up), hold
    gains, gravity feed-forward — never a stale command;
  - **fault / e-stop**: the configured safe action (hold, damp or disable).
  Then limits: soft position limits and velocity limits on controller commands, a slew limit so the commanded
  position never steps by more than ``velocity_limit · dt`` (hold latching included), and the predicted drive
  torque kept within ``±effort``. A limit that engages is reported once, when it engages and when it releases.

All per-cycle work is vectorised over preallocated arrays; events are the only allocations, and they happen on
changes, not per cycle.
"""

from __future__ import annotations

import enum
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from hild.arrays import JointState, ServoCommand
from hild.controller import JointLimitArrays
from hild.events import EventLog
from hild.interfaces import FIELDS, ClaimMasks


class JointMode(enum.IntEnum):
    HOLD = 0
    CONTROLLED = 1
    FAULT = 2
    ESTOP = 3


MODE_NAMES = {m.value: m.name.lower() for m in JointMode}


class Fault(enum.IntEnum):
    NONE = 0
    STALE_FEEDBACK = 1
    DRIVE = 2
    HARDWARE = 3
    POSITION_LIMIT = 4
    OVERSPEED = 5
    INVALID_FEEDBACK = 6
    OVERRUN = 7


class Action(enum.IntEnum):
    HOLD = 0
    DAMP = 1
    DISABLE = 2


LIMIT_POSITION, LIMIT_VELOCITY, LIMIT_EFFORT = 1, 2, 4
_LIMIT_WORDS = ((LIMIT_POSITION, "position"), (LIMIT_VELOCITY, "velocity"), (LIMIT_EFFORT, "effort"))


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
    ) -> None:
        n = len(joints)
        self.joints = joints
        self.limits = limits
        self.gains = gains
        self.safety = safety
        self.events = events
        self.gravity = gravity
        self.describe_fault = describe_fault or (lambda i, code: f"drive fault code {code:#x}")

        self.mode = np.zeros(n, dtype=np.int64)
        self.latched = np.zeros(n)
        self.fault = np.zeros(n, dtype=np.int64)
        self.fault_text: list[str] = [""] * n
        self.limit_flags = np.zeros(n, dtype=np.int64)
        self.estop = False
        self.change_seq = 0  # bumped on any mode/fault/limit change: the status publisher watches it

        self._masks = ClaimMasks.empty(n)
        self._default_kp = np.zeros(n)
        self._default_kd = np.zeros(n)
        self._position_from_measured = np.zeros(n, dtype=bool)
        self._safe_action = np.zeros(n, dtype=np.int64)
        self._stale = np.zeros(n, dtype=np.int64)
        self._prev_position = np.zeros(n)
        self._relatch = np.ones(n, dtype=bool)  # latch at the next command(): start-up and reset
        self._g = np.zeros(n)
        self._controlled = np.zeros(n, dtype=bool)
        self._b = np.zeros(n, dtype=bool)
        self._b2 = np.zeros(n, dtype=bool)
        self._b3 = np.zeros(n, dtype=bool)
        self._claimed = np.zeros(n, dtype=bool)
        self._neg_velocity = -limits.velocity
        self._neg_effort = -limits.effort
        self._new_mode = np.zeros(n, dtype=np.int64)
        self._neg_step = np.zeros(n)
        self._stale_limit = np.zeros(n, dtype=np.int64)
        self._s = np.zeros(n)
        self._s2 = np.zeros(n)
        self._flags = np.zeros(n, dtype=np.int64)
        self._step = np.zeros(n)
        self.bad_command_owners: list[int] = []  # controller slots that produced non-finite commands this cycle
        self.set_claims(self._masks)

    # ---- configuration (between cycles) -------------------------------------------------------------------
    def start(self, state: JointState) -> None:
        """Latch every joint where the first read found it: starting the daemon never moves the arm."""
        finite = np.isfinite(state.position)
        self.latched[:] = np.where(finite, state.position, 0.0)
        self._prev_position[:] = self.latched
        self._relatch[:] = False
        self.mode[:] = JointMode.HOLD

    def set_claims(self, masks: ClaimMasks) -> None:
        """Recompute per-joint mode defaults from the active claims (called at each switch)."""
        self._masks = masks
        np.greater_equal(masks.owner, 0, out=self._claimed)
        g = self.gains
        position_mode = masks.position
        velocity_mode = masks.velocity & ~position_mode
        self._position_from_measured[:] = ~position_mode
        self._default_kp[:] = np.where(position_mode, g.position_kp, 0.0)
        self._default_kd[:] = np.where(position_mode, g.position_kd, np.where(velocity_mode, g.velocity_kd, 0.0))
        self.change_seq += 1

    # ---- fault detection (after read) ---------------------------------------------------------------------
    def check(self, state: JointState) -> None:
        q, qd = state.position, state.velocity
        stale, b, b3 = self._stale, self._b, self._b3
        if state.fresh.all():
            stale.fill(0)
        else:
            np.add(stale, 1, out=stale)
            np.logical_not(state.fresh, out=b)
            np.multiply(stale, b, out=stale)
            limit = self.safety.stale_feedback_cycles
            if stale.max() >= limit:
                self._trip_where(stale >= limit, Fault.STALE_FEEDBACK, f"no feedback for {limit} cycles", q)
        if state.fault.any():
            for i in np.flatnonzero(state.fault):
                if self.fault[i] == Fault.NONE:
                    self.trip(int(i), Fault.DRIVE, self.describe_fault(int(i), int(state.fault[i])), q)
        np.isfinite(q, out=b)
        np.isfinite(qd, out=b3)
        np.logical_and(b, b3, out=b)
        if not b.all():
            self._trip_where(~b, Fault.INVALID_FEEDBACK, "non-finite position or velocity feedback", q)
        lim = self.limits
        np.less(q, lim.lower, out=b)
        np.greater(q, lim.upper, out=b3)
        np.logical_or(b, b3, out=b)
        if b.any():
            self._trip_where(b, Fault.POSITION_LIMIT, "measured position outside the hard limits", q)
        np.abs(qd, out=self._s)
        np.multiply(lim.velocity, self.safety.overspeed_factor, out=self._s2)
        np.greater(self._s, self._s2, out=b)
        if b.any():
            self._trip_where(b, Fault.OVERSPEED, f"speed above {self.safety.overspeed_factor:g}× the velocity limit", q)

    def trip(self, i: int, kind: Fault, text: str, q: np.ndarray | None = None) -> None:
        """Latch a fault on joint ``i`` (no-op if it already has one: the first cause is the one reported)."""
        if self.fault[i] != Fault.NONE:
            return
        self.fault[i] = kind
        self.fault_text[i] = text
        self.mode[i] = JointMode.FAULT
        self._safe_action[i] = self.safety.estop_action if self.estop else self.safety.fault_action
        self._latch(i, q)
        self.change_seq += 1
        self.events.emit("error", "supervisor", f"joint {self.joints[i]} fault: {text}")

    def trip_all(self, kind: Fault, text: str, q: np.ndarray | None = None) -> None:
        for i in range(len(self.joints)):
            self.trip(i, kind, text, q)

    def _trip_where(self, mask: np.ndarray, kind: Fault, text: str, q: np.ndarray) -> None:
        for i in np.flatnonzero(mask):
            self.trip(int(i), kind, text, q)

    def _latch(self, i: int, q: np.ndarray | None) -> None:
        value = q[i] if q is not None else np.nan
        self.latched[i] = value if np.isfinite(value) else self._prev_position[i]

    # ---- operator actions (between cycles) ----------------------------------------------------------------
    def engage_estop(self) -> None:
        if self.estop:
            return
        self.estop = True
        self._safe_action[:] = self.safety.estop_action
        self.mode[:] = JointMode.ESTOP
        self._relatch[:] = True
        self.change_seq += 1
        self.events.emit("error", "supervisor", "e-stop engaged")

    def reset(self) -> list[str]:
        """Clear e-stop and latched faults; every joint restarts in hold where it is. Returns what was cleared."""
        cleared = [f"{self.joints[i]}: {self.fault_text[i]}" for i in np.flatnonzero(self.fault)]
        if self.estop:
            cleared.insert(0, "e-stop")
        self.estop = False
        self.fault[:] = Fault.NONE
        self.fault_text = [""] * len(self.joints)
        self.mode[:] = JointMode.HOLD
        self._stale.fill(0)
        self._relatch[:] = True
        self.change_seq += 1
        self.events.emit("info", "supervisor", "reset: " + ("; ".join(cleared) if cleared else "nothing to clear"))
        return cleared

    # ---- the final command (after the controllers) --------------------------------------------------------
    def command(self, dt: float, state: JointState, ctrl: ServoCommand, out: ServoCommand) -> None:
        q = state.position
        masks, mode, b, b3 = self._masks, self.mode, self._b, self._b3
        safe = self._b2
        np.greater_equal(mode, JointMode.FAULT, out=safe)

        # Who is controlled this cycle: claimed, written, not faulted or stopped, and a finite command.
        controlled = self._controlled
        np.logical_and(ctrl.written, self._claimed, out=controlled)
        np.logical_not(safe, out=b)
        np.logical_and(controlled, b, out=controlled)
        self._reject_bad_commands(ctrl, controlled)

        # Latch joints entering hold (lost their controller), after reset or e-stop.
        np.equal(mode, JointMode.CONTROLLED, out=b)
        np.logical_not(controlled, out=b3)
        np.logical_and(b, b3, out=b)
        np.logical_or(b, self._relatch, out=b)
        np.isfinite(q, out=b3)
        np.logical_and(b, b3, out=b)
        np.copyto(self.latched, q, where=b)
        self._relatch.fill(False)

        g = self._g
        if self.gravity is not None:
            self.gravity(q, g)

        # Hold everywhere, then overwrite controlled joints with mode defaults and claimed fields.
        gains = self.gains
        np.copyto(out.position, self.latched)
        out.velocity.fill(0.0)
        np.copyto(out.kp, gains.hold_kp)
        np.copyto(out.kd, gains.hold_kd)
        np.copyto(out.effort, g)
        np.copyto(out.kp, self._default_kp, where=controlled)
        np.copyto(out.kd, self._default_kd, where=controlled)
        np.logical_and(controlled, self._position_from_measured, out=b)
        np.copyto(out.position, q, where=b)
        for field in FIELDS:
            np.logical_and(controlled, getattr(masks, field), out=b)
            np.copyto(getattr(out, field), getattr(ctrl, field), where=b)
        if safe.any():
            self._apply_safe_actions(q, safe, out)

        flags = self._flags
        flags.fill(0)
        self._limit_commands(dt, state, controlled, out, flags)
        np.copyto(self._prev_position, out.position)

        self._update_modes(controlled, safe, flags)

    def _reject_bad_commands(self, ctrl: ServoCommand, controlled: np.ndarray) -> None:
        """A non-finite or negative-gain command from a controller never reaches a drive."""
        ok, b3 = self._b, self._b3
        np.greater_equal(ctrl.kp, 0.0, out=ok)  # False for NaN too
        np.greater_equal(ctrl.kd, 0.0, out=b3)
        np.logical_and(ok, b3, out=ok)
        for field in ("position", "velocity", "effort"):
            np.isfinite(getattr(ctrl, field), out=b3)
            np.logical_and(ok, b3, out=ok)
        np.logical_not(controlled, out=b3)
        np.logical_or(ok, b3, out=ok)
        if ok.all():
            if self.bad_command_owners:
                self.bad_command_owners = []
            return
        bad = ~ok  # rare path: a controller bug
        self.bad_command_owners = sorted({int(self._masks.owner[i]) for i in np.flatnonzero(bad)})
        np.logical_and(controlled, ok, out=controlled)

    def _apply_safe_actions(self, q: np.ndarray, safe: np.ndarray, out: ServoCommand) -> None:
        gains = self.gains
        for i in np.flatnonzero(safe):
            action = self._safe_action[i]
            if action == Action.HOLD:
                out.position[i] = self.latched[i]
                out.velocity[i] = 0.0
                out.kp[i] = gains.hold_kp[i]
                out.kd[i] = gains.hold_kd[i]
                out.effort[i] = self._g[i]
            else:
                out.position[i] = q[i] if np.isfinite(q[i]) else self.latched[i]
                out.velocity[i] = 0.0
                out.kp[i] = 0.0
                out.kd[i] = gains.hold_kd[i] if action == Action.DAMP else 0.0
                out.effort[i] = 0.0

    def _limit_commands(
        self, dt: float, state: JointState, controlled: np.ndarray, out: ServoCommand, flags: np.ndarray
    ) -> None:
        lim, s, s2, b, b3 = self.limits, self._s, self._s2, self._b, self._b3
        # Soft position limits, on controller commands only: hold never pulls the arm anywhere.
        np.minimum(out.position, lim.soft_upper, out=s)
        np.maximum(s, lim.soft_lower, out=s)
        np.not_equal(s, out.position, out=b)
        np.logical_and(b, controlled, out=b)
        np.copyto(out.position, s, where=controlled)
        np.bitwise_or(flags, LIMIT_POSITION, out=flags, where=b)
        # Velocity command limit.
        np.minimum(out.velocity, lim.velocity, out=s)
        np.maximum(s, self._neg_velocity, out=s)
        np.not_equal(s, out.velocity, out=b)
        np.logical_and(b, controlled, out=b)
        np.copyto(out.velocity, s)
        np.bitwise_or(flags, LIMIT_VELOCITY, out=flags, where=b)
        # Slew: a stiff (kp > 0) position command moves at most velocity_limit·dt per cycle.
        step, neg_step = self._step, self._neg_step
        np.multiply(lim.velocity, dt, out=step)
        np.negative(step, out=neg_step)
        np.subtract(out.position, self._prev_position, out=s)
        np.minimum(s, step, out=s2)
        np.maximum(s2, neg_step, out=s2)
        np.not_equal(s2, s, out=b)
        np.greater(out.kp, 0.0, out=b3)
        np.logical_and(b, b3, out=b)
        np.add(self._prev_position, s2, out=s)
        np.copyto(out.position, s, where=b)
        np.logical_and(b, controlled, out=b)
        np.bitwise_or(flags, LIMIT_VELOCITY, out=flags, where=b)
        # Effort: predict the drive's torque and trim the feed-forward so it stays within ±effort.
        tau = s
        np.subtract(out.position, state.position, out=tau)
        np.multiply(tau, out.kp, out=tau)
        np.subtract(out.velocity, state.velocity, out=s2)
        np.multiply(s2, out.kd, out=s2)
        np.add(tau, s2, out=tau)
        np.add(tau, out.effort, out=tau)
        np.minimum(tau, lim.effort, out=s2)
        np.maximum(s2, self._neg_effort, out=s2)
        np.subtract(tau, s2, out=tau)  # the excess torque
        np.isnan(tau, out=b)  # unknown state (faulted feedback): nothing to trim
        np.copyto(tau, 0.0, where=b)
        np.not_equal(tau, 0.0, out=b)
        if b.any():
            np.subtract(out.effort, tau, out=out.effort)
            np.bitwise_or(flags, LIMIT_EFFORT, out=flags, where=b)

    def _update_modes(self, controlled: np.ndarray, safe: np.ndarray, flags: np.ndarray) -> None:
        mode, new_mode, b = self.mode, self._new_mode, self._b
        new_mode.fill(JointMode.HOLD)
        np.copyto(new_mode, JointMode.CONTROLLED, where=controlled)
        np.copyto(new_mode, mode, where=safe)
        np.not_equal(new_mode, mode, out=b)
        if b.any():
            np.copyto(mode, new_mode)
            self.change_seq += 1
        np.not_equal(flags, self.limit_flags, out=b)
        if b.any():
            self._report_limits(flags)
            np.copyto(self.limit_flags, flags)
            self.change_seq += 1

    def _report_limits(self, flags: np.ndarray) -> None:
        for i in np.flatnonzero(flags != self.limit_flags):
            for bit, word in _LIMIT_WORDS:
                was, now = bool(self.limit_flags[i] & bit), bool(flags[i] & bit)
                if now and not was:
                    self.events.emit("warning", "supervisor", f"joint {self.joints[i]}: {word} limit engaged")
                elif was and not now:
                    self.events.emit("info", "supervisor", f"joint {self.joints[i]}: {word} limit released")
