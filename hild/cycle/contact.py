"""Contact detection and the collision reflex (docs/safety.md, "Contact").

Every cycle, right after the supervisor has gated the readings: the torque that acted over the last interval (the
drive's torque reply where it reports one, else the torque the last final command predicts through the servo law,
saturated at the effort limit), minus the identified friction, goes into the momentum observer
(``hild.dynamics.momentum``), whose residual ``tau_ext`` is each joint's external torque estimate. Per joint:

* above its **contact** threshold: a ``warning`` event (once per episode), nothing stops;
* above its **collision** threshold: the reflex (the supervisor's ``collide``: every joint latches
  ``Fault.COLLISION`` and holds compliantly, kp lowered, zero velocity; or first retracts along the recent measured
  path) and the engine deactivates every commanding controller, as an e-stop does. The fault names the joint and
  the torque and stays until ``reset``.

Both thresholds rise by ``model_margin`` × the joint's low-passed motor torque: a model whose masses are 10 % off
explains 10 % of the torque wrongly, most of all in fast motion and abrupt stops.

With ``safety.contact.force``, the same two levels in N on the force at the tool the torques imply
(``hild.cycle.contact_force``): a push at the tool spreads over the joints below each one's threshold. A collision
there is reported as joint index ``len(joints)``, "the tool".

The observer only runs on torques it can trust: while any reading is not fresh, a joint has another fault, an
e-stop or the stop descent runs, it restarts at every cycle (``tau_ext`` is NaN, published as null) and detects
nothing. Allocation-free per cycle; events and the reflex's set-up allocate, once.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from hild.arrays import JointState, ServoCommand
from hild.cycle.contact_force import ToolForce
from hild.dynamics.friction import FrictionArrays

NONE, CONTACT, COLLISION = 0, 1, 2
HISTORY = 1.0  # s of measured positions kept for the retract
RELEASE = 0.5  # a contact ends below this fraction of its threshold (hysteresis: one event per episode)
SEARCH_POINTS = 64  # tool positions computed at most to find where the retract goes


class Observer(Protocol):
    residual: np.ndarray

    def reset(self, q: np.ndarray, qd: np.ndarray) -> None: ...

    def update(self, q: np.ndarray, qd: np.ndarray, tau: np.ndarray, dt: float) -> np.ndarray: ...


ToolFn = Callable[[np.ndarray], np.ndarray]  # joint positions → the tool's position (m)


@dataclass(frozen=True)
class ContactSettings:
    """``safety.contact`` as the cycle uses it: per-joint arrays in the robot's order."""

    gain: float
    use_reply: bool
    contact: np.ndarray
    collision: np.ndarray
    model_margin: float
    retract: bool
    reflex_stiffness: float
    retract_distance: float
    retract_time: float
    force_contact: float = math.inf  # N at the tool (safety.contact.force); inf: no Cartesian detection
    force_collision: float = math.inf


