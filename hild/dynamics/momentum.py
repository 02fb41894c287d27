"""The generalized-momentum observer: an estimate of the joint torques nothing in the model explains (a contact).

With ``p = M(q)q̇`` the arm's generalized momentum, the model says ``ṗ = τ + Cᵀ(q,q̇)q̇ − g(q) + τ_ext``
(De Luca's residual; ``Ṁ = C + Cᵀ``). The observer integrates the model's side and calls the difference external:

    r = K·(p − p̂),   p̂ = p₀ + ∫(τ + Cᵀq̇ − g + r) dt

so each joint's ``r`` follows ``τ_ext`` as a first-order low-pass of bandwidth ``K`` (1/s): ``ṙ = K·(τ_ext − r)``.
No acceleration is measured or differentiated, which is why it works on encoder readings.

Discrete form (the one this module runs, once per cycle, over the interval from the previous reading to this one):
MuJoCo gives ``qfrc_bias = C q̇ + g`` and ``qfrc_passive`` (the model's joint damping and springs), so
``Cᵀq̇ − g = Ṁq̇ − qfrc_bias``, and over one interval ``∫Ṁq̇ dt ≈ (M_k − M_{k−1})·½(q̇_k + q̇_{k−1})``: the mass matrix
is differenced, never ``Ṁ`` or ``C`` formed. ``qfrc_bias`` and ``qfrc_passive`` are averaged over the interval's two
ends (trapezoid); ``τ`` is what the caller says acted over the interval. ``p̂`` is integrated with the ``r`` of the
interval's start, so the error obeys ``e_k = (1 − K·dt)·e_{k−1} + τ_ext·dt``: exact for a constant ``τ_ext``,
second-order in ``dt`` for the model terms, and stable without ringing for ``K·dt < 1`` (checked at construction).

How it runs it cheaply (it is on the cycle: docs/performance.md, "Contact safety"). With ``e = p − p̂`` the same
recursion reads, exactly,

    e_k = (1 − K·dt)·e_{k−1} + ½(M_k + M_{k−1})·(q̇_k − q̇_{k−1}) − (τ − ½(known_k + known_{k−1}))·dt,   r = K·e

(``known = qfrc_bias − qfrc_passive``), so no dense mass matrix is formed and one ``MjData`` holds it all: the
velocity step is known before the new reading is evaluated, so ``mj_mulM`` multiplies it by the previous reading's
``M`` while the data still holds it, and by the new one's right after (one ``MjData``, not two taking turns: half
the memory a cycle touches, which on the cycle costs more than the arithmetic). The 6–14 per-joint sums are plain
Python floats: a numpy call on a 6-element array costs about a microsecond, more than the arithmetic (the supervisor
does the same).

Compiled, where it could be built: the same steps in one C call (``hild/dynamics/_momentum.c``, on MuJoCo's own C
functions), which on the cycle costs about a quarter as much (4 vs 15 µs) — the Python path pays the bindings'
conversion on every MuJoCo call and the interpreter on every sum. It is used only after it gave this module's
figures to the bit on readings of this very model (checked at construction); otherwise, and where no C compiler
built it, the Python path below runs, and ``implementation`` says which and why.

Runs on the cycle thread: every array is allocated here, and ``update`` allocates no array.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from hild.arrays import contiguous_slice
from hild.dynamics.model import load_model, scalar_joint_addresses


class MomentumObserver:
    """``r`` (``residual``, one entry per joint in ``joint_names`` order): the external joint torque estimate.

    Joints of the model not in ``joint_names`` stay at the model's ``qpos0`` with zero velocity. Call ``reset``
    before the first ``update`` and whenever the torque the caller reports stops being the one that acted (a drive
    off, a reading missing): ``r`` starts again from 0, with no memory of what the model could not explain.
    """

    def __init__(
        self,
        model_path: Path,
        joint_names: Sequence[str],
        gain: float,
        period: float,
        *,
        gravity: bool = False,
        residual: np.ndarray | None = None,
        compiled: bool = True,
    ) -> None:
        """``gravity``: also compute the gravity torque at each reading it evaluates (``gravity``, `gravity_at`), for
        the supervisor's feed-forward: one evaluation of the arm's dynamics per cycle serves both. ``residual``: the
        array to keep ``r`` in (one entry per joint; written in place, never rebound), e.g. where the contact monitor
        publishes its estimate — no copy per cycle. ``compiled``: use the compiled update when it was built and
        agrees with this module to the bit (False: the Python path, e.g. to compare them)."""
        if not gain > 0.0:
            raise ValueError(f"observer gain {gain} must be > 0 (1/s)")
        if gain * period >= 1.0:
            raise ValueError(
                f"observer gain {gain:g}/s × period {period * 1e3:g} ms = {gain * period:.2f} ≥ 1: the discrete "
                f"observer would ring or diverge; use a gain below {1.0 / period:.0f}/s"
            )
        self.model = load_model(Path(model_path))
        self.joint_names = tuple(joint_names)
        self.gain = float(gain)
        try:
            _, qposadr, dofadr = scalar_joint_addresses(self.model, self.joint_names)
        except ValueError as exc:
            raise ValueError(f"model {model_path}: {exc}") from None
        m, n = self.model, len(self.joint_names)
        # Its own copy of the model: only the dynamics are wanted, never contacts or constraint forces.
        m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT) | int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
        self._dofs = [int(a) for a in dofadr]
        self._qposadr, self._dofadr = qposadr, dofadr
        self.data = d = mujoco.MjData(m)  # the last reading: its kinematics, comPos, M, qfrc_bias and qfrc_passive
        d.qpos[:] = m.qpos0
        d.qvel[:] = 0.0
        self._qpos, self._qvel = d.qpos, d.qvel  # cached views: attribute access on MjData builds a new one each time
        self._bias, self._passive = d.qfrc_bias, d.qfrc_passive
        self._step = np.zeros(m.nv)  # q̇_k − q̇_{k−1} over every dof (0 where not a joint of ours)
        self._mass = np.zeros((2, m.nv))  # M_k·Δq̇ and M_{k−1}·Δq̇, one buffer: one tolist for both
        self._mass_now, self._mass_prev = self._mass[0], self._mass[1]
        # Contacts and constraints are off in this model; with no tendon and no flex either, the position stages the
        # observer reads give the same figures as mj_fwdPosition (to the bit: tests/test_momentum.py).
        self._staged = m.ntendon == 0 and m.nflex == 0
        self._gather = np.zeros(n)  # the joints' velocity step when their dofs are not one block
        # The joints' entries as prebuilt views when they are one block of the model (the usual case).
        qb, db = contiguous_slice(qposadr), contiguous_slice(dofadr)
        self._blocks = qb is not None and db is not None
        if qb is not None and db is not None:
            self._qpos_j, self._qvel_j, self._step_j = d.qpos[qb], d.qvel[db], self._step[db]
            self._bias_j, self._passive_j = d.qfrc_bias[db], d.qfrc_passive[db]
            self._mass_j = self._mass[:, db]

        if residual is not None and residual.shape != (n,):
            raise ValueError(f"the residual's array has shape {residual.shape}, not ({n},)")
        self.residual = np.zeros(n) if residual is None else residual
        self._with_gravity = gravity
        self.evaluated_at: list[float] = []  # the positions of the last reading evaluated with ``gravity``, as floats
        self._gravity_full = np.zeros(m.nv)
        self._cvel, self._cdof_dot = d.cvel, d.cdof_dot
        self._gravity_j = self._gravity_full[db] if db is not None else None
        # g(q) at that reading (with ``gravity``): the joints' block of the RNE's output itself when they are one
        # block (no copy per cycle), else gathered into its own array
        self.gravity = self._gravity_j if self._gravity_j is not None else np.zeros(n)
        self._r = [0.0] * n  # the residual as floats: the recursion's state
        self._bias_prev = [0.0] * n  # qfrc_bias and qfrc_passive at the interval's start
        self._passive_prev = [0.0] * n
        self._kernel: Any = None
        self.implementation = "python (not asked for the compiled update)"
        if compiled:
            self._kernel, self.implementation = self._compiled()

    def __len__(self) -> int:
        return len(self.joint_names)

    @property
    def momentum(self) -> np.ndarray:
        """``p = M(q)·q̇`` at the last reading (a new array: for inspection, not for the cycle)."""
        full = np.zeros(self.model.nv)
        mujoco.mj_mulM(self.model, self.data, full, self._qvel)
        return full[self._dofs]

    def reset(self, q: np.ndarray, qd: np.ndarray) -> None:
        """Start again at this reading: ``p̂ = p``, ``r = 0``."""
        if self._kernel is not None:
            self._kernel.reset(q, qd)
            if self._with_gravity:
                self.evaluated_at = q.tolist()
            return
        self._evaluate(q, qd)
        self._bias_prev = self._joints(self._bias, "_bias_j")
        self._passive_prev = self._joints(self._passive, "_passive_j")
        self._r = [0.0] * len(self._r)
        self.residual.fill(0.0)

    def update(self, q: np.ndarray, qd: np.ndarray, tau: np.ndarray, dt: float) -> np.ndarray:
        """Advance over the interval that ends at this reading (``q``, ``qd``) and return ``residual``.

        ``tau``: the joint torque that acted over the interval, net of friction the model does not hold (the
        caller subtracts the identified friction)."""
        if self._kernel is not None:
            self._kernel.update(q, qd, tau, dt)
            if self._with_gravity:
                self.evaluated_at = q.tolist()
            return self.residual
        m, d = self.model, self.data
        if self._blocks:  # the velocity step, while the data still holds the previous reading
            np.subtract(qd, self._qvel_j, out=self._step_j)
        else:
            np.take(self._qvel, self._dofadr, out=self._gather)
            np.subtract(qd, self._gather, out=self._gather)
            np.put(self._step, self._dofadr, self._gather)
        mujoco.mj_mulM(m, d, self._mass_prev, self._step)  # M_{k−1}·Δq̇
        self._evaluate(q, qd)
        mujoco.mj_mulM(m, d, self._mass_now, self._step)  # M_k·Δq̇
        if self._blocks:
            x, y = self._mass_j.tolist()
            bias, passive = self._bias_j.tolist(), self._passive_j.tolist()
        else:
            dofs = self._dofadr
            x, y = self._mass[:, dofs].tolist()
            bias, passive = self._bias[dofs].tolist(), self._passive[dofs].tolist()
        # r_k = K·e_k = (1 − K·dt)·r_{k−1} + K·(½(M_k + M_{k−1})·Δq̇ − (τ − ½(known_k + known_{k−1}))·dt), with
        # known = qfrc_bias − qfrc_passive
        decay, half_k, k_dt = 1.0 - self.gain * dt, 0.5 * self.gain, self.gain * dt
        # zip without strict=: the keyword alone costs more than the arithmetic here (every list is n long)
        self._r = r = [
            decay * r0 + half_k * (a + b) - k_dt * (t - 0.5 * (g - p + g0 - p0))
            for r0, a, b, t, g, p, g0, p0 in zip(  # noqa: B905
                self._r, x, y, tau.tolist(), bias, passive, self._bias_prev, self._passive_prev
            )
        ]
        self.residual[:] = r
        self._bias_prev, self._passive_prev = bias, passive
        return self.residual

    def _evaluate(self, q: np.ndarray, qd: np.ndarray) -> None:
        m, d = self.model, self.data
        if self._blocks:  # slice assignment: np.copyto's dispatch costs more than the copy of n numbers
            self._qpos_j[:] = q
            self._qvel_j[:] = qd
        else:
            np.put(self._qpos, self._qposadr, q)
            np.put(self._qvel, self._dofadr, qd)
        if self._staged:  # only the position stages the observer reads: mj_fwdPosition also factors M, and more
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            mujoco.mj_makeM(m, d)  # composite inertias and M
        else:  # tendons or flexes: their lengths feed the passive forces
            mujoco.mj_fwdPosition(m, d)
        if self._with_gravity:  # g(q) alone: RNE with no body velocity (mj_fwdVelocity sets them again next)
            self._cvel.fill(0.0)
            self._cdof_dot.fill(0.0)
            mujoco.mj_rne(m, d, 0, self._gravity_full)
            if self._gravity_j is None:
                np.take(self._gravity_full, self._dofadr, out=self.gravity)
            self.evaluated_at = q.tolist()
        mujoco.mj_fwdVelocity(m, d)  # qfrc_passive, and qfrc_bias = C(q, q̇)q̇ + g(q)

    def gravity_at(self, q: np.ndarray, out: np.ndarray) -> bool:
        """Write g(``q``) into ``out`` if ``q`` is the reading last evaluated (the usual cycle: the supervisor asks at
        the reading the observer just took) and say so; False, leaving ``out`` alone, otherwise."""
        if not self._with_gravity or q.tolist() != self.evaluated_at:
            return False
        out[:] = self.gravity
        return True

    def _compiled(self) -> tuple[Any, str]:
        """The compiled update on this observer's arrays, if it was built and agrees with the Python path to the bit
        on a few readings of this model; else None, and why (``implementation``)."""
        from hild.dynamics.compiled import momentum_kernel  # the C side's plumbing: addresses, not arithmetic

        kernel, why = momentum_kernel(self)
        if kernel is None:
            return None, f"python ({why})"
        disagreement = self._compare(kernel)
        if disagreement:
            return None, f"python (the compiled update disagreed with it: {disagreement})"
        return kernel, "compiled"

    def _compare(self, kernel: Any) -> str:
        """Run the Python path and ``kernel`` over the same readings from a reset; '' if every residual and gravity
        torque is identical to the bit, else the first difference. Leaves the observer to be reset by its user."""
        rng = np.random.default_rng(0)
        n, dt = len(self), 1e-3
        low, high = self.model.jnt_range[[self.model.joint(j).id for j in self.joint_names]].T
        span = np.where(high > low, high - low, 2.0)
        centre = np.where(high > low, 0.5 * (high + low), 0.0)
        readings = [
            (centre + span * rng.uniform(-0.4, 0.4, n), rng.uniform(-2.0, 2.0, n), rng.uniform(-20.0, 20.0, n))
            for _ in range(4)
        ]
        kept = self.residual.copy(), self.gravity.copy()  # the residual may be the cycle log's: left as found
        runs = []
        for use in (None, kernel):
            self._kernel = use
            self.reset(readings[0][0], readings[0][1])
            out = []
            for q, qd, tau in readings[1:]:
                out.append((self.update(q, qd, tau, dt).copy(), self.gravity.copy()))
            runs.append(out)
        self._kernel = None
        self.residual[:], self.gravity[:] = kept
        self.evaluated_at = []
        for k, ((r_py, g_py), (r_c, g_c)) in enumerate(zip(*runs, strict=True)):
            if r_py.tobytes() != r_c.tobytes():
                return f"residual at reading {k + 1}: {r_c.tolist()} vs {r_py.tolist()}"
            if self._with_gravity and g_py.tobytes() != g_c.tobytes():
                return f"gravity at reading {k + 1}: {g_c.tolist()} vs {g_py.tolist()}"
        return ""

    def _joints(self, full: np.ndarray, view: str) -> list[float]:
        """The joints' entries of a per-dof array, as floats (set-up and reset: not every cycle)."""
        return getattr(self, view).tolist() if self._blocks else full[self._dofadr].tolist()
