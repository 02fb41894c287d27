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

The per-cycle work is a plain loop over joints reading and writing preallocated arrays in place. For the 2–14
joints of an arm that is several times faster than vectorised numpy (each numpy call on a six-element array is
almost pure overhead), and it reads as what it is: for each joint, decide its mode, build its command, apply its
limits. Events are the only allocations, and they happen on changes, not per cycle.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from hild.arrays import JointState, ServoCommand
from hild.controller import JointLimitArrays
from hild.events import EventLog
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


class Action(enum.IntEnum):
    HOLD = 0
    DAMP = 1
    DISABLE = 2


LIMIT_POSITION, LIMIT_VELOCITY, LIMIT_EFFORT = 1, 2, 4
_LIMIT_WORDS = ((LIMIT_POSITION, "position"), (LIMIT_VELOCITY, "velocity"), (LIMIT_EFFORT, "effort"))


# Plain ints for the per-joint loop (enum attribute lookups cost more than the comparisons they feed).
_FAULT, _CONTROLLED, _HOLD_MODE = int(JointMode.FAULT), int(JointMode.CONTROLLED), int(JointMode.HOLD)
_HOLD, _DAMP = int(Action.HOLD), int(Action.DAMP)


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

        # Published state (read by status from other threads; written element-wise, only on change).
        self.mode = np.zeros(n, dtype=np.int64)
        self.latched = np.zeros(n)
        self.fault = np.zeros(n, dtype=np.int64)
        self.fault_text: list[str] = [""] * n
        self.limit_flags = np.zeros(n, dtype=np.int64)
        self.estop = False
        self.change_seq = 0  # bumped on any mode/fault/limit change: the status publisher watches it
        self.bad_command_owners: list[int] = []  # controller slots that produced invalid commands this cycle

        # Per-joint constants as Python floats: the cycle loop reads them without numpy scalar overhead.
        self._lower, self._upper = limits.lower.tolist(), limits.upper.tolist()
        self._soft_lower, self._soft_upper = limits.soft_lower.tolist(), limits.soft_upper.tolist()
        self._vmax, self._emax = limits.velocity.tolist(), limits.effort.tolist()
        self._overspeed = [v * safety.overspeed_factor for v in self._vmax]
        self._hold_kp, self._hold_kd = gains.hold_kp.tolist(), gains.hold_kd.tolist()

        # Per-joint claim view, rebuilt at each switch (set_claims).
        self._owner = [-1] * n
        self._claims: list[tuple[bool, bool, bool, bool, bool]] = [(False,) * 5] * n  # type: ignore[list-item]
        self._default_kp = [0.0] * n
        self._default_kd = [0.0] * n

        self._safe_action = [Action.HOLD] * n
        self._stale = [0] * n
        self._relatch = [False] * n  # latch at the next command(): after reset and e-stop
        self._follow = [0] * n  # cycles left during which hold follows the measured position (after set-zero)
        self._prev_position = np.zeros(n)
        self._g = np.zeros(n)
        self.set_claims(ClaimMasks.empty(n))

    # ---- configuration (between cycles) -------------------------------------------------------------------
    def start(self, state: JointState) -> None:
        """Latch every joint where the first read found it: starting the daemon never moves the arm."""
        finite = np.isfinite(state.position)
        self.latched[:] = np.where(finite, state.position, 0.0)
        self._prev_position[:] = self.latched
        self._relatch = [False] * len(self.joints)
        self.mode[:] = JointMode.HOLD

    def set_claims(self, masks: ClaimMasks) -> None:
        """Recompute per-joint mode defaults from the active claims (called at each switch)."""
        g = self.gains
        self._owner = masks.owner.tolist()
        self._claims = list(zip(*(getattr(masks, f).tolist() for f in FIELDS), strict=True))
        for i, (position, velocity, _, _, _) in enumerate(self._claims):
            if position:
                self._default_kp[i], self._default_kd[i] = float(g.position_kp[i]), float(g.position_kd[i])
            elif velocity:
                self._default_kp[i], self._default_kd[i] = 0.0, float(g.velocity_kd[i])
            else:
                self._default_kp[i], self._default_kd[i] = 0.0, 0.0
        self.change_seq += 1

    # ---- fault detection (after read) ---------------------------------------------------------------------
    def check(self, state: JointState) -> None:
        pos = state.position
        fresh, codes = state.fresh.tolist(), state.fault.tolist()
        q_all, qd_all = pos.tolist(), state.velocity.tolist()
        stale, stale_limit = self._stale, self.safety.stale_feedback_cycles
        lower, upper, overspeed, isfinite = self._lower, self._upper, self._overspeed, math.isfinite
        for i, q in enumerate(q_all):
            if fresh[i]:
                stale[i] = 0
            else:
                stale[i] += 1
                if stale[i] == stale_limit:
                    self.trip(i, Fault.STALE_FEEDBACK, f"no feedback for {stale_limit} cycles", pos)
            code = codes[i]
            if code:
                self.trip(i, Fault.DRIVE, self.describe_fault(i, code), pos)
            qd = qd_all[i]
            if not (isfinite(q) and isfinite(qd)):
                self.trip(i, Fault.INVALID_FEEDBACK, "non-finite position or velocity feedback", pos)
            elif q < lower[i] or q > upper[i]:
                self.trip(i, Fault.POSITION_LIMIT, "measured position outside the hard limits", pos)
            elif qd > overspeed[i] or qd < -overspeed[i]:
                factor = self.safety.overspeed_factor
                self.trip(i, Fault.OVERSPEED, f"speed above {factor:g}× the velocity limit", pos)

    def trip(self, i: int, kind: Fault, text: str, q: np.ndarray | None = None) -> None:
        """Latch a fault on joint ``i`` (no-op if it already has one: the first cause is the one reported)."""
        if self.fault[i] != Fault.NONE:
            return
        self.fault[i] = kind
        self.fault_text[i] = text
        self.mode[i] = JointMode.FAULT
        self._safe_action[i] = self.safety.estop_action if self.estop else self.safety.fault_action
        value = q.item(i) if q is not None else math.nan
        self.latched[i] = value if math.isfinite(value) else self._prev_position.item(i)
        self.change_seq += 1
        self.events.emit("error", "supervisor", f"joint {self.joints[i]} fault: {text}")

    def trip_all(self, kind: Fault, text: str, q: np.ndarray | None = None) -> None:
        for i in range(len(self.joints)):
            self.trip(i, kind, text, q)

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
        """Clear e-stop and latched faults; every joint restarts in hold where it is. Returns what was cleared."""
        cleared = [f"{self.joints[i]}: {self.fault_text[i]}" for i in np.flatnonzero(self.fault)]
        if self.estop:
            cleared.insert(0, "e-stop")
        n = len(self.joints)
        self.estop = False
        self.fault[:] = Fault.NONE
        self.fault_text = [""] * n
        self.mode[:] = JointMode.HOLD
        self._stale = [0] * n
        self._relatch = [True] * n
        self.change_seq += 1
        self.events.emit("info", "supervisor", "reset: " + ("; ".join(cleared) if cleared else "nothing to clear"))
        return cleared

    def rearm(self, i: int) -> bool:
        """Clear joint ``i``'s drive fault once its drive is enabled again (operator ``enable``); it holds where
        it is now. Other faults stay: they need a ``reset``."""
        if self.estop or self.fault[i] not in (Fault.DRIVE, Fault.STALE_FEEDBACK):
            return False
        self.fault[i] = Fault.NONE
        self.fault_text[i] = ""
        self.mode[i] = JointMode.HOLD
        self._stale[i] = 0
        self._relatch[i] = True
        self.change_seq += 1
        return True

    def follow_measured(self, i: int, cycles: int) -> None:
        """Hold joint ``i`` with damping and gravity only (kp 0, position = the reading) for ``cycles``, then latch
        the last reading: after a drive's zero moved (the new frame's reading is latched, never a pull toward the
        old one), and while a re-enabled drive confirms (its first commands are where the shaft is)."""
        self._follow[i] = max(1, cycles)

    # ---- the final command (after the controllers) --------------------------------------------------------
    def command(self, dt: float, state: JointState, ctrl: ServoCommand, out: ServoCommand) -> None:
        pos, g = state.position, self._g
        if self.gravity is not None:
            self.gravity(pos, g)
        # One tolist() per array instead of an item() per element, and locals instead of attribute lookups: this
        # loop runs for every joint in every cycle.
        q_all, qd_all, g_all = pos.tolist(), state.velocity.tolist(), g.tolist()
        c_pos, c_vel, c_eff = ctrl.position.tolist(), ctrl.velocity.tolist(), ctrl.effort.tolist()
        c_kp, c_kd, written = ctrl.kp.tolist(), ctrl.kd.tolist(), ctrl.written.tolist()
        latched, prev, modes, old_flags = self.latched, self._prev_position, self.mode, self.limit_flags
        mode_all, prev_all, flags_all = modes.tolist(), prev.tolist(), old_flags.tolist()
        o_pos, o_vel, o_eff, o_kp, o_kd = out.position, out.velocity, out.effort, out.kp, out.kd
        owner, claims, default_kp, default_kd = self._owner, self._claims, self._default_kp, self._default_kd
        hold_kp, hold_kd, soft_lower, soft_upper = self._hold_kp, self._hold_kd, self._soft_lower, self._soft_upper
        vmax_all, emax_all, safe_action = self._vmax, self._emax, self._safe_action
        relatch, follow = self._relatch, self._follow
        check_relatch = True in relatch
        check_follow = any(follow)
        isfinite = math.isfinite
        bad_owners: list[int] | None = None
        for i, mode in enumerate(mode_all):
            q, qd, ff_gravity = q_all[i], qd_all[i], g_all[i]
            if check_relatch and relatch[i]:
                relatch[i] = False
                if isfinite(q):
                    latched[i] = q
            following = False
            if check_follow and follow[i]:  # the reading is not to be held yet: follow it, re-latch at the end
                follow[i] -= 1
                if isfinite(q):
                    latched[i] = q
                    prev_all[i] = q
                    following = True
            controlled = False

            # 1. The servo command this joint gets before limits.
            if mode >= _FAULT:
                action = safe_action[i]
                if action == _HOLD:
                    p, v, ff, kp, kd = latched.item(i), 0.0, ff_gravity, hold_kp[i], hold_kd[i]
                else:  # damp or disable: no stiffness, position field follows the arm
                    p = q if isfinite(q) else latched.item(i)
                    v, ff, kp = 0.0, 0.0, 0.0
                    kd = hold_kd[i] if action == _DAMP else 0.0
                new_mode = mode
            else:
                if written[i] and owner[i] >= 0:
                    has_p, has_v, has_e, has_kp, has_kd = claims[i]
                    p = c_pos[i] if has_p else q
                    v = c_vel[i] if has_v else 0.0
                    ff = c_eff[i] if has_e else ff_gravity
                    kp = c_kp[i] if has_kp else default_kp[i]
                    kd = c_kd[i] if has_kd else default_kd[i]
                    # Finite command and non-negative gains (NaN gains compare False, so they fail too).
                    if isfinite(p) and isfinite(v) and isfinite(ff) and kp >= 0.0 and kd >= 0.0:
                        controlled = True
                    else:  # a controller bug never reaches a drive: hold, and fail the controller
                        bad_owners = bad_owners or []
                        bad_owners.append(owner[i])
                if not controlled:
                    if mode == _CONTROLLED and isfinite(q):
                        latched[i] = q  # it just lost its controller: hold where it is now
                    p, v, ff, kp, kd = latched.item(i), 0.0, ff_gravity, hold_kp[i], hold_kd[i]
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
            tau = kp * (p - q) + kd * (v - qd) + ff  # what the drive will do; NaN if the state is unknown
            emax = emax_all[i]
            if tau > emax or tau < -emax:
                ff -= tau - (emax if tau > 0.0 else -emax)
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

    def _report_limits(self, i: int, was: int, now: int) -> None:
        for bit, word in _LIMIT_WORDS:
            if now & bit and not was & bit:
                self.events.emit("warning", "supervisor", f"joint {self.joints[i]}: {word} limit engaged")
            elif was & bit and not now & bit:
                self.events.emit("info", "supervisor", f"joint {self.joints[i]}: {word} limit released")