class ContactMonitor:
    def __init__(
        self,
        joints: tuple[str, ...],
        settings: ContactSettings,
        observer: Observer,
        *,
        effort_limit: np.ndarray,
        applies_gains: np.ndarray,
        friction: FrictionArrays,
        emit: Callable[[str, str, str], None],
        update_rate: float,
        tool: ToolFn | None = None,
        tool_force: ToolForce | None = None,
        tau_ext: np.ndarray | None = None,
    ) -> None:
        n = len(joints)
        self.joints = joints
        self.settings = settings
        self.observer = observer
        self.friction = friction
        self._has_friction = friction.any  # none identified: nothing to subtract (3 µs a cycle saved)
        self.tool = tool
        self._emit = emit
        self._emax = effort_limit.tolist()
        self._applies = [bool(a) for a in applies_gains]
        self._use_reply = settings.use_reply
        self._contact, self._collision = settings.contact.tolist(), settings.collision.tolist()

        # published: the estimate, NaN while the observer cannot run (``tau_ext``: the array to keep it in, e.g. the
        # engine's cycle-log row; written in place, never rebound)
        self.tau_ext = np.full(n, np.nan) if tau_ext is None else tau_ext
        self.tau_ext.fill(np.nan)
        self.level = [NONE] * n  # per joint: NONE, CONTACT or COLLISION (its last episode's peak)
        self.collided = False  # a collision was detected and not yet reset: detection paused, tau_ext goes on
        self.running = False
        self._tau = np.zeros(n)  # net torque over the last interval, when the replies alone do not give it
        self._net = [0.0] * n  # the net torque over the last interval, as floats
        self._raw = [0.0] * n  # the motor torque over the last interval (friction not taken off), as floats
        self._gain = settings.gain
        self._friction = np.zeros(n)
        self._qd_mid = np.zeros(n)
        self._q_prev = [0.0] * n  # the interval's start, as floats: the per-joint sums run on Python floats
        self._qd_prev = [0.0] * n
        self._load = [0.0] * n  # low-passed |motor torque|: what model_margin scales
        self._extra = [0.0] * n  # what model_margin adds to each joint's thresholds this cycle (N·m)
        self._deferred = -1.0  # a quiet check's load update still to do: this cycle's low-pass share, or < 0: none
        self._judge_due = 0.0  # a quiet force check's judgement still to do: this cycle's dt, or 0: none
        self._force_limit = min(settings.force_contact, settings.force_collision)

        size = max(2, round(HISTORY * update_rate))
        self._history = np.zeros((size, n))
        self._rows = list(self._history)  # prebuilt row views: no view object per cycle
        self._head = 0
        self._filled = 0
        self._keeps_path = settings.retract  # only the retract needs the recent path
        self._retract: tuple[np.ndarray, np.ndarray] | None = None  # (from, to) while the reflex retracts
        self._retract_t = 0.0
        self._step = np.zeros(n)
        self.tool_force = tool_force  # the Cartesian check, or None (per-joint thresholds only)
        self.force_level = NONE
        self._margin = np.zeros(n)
        self._values: list[float] = []  # this cycle's estimate as floats
        self._last_dt = 0.0

    # ---- every cycle ------------------------------------------------------------------------------------------
    def observe(self, state: JointState, last: ServoCommand, trusted: bool, dt: float) -> int:
        """Advance the observer over the interval that ended at this reading; the joint whose external torque
        crossed its collision threshold (the largest crossing), or -1.

        ``last``: the final command sent at the interval's start. ``trusted``: every reading fresh and accepted, no
        joint faulted but by a collision, no e-stop and no stop descent: the torque the observer is told acted."""
        if self._deferred >= 0.0:  # the last check's load update is still due (no after_write since)
            self._settle_load()
        if self._judge_due > 0.0:  # and its force judgement (tau_ext still holds the estimate it was for)
            self._judge_later(state.position)
        q, qd = state.position, state.velocity
        if self._keeps_path:
            np.copyto(self._rows[self._head], q)
            self._head = (self._head + 1) % len(self._rows)
            self._filled = min(self._filled + 1, len(self._rows))
        if not trusted or dt <= 0.0 or not self.running:  # not running: the first trusted reading starts it here
            self._restart(q, qd)
            return -1
        tau = self._motor_torque(state, last)
        r = self.observer.update(q, qd, tau, dt)
        if r is not self.tau_ext:  # the engine's observer writes it there itself
            self.tau_ext[:] = r  # slice assignment: cheaper than np.copyto's dispatch on n numbers
        self._values = values = r.tolist()
        alpha = min(1.0, self._gain * dt)
        if self._quiet(values):  # nothing near a threshold: the load's update waits until after the writes
            self._deferred, worst = alpha, -1
        else:
            worst = self._classify(values, alpha)
        return worst if self.tool_force is None else self._classify_force(q, r, dt, worst)  # the force at the tool

    def after_write(self, q: np.ndarray) -> None:
        """After the cycle's writes: what the next cycle's check needs and this cycle's command does not — the force
        estimate's G at this reading (``q``) and the image of the joints' model margins at the tool. Off the path
        of the command, so it never delays one. Also the load update a quiet check left for now (`_quiet`)."""
        if self._deferred >= 0.0:
            self._settle_load()
        if self._judge_due > 0.0:  # before the refresh: with the G the check would have used
            dt = self._judge_due
            self._judge_later(q)
            if self.tool_force is not None:
                self._margin[:] = self._extra
                self.tool_force.refresh(q, self._margin)
                self.tool_force.predict(self.tau_ext, dt)
            return
        if self.running and self.tool_force is not None:
            self._margin[:] = self._extra  # each joint's model margin, as its thresholds rose in this cycle's check
            self.tool_force.refresh(q, self._margin)
            if self.tool_force.fresh and not math.isnan(self.tool_force.excess):
                self.tool_force.predict(self.tau_ext, self._last_dt)

    def _restart(self, q: np.ndarray, qd: np.ndarray) -> None:
        self.running = False
        self.tau_ext.fill(np.nan)
        if self.tool_force is not None:
            self.tool_force.restart()
        if not (np.isfinite(q).all() and np.isfinite(qd).all()):
            return
        self.observer.reset(q, qd)
        self.tau_ext.fill(np.nan)  # the observer may keep its residual (0 after a reset) in this very array
        self._q_prev, self._qd_prev = q.tolist(), qd.tolist()
        self.running = True

    def _motor_torque(self, state: JointState, last: ServoCommand) -> np.ndarray:
        """Per joint, the torque that acted over the interval, minus friction (at the mean speed): into ``_net`` as
        floats, and returned as the array the observer is told (the replies themselves when they are all of it).
        This reading becomes the next interval's start."""
        q, qd = state.position.tolist(), state.velocity.tolist()
        q0, qd0 = self._q_prev, self._qd_prev
        self._q_prev, self._qd_prev = q, qd
        reply = state.effort.tolist()
        every_reply = self._use_reply and math.isfinite(sum(reply))  # a NaN or inf in any would show
        if every_reply and not self._has_friction:  # the usual cycle: the drives' replies are the torque
            self._raw = self._net = reply
            return state.effort
        if every_reply:
            tau = reply
        else:
            p, v, ff = last.position.tolist(), last.velocity.tolist(), last.effort.tolist()
            kp, kd = last.kp.tolist(), last.kd.tolist()
            emax, applies, use_reply = self._emax, self._applies, self._use_reply
            tau = []
            for i in range(len(q)):
                t = reply[i]
                if not (use_reply and math.isfinite(t)):
                    if applies[i]:  # the servo law at the interval's mean state: the trapezoid of its two ends
                        t = kp[i] * (p[i] - 0.5 * (q[i] + q0[i])) + kd[i] * (v[i] - 0.5 * (qd[i] + qd0[i])) + ff[i]
                    else:
                        t = ff[i]
                    t = min(max(t, -emax[i]), emax[i])
                tau.append(t)
        self._raw = tau
        self._tau[:] = tau
        if self._has_friction:
            self._qd_mid[:] = [0.5 * (a + b) for a, b in zip(qd, qd0, strict=True)]
            self.friction.torque(self._qd_mid, self._friction)
            self._tau -= self._friction
            tau = self._tau.tolist()
        self._net = tau
        return self._tau

    def _quiet(self, r: list[float]) -> bool:
        """Every joint's estimate within its own contact threshold before the model margin, no joint in a contact
        episode, and the force check's margin image not due now: then this check can neither report nor release
        anything (the margin only raises the thresholds, and contact ≤ collision), so the per-joint load update is
        all `_classify` would do, and it waits until after the writes (`_settle_load`). Exact: the same arithmetic,
        later."""
        if any(self.level) or (self.tool_force is not None and not self.tool_force.fresh):
            return False
        for x, contact in zip(r, self._contact):  # noqa: B905 (strict= costs more than this loop; both are n long)
            if x > contact or -x > contact:
                break
        else:
            return True
        return False

    def _settle_load(self) -> None:
        """The load update and model margin a quiet check deferred (the same arithmetic as `_classify`'s, on this
        interval's torques, still in ``_raw`` and ``_net``)."""
        alpha, self._deferred = self._deferred, -1.0
        margin, load, extras = self.settings.model_margin, self._load, self._extra
        for i, (m, t) in enumerate(zip(self._raw, self._net, strict=True)):
            held = load[i] = load[i] + alpha * ((m if m >= 0.0 else -m) - load[i])
            t = t if t >= 0.0 else -t
            extras[i] = margin * (held if held > t else t)

    def _classify(self, r: list[float], alpha: float) -> int:
        """The contact events, and the joint whose collision threshold ``r`` crossed most (or -1). Low-passes the
        load (``alpha``: this cycle's share) on the way: the thresholds rise with it."""
        level, margin = self.level, self.settings.model_margin
        worst, worst_ratio = -1, 1.0
        load, extras = self._load, self._extra
        for i, (x, m, t, contact) in enumerate(zip(r, self._raw, self._net, self._contact, strict=True)):
            a = x if x >= 0.0 else -x
            held = load[i] = load[i] + alpha * ((m if m >= 0.0 else -m) - load[i])
            t = t if t >= 0.0 else -t
            extra = extras[i] = margin * (held if held > t else t)
            contact += extra
            if a <= contact and level[i] == NONE:  # the usual cycle: nothing near a threshold, nothing to release
                continue
            collision = self._collision[i] + extra
            if a > collision and not self.collided and a / collision > worst_ratio:
                worst, worst_ratio = i, a / collision
            if a > contact and level[i] == NONE:
                level[i] = CONTACT
                if not self.collided:
                    self._emit(
                        "warning",
                        "contact",
                        f"contact on joint {self.joints[i]}: external torque {x:+.3g} N·m (contact threshold "
                        f"{contact:.3g})",
                    )
            elif level[i] != NONE and a < RELEASE * contact:
                level[i] = NONE
                if not self.collided:
                    self._emit("info", "contact", f"contact on joint {self.joints[i]} released")
        if worst >= 0:
            level[worst] = COLLISION
            self.collided = True
        return worst

    def _classify_force(self, q: np.ndarray, r: np.ndarray, dt: float, worst: int) -> int:
        """The Cartesian check (``safety.contact.force``) after the joints': the force at the tool against its two
        levels; returns ``worst``, or ``len(joints)`` (the tool) for a collision there that no joint reported."""
        tf = self.tool_force
        assert tf is not None
        self._last_dt = dt
        if self.force_level == NONE and tf.quiet(self._values, dt, self._force_limit):
            self._judge_due = dt  # nothing this judgement can find: after the writes (`after_write`)
            return worst
        if not tf.fresh:  # the first check after a restart: G and the margin's image are taken now
            self._margin[:] = self._extra
        excess = tf.judge(q, r, self._margin, dt)
        s = self.settings
        if excess > s.force_collision and not self.collided:
            self.force_level = COLLISION
            self.collided = True
            return len(self.joints) if worst < 0 else worst
        if excess > s.force_contact and self.force_level == NONE:
            self.force_level = CONTACT
            if not self.collided:
                self._emit(
                    "warning",
                    "contact",
                    f"contact at the tool: external force {self._force_words()} (contact threshold "
                    f"{s.force_contact:.3g} N)",
                )
        elif self.force_level != NONE and excess < RELEASE * s.force_contact:
            self.force_level = NONE
            if not self.collided:
                self._emit("info", "contact", "contact at the tool released")
        return worst

    def _judge_later(self, q: np.ndarray) -> None:
        """The judgement a quiet force check left for after the writes: on the same estimate (``tau_ext``), with the
        same G; `quiet` proved its excess below every level, so it reports nothing."""
        tf = self.tool_force
        assert tf is not None
        tf.judge(q, self.tau_ext, self._margin, self._judge_due)
        self._judge_due = 0.0

    def _force_words(self) -> str:
        tf = self.tool_force
        assert tf is not None
        fx, fy, fz = tf.force.tolist()
        return (
            f"{math.sqrt(fx * fx + fy * fy + fz * fz):.3g} N ({fx:+.3g}, {fy:+.3g}, {fz:+.3g}; a change of "
            f"{tf.change:.3g} N, {tf.level:.3g} N above the model margin)"
        )

    # ---- the reflex --------------------------------------------------------------------------------------------
    def describe(self, i: int) -> str:
        """The collision fault's words: the joint, its torque and the threshold it crossed (or the tool's force)."""
        if i == len(self.joints):
            return (
                f"collision at the tool: external force {self._force_words()} (collision threshold "
                f"{self.settings.force_collision:.3g} N); reflex: {'retract' if self.settings.retract else 'hold'}"
            )
        x = float(self.tau_ext[i])
        extra = self.settings.model_margin * max(self._load[i], abs(self._net[i]))
        return (
            f"collision on {self.joints[i]}: external torque {x:+.3g} N·m (collision threshold "
            f"{self._collision[i] + extra:.3g}); reflex: {'retract' if self.settings.retract else 'hold'}"
        )

    def begin_reflex(self, q: np.ndarray) -> str:
        """Plan the retract from ``q`` (the measured position at detection) back along the recent path; what it
        found, in words ("" for the hold reflex)."""
        if not self.settings.retract:
            return ""
        target, moved = self._retract_target(q)
        if moved <= 0.0:
            return "; no recent motion to retract along: holds"
        self._retract = (q.copy(), target)
        self._retract_t = 0.0
        return f"; retracts {moved * 1000:.1f} mm along its path over {self.settings.retract_time:g} s"

    def _retract_target(self, q: np.ndarray) -> tuple[np.ndarray, float]:
        """The newest recorded position at least ``retract_distance`` from the tool's position now (or the oldest
        one, if the arm has not moved that far in ``HISTORY``), and how far from it the tool is there."""
        if self.tool is None or self._filled < 2:
            return q.copy(), 0.0
        size, want = len(self._rows), self.settings.retract_distance
        here = self.tool(q).copy()  # the tool function may answer in one buffer it reuses
        ages = list(range(1, self._filled))  # 1 = the newest before now
        stride = max(1, len(ages) // SEARCH_POINTS)

        def at(age: int) -> tuple[np.ndarray, float]:
            row = self._rows[(self._head - 1 - age) % size]
            return row, float(np.linalg.norm(self.tool(row) - here))

        previous = 0
        for age in [*ages[::stride], ages[-1]]:
            row, dist = at(age)
            if dist >= want:  # refine within the last stride: the newest point far enough
                for finer in range(previous + 1, age + 1):
                    row, dist = at(finer)
                    if dist >= want:
                        return row.copy(), dist
            previous = age
        row, dist = at(ages[-1])
        return row.copy(), dist

    @property
    def retracting(self) -> bool:
        return self._retract is not None

    def reflex_step(self, dt: float, target: np.ndarray) -> None:
        """While retracting: write this cycle's hold target into ``target`` (the supervisor's latched positions),
        a cosine blend from where the collision was detected to the retract point over ``retract_time``."""
        if self._retract is None:
            return
        start, end = self._retract
        self._retract_t += dt
        s = min(1.0, self._retract_t / self.settings.retract_time)
        w = 0.5 - 0.5 * math.cos(math.pi * s)
        np.subtract(end, start, out=self._step)
        self._step *= w
        np.add(start, self._step, out=target)
        if s >= 1.0:
            self._retract = None

    def clear(self) -> None:
        """After ``reset``: detect again (a contact that persists trips again on the next cycle)."""
        self.collided = False
        self._retract = None
        self.level = [NONE] * len(self.level)
        self.force_level = NONE
        if self.tool_force is not None:
            self.tool_force.rearm()
