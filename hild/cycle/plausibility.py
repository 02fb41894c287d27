"""Plausibility before trust: every reading is checked before the supervisor, a controller or a model uses it.

A drive's reading is input like any other. A reading is **plausible** when

* its position and velocity are finite,
* its position lies inside the hard limits widened by ``margin`` (a joint may rest on its end stop), and
* its position is no further from the last *accepted* reading than the joint could have moved since:
  ``factor · velocity_limit · (elapsed + dt + slack) + tolerance``, ``dt`` the reading's own cycle, ``slack`` one
  period (a reply shows the shaft at some moment of the last period, not at the cycle's start: a reading a period
  out of step after a short cycle is motion, not a jump — found beside busy processes, where a moving joint was
  rejected once and then faulted on readings that continued it). ``elapsed`` is the
  wall time since that reading over cycles that brought *no* reading, and only until a reading is rejected: a
  rejected reading is evidence too, and a missing reply during a rejection streak is no evidence that the shaft
  moved — were the window to widen over a streak, any persistent jump would fit at last (issue 28: a +0.3 rad
  offset accepted after 35 rejected readings with lost replies between them). So a persistent jump never becomes
  acceptable because time passed, however many replies go missing; it stays rejected until an operator ``reset``
  re-anchors the joint;
* and, while readings are being rejected as a jump, it does not *continue* that jump: a reading no further from
  the last rejected one than the joint could have moved since (same bound, over the time since that one) is the
  same jump — the offset reading of a sensor whose offset stays, however long the gap between the two — even
  where it would pass the check above (a late cycle's long ``dt``). When the offset goes away, the step back from
  the last rejected reading is itself a jump and the true reading is accepted; only after a gap so long that the
  step back could be motion (or after the shaft itself moved beyond the window) does it stay rejected — steady
  readings, which ``reset`` re-anchors on;
* and it is not a **frozen** position: one that stays bit-identical while the velocity reported beside it adds up
  to more than ``FROZEN_TRAVEL`` of motion. Once caught, the same value stays suspect until the reading moves
  (a frozen encoder whose drive then reports standstill is still frozen).

A rejected reading counts like a missing one: the gate writes the last accepted position and velocity back into
the state and marks it not fresh, so the supervisor's stale logic decides when nonsense becomes a fault, and
nothing downstream — a hold latch, a gravity pose, a trajectory start, a ``joint_states`` sample — ever sees the
bad value (``rejected`` flags the joints whose state is a stand-in). Each episode of rejections is reported once
when it starts (with the first reason) and once when it ends. The per-cycle work is a loop over plain floats that
allocates nothing while readings are plausible.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from hild.arrays import JointState

FROZEN_TRAVEL = 0.02  # rad: motion the reported velocity may claim while the position does not change at all
FROZEN_MIN_SPEED = 0.05  # rad/s: below this a reported velocity is noise and says nothing about a frozen encoder
STEADY_READINGS = 10  # rejected readings in a row, each a plausible step from the one before: a moved frame
# (a plausible step: within factor · velocity_limit · the time between the two + tolerance, lost replies included)

# Why the current episode began (the words are built only when an episode starts).
NONE, NON_FINITE, BEYOND_LIMITS, JUMP, FROZEN = 0, 1, 2, 3, 4

EmitFn = Callable[[str, str], None]  # (level, message)


class FeedbackGate:
    """Checks each cycle's readings (joint space) against the last accepted ones and stands in for bad ones."""

    def __init__(
        self,
        joints: tuple[str, ...],
        lower: np.ndarray,
        upper: np.ndarray,
        velocity_limit: np.ndarray,
        *,
        margin: float,
        factor: float,
        tolerance: float,
        emit: EmitFn,
        slack: float = 0.0,
    ) -> None:
        """``slack``: seconds of timing uncertainty in each reading (the cycle's period: a reply shows the shaft at
        some moment of the last period, not at the cycle's start), added to the time a reading may have moved over."""
        n = len(joints)
        self.joints = joints
        self.emit = emit
        self.tolerance = tolerance
        self.slack = slack
        self._lower = (lower - margin).tolist()
        self._upper = (upper + margin).tolist()
        self._speed = (velocity_limit * factor).tolist()
        self.accepted_position = np.full(n, np.nan)  # published: the last reading trusted, per joint
        self.accepted_velocity = np.zeros(n)
        self.rejected = np.zeros(n, dtype=bool)  # published: this cycle's state is a stand-in, not a reading
        self.all_known = False  # every joint has had an accepted reading (the gravity pose needs no fill-in)
        self.cause = [NONE] * n  # why the current episode began; NONE when the joint's readings are trusted
        self.reason: list[str] = [""] * n  # the words for it (kept after the episode, for fault texts)
        self._accepted = [math.nan] * n
        self._accepted_v = [0.0] * n
        self._elapsed = [0.0] * n
        self._anchor = [True] * n  # accept the next finite reading inside the limits without a step check
        self._rejections = [0] * n
        self._last_raw = [math.nan] * n
        self._frozen_travel = [0.0] * n
        self._steady = [0] * n  # rejected readings in a row that move plausibly among themselves
        self._raw_age = [0.0] * n  # s since ``_last_raw`` arrived (before this cycle)
        self._on_jump = [False] * n  # ``_last_raw`` is a rejected jump: a reading within its reach is the same one

    # ---- between cycles ------------------------------------------------------------------------------------
    def start(self, state: JointState) -> None:
        """Anchor on the start-up read (taken as fresh); a joint without a usable reading has no position yet."""
        self._anchor = [True] * len(self.joints)
        state.fresh.fill(True)
        self.filter(state, 0.0)

    def reanchor(self, i: int) -> None:
        """The next finite reading inside the limits is accepted as it is: an operator ``reset`` says the readings
        are right again, and a set-zero moves the drive's frame on purpose."""
        self._anchor[i] = True

    def steady(self, i: int) -> bool:
        """Joint ``i``'s rejected readings agree among themselves (each a plausible step from the one before over
        the time between them, inside the limits, not frozen): the sensor works and the shaft is where it says, only
        far from where it was last accepted — a drive's frame that moved (a reboot, a lost turn count), a steady
        offset, or motion while readings were rejected. Only ``reset`` makes such readings the truth."""
        return self._steady[i] >= STEADY_READINGS

    def untrusted(self, i: int) -> bool:
        """Joint ``i`` has no accepted reading now: its current readings are rejected, or it never had one."""
        return self.cause[i] != NONE or math.isnan(self._accepted[i])

    # ---- the cycle -----------------------------------------------------------------------------------------
    def filter(self, state: JointState, dt: float) -> None:
        """Accept or reject each joint's reading in place; rejected and missing ones are replaced by the last
        accepted values and marked not fresh."""
        pos, vel, fresh_arr = state.position, state.velocity, state.fresh
        q_all, qd_all, fresh_all = pos.tolist(), vel.tolist(), fresh_arr.tolist()
        accepted, accepted_v, elapsed, anchor = self._accepted, self._accepted_v, self._elapsed, self._anchor
        lower, upper, speed, tol = self._lower, self._upper, self._speed, self.tolerance
        last_raw, travel, cause, rejected = self._last_raw, self._frozen_travel, self.cause, self.rejected
        raw_age, on_jump = self._raw_age, self._on_jump
        isfinite = math.isfinite
        span = dt + self.slack  # this reading's own time, and the uncertainty of when it was taken
        for i, q in enumerate(q_all):
            if not fresh_all[i]:  # no reading: the joint may have moved meanwhile…
                if cause[i] == NONE:  # …but during a rejection streak that never widens the window (docstring)
                    elapsed[i] += dt
                raw_age[i] += dt
                self._stand_in(i, pos, vel, rejected_now=False)
                continue
            qd = qd_all[i]
            why = NONE
            if not (isfinite(q) and isfinite(qd)):
                why = NON_FINITE
            elif q < lower[i] or q > upper[i]:
                why = BEYOND_LIMITS
            elif not anchor[i] and abs(q - accepted[i]) > speed[i] * (elapsed[i] + span) + tol:
                why = JUMP
            elif not anchor[i] and on_jump[i] and abs(q - last_raw[i]) <= speed[i] * (raw_age[i] + span) + tol:
                why = JUMP  # it continues the rejected jump: the same offset, not the shaft coming back
            elif cause[i] == FROZEN and q == last_raw[i]:
                why = FROZEN  # once caught, a frozen encoder stays suspect until its reading moves again
            else:
                if q == last_raw[i] and (qd >= FROZEN_MIN_SPEED or qd <= -FROZEN_MIN_SPEED):
                    travel[i] += qd * dt
                    if travel[i] > FROZEN_TRAVEL or travel[i] < -FROZEN_TRAVEL:
                        why = FROZEN
                elif q != last_raw[i]:
                    travel[i] = 0.0
            if why == NONE:
                last_raw[i] = q
                raw_age[i] = 0.0
                on_jump[i] = False
                accepted[i] = q
                accepted_v[i] = qd
                elapsed[i] = 0.0
                anchor[i] = False
                self._steady[i] = 0
                if cause[i] != NONE:
                    self._end_episode(i, q)
                if rejected[i]:
                    rejected[i] = False
                continue
            if why == JUMP and abs(q - last_raw[i]) <= speed[i] * (raw_age[i] + span) + tol:
                self._steady[i] += 1
            else:
                self._steady[i] = 0
            if isfinite(q):
                last_raw[i] = q
                raw_age[i] = 0.0
                on_jump[i] = why == JUMP
            else:
                raw_age[i] += dt
            if cause[i] == NONE:
                self._begin_episode(i, why, q, qd, dt)
            self._rejections[i] += 1
            fresh_arr[i] = False
            self._stand_in(i, pos, vel, rejected_now=True)
        self.accepted_position[:] = accepted
        self.accepted_velocity[:] = accepted_v
        if not self.all_known:
            self.all_known = not any(a != a for a in accepted)  # NaN is the only value unequal to itself

    def _stand_in(self, i: int, pos: np.ndarray, vel: np.ndarray, *, rejected_now: bool) -> None:
        """Write the last accepted reading where the driver left a missing or rejected one (NaN when the joint
        never had one: the supervisor then knows it has no position)."""
        pos[i] = self._accepted[i]
        vel[i] = self._accepted_v[i]
        if self.rejected[i] != rejected_now:
            self.rejected[i] = rejected_now

    def _begin_episode(self, i: int, why: int, q: float, qd: float, dt: float) -> None:
        self.cause[i] = why
        self._rejections[i] = 0
        last = self._accepted[i]
        if why == NON_FINITE:
            text = f"non-finite reading (position {q}, velocity {qd})"
        elif why == BEYOND_LIMITS:
            lo, hi = self._lower[i], self._upper[i]
            text = f"position {q:.4g} rad outside the hard limits and their margin [{lo:.4g}, {hi:.4g}]"
        elif why == JUMP:
            span = self._elapsed[i] + dt  # the time it had, as it happened (the slack is the gate's allowance)
            implied = abs(q - last) / span if span > 0.0 else math.inf
            text = f"jump of {q - last:+.4g} rad in {span * 1000:.3g} ms ({implied:.3g} rad/s implied)"
        else:
            text = f"position frozen at {q:.4g} rad while the drive reports {qd:.3g} rad/s"
        self.reason[i] = text
        held = f"; held at the last accepted {last:.4g} rad" if math.isfinite(last) else "; no accepted reading yet"
        self.emit("warning", f"joint {self.joints[i]}: reading rejected: {text}{held}")

    def _end_episode(self, i: int, q: float) -> None:
        count = self._rejections[i]
        self.cause[i] = NONE
        self.emit("info", f"joint {self.joints[i]}: readings plausible again at {q:.4g} rad after {count} rejected")
