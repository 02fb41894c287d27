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

(``known = qfrc_bias − qfrc_passive``), so no dense mass matrix is formed: two ``MjData`` take turns holding the
reading, and ``mj_mulM`` multiplies the velocity step by the new reading's ``M`` and by the previous one's, which its
``MjData`` still holds. The 6–14 per-joint sums are plain Python floats: a numpy
call on a 6-element array costs about a microsecond, more than the arithmetic (the supervisor does the same).

Runs on the cycle thread: every array is allocated here, and ``update`` allocates no array.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import mujoco
import numpy as np

from hild.arrays import contiguous_slice
from hild.dynamics.model import load_model, scalar_joint_addresses


class _Reading:
    """One ``MjData`` holding a reading: its kinematics, mass matrix (``qM``), ``qfrc_bias`` and ``qfrc_passive``."""

    def __init__(self, model: mujoco.MjModel, qposadr: np.ndarray, dofadr: np.ndarray) -> None:
        self.model = model
        self.data = d = mujoco.MjData(model)
        d.qpos[:] = model.qpos0
        d.qvel[:] = 0.0
        self.qpos, self.qvel = d.qpos, d.qvel  # cached views: attribute access on MjData builds a new one each time
        self.bias, self.passive = d.qfrc_bias, d.qfrc_passive
        self.qposadr, self.dofadr = qposadr, dofadr
        self.mass_step = np.zeros(model.nv)  # M of this reading × the velocity step
        # The joints' entries as prebuilt views when they are one block of the model (the usual case).
        qb, db = contiguous_slice(qposadr), contiguous_slice(dofadr)
        self.qpos_view = self.qpos[qb] if qb is not None else None
        self.qvel_view = self.qvel[db] if db is not None else None
        self.joint_bias = self.bias[db] if db is not None else None
        self.joint_passive = self.passive[db] if db is not None else None
        self.joint_mass_step = self.mass_step[db] if db is not None else None

    def evaluate(self, q: np.ndarray, qd: np.ndarray) -> None:
        m, d = self.model, self.data
        if self.qpos_view is not None and self.qvel_view is not None:
            np.copyto(self.qpos_view, q)
            np.copyto(self.qvel_view, qd)
        else:
            np.put(self.qpos, self.qposadr, q)
            np.put(self.qvel, self.dofadr, qd)
        # Two calls, not the stages they run one by one (kinematics, com, M; com velocities, passive, bias): on 6
        # joints a call into MuJoCo costs more than a stage. Contacts and constraints are off in this model.
        mujoco.mj_fwdPosition(m, d)
        mujoco.mj_fwdVelocity(m, d)

    def joints(self, full: np.ndarray, view: np.ndarray | None) -> list[float]:
        """The joints' entries of a per-dof array of this reading, as floats."""
        return view.tolist() if view is not None else full[self.dofadr].tolist()


class MomentumObserver:
    """``r`` (``residual``, one entry per joint in ``joint_names`` order): the external joint torque estimate.

    Joints of the model not in ``joint_names`` stay at the model's ``qpos0`` with zero velocity. Call ``reset``
    before the first ``update`` and whenever the torque the caller reports stops being the one that acted (a drive
    off, a reading missing): ``r`` starts again from 0, with no memory of what the model could not explain.
    """

    def __init__(self, model_path: Path, joint_names: Sequence[str], gain: float, period: float) -> None:
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
        self._now = _Reading(m, qposadr, dofadr)  # this reading
        self._prev = _Reading(m, qposadr, dofadr)  # the previous one: the interval's start
        self.datas = (self._now.data, self._prev.data)  # both, for who reads the model at a reading (the tool force)
        self.latest = self._now.data  # the one holding the last reading: its kinematics, comPos and M are done
        self._step = np.zeros(m.nv)  # q̇_k − q̇_{k−1} over every dof (0 where not a joint of ours)

        self.residual = np.zeros(n)
        self._r = [0.0] * n  # the residual as floats: the recursion's state
        self._bias_prev = [0.0] * n  # qfrc_bias and qfrc_passive at the interval's start
        self._passive_prev = [0.0] * n

    def __len__(self) -> int:
        return len(self.joint_names)

    @property
    def momentum(self) -> np.ndarray:
        """``p = M(q)·q̇`` at the last reading (a new array: for inspection, not for the cycle)."""
        now = self._now
        full = np.zeros(self.model.nv)
        mujoco.mj_mulM(self.model, now.data, full, now.qvel)
        return full[self._dofs]

    def reset(self, q: np.ndarray, qd: np.ndarray) -> None:
        """Start again at this reading: ``p̂ = p``, ``r = 0``."""
        now = self._now
        now.evaluate(q, qd)
        self.latest = now.data
        self._bias_prev, self._passive_prev = (
            now.joints(now.bias, now.joint_bias),
            now.joints(now.passive, now.joint_passive),
        )
        self._r = [0.0] * len(self._r)
        self.residual.fill(0.0)

    def update(self, q: np.ndarray, qd: np.ndarray, tau: np.ndarray, dt: float) -> np.ndarray:
        """Advance over the interval that ends at this reading (``q``, ``qd``) and return ``residual``.

        ``tau``: the joint torque that acted over the interval, net of friction the model does not hold (the
        caller subtracts the identified friction)."""
        self._prev, self._now = prev, now = self._now, self._prev  # the last reading is the interval's start
        m = self.model
        now.evaluate(q, qd)
        self.latest = now.data
        np.subtract(now.qvel, prev.qvel, out=self._step)
        mujoco.mj_mulM(m, now.data, now.mass_step, self._step)
        mujoco.mj_mulM(m, prev.data, prev.mass_step, self._step)
        bias, passive = now.joints(now.bias, now.joint_bias), now.joints(now.passive, now.joint_passive)
        # r_k = K·e_k = (1 − K·dt)·r_{k−1} + K·(½(M_k + M_{k−1})·Δq̇ − (τ − ½(known_k + known_{k−1}))·dt), with
        # known = qfrc_bias − qfrc_passive
        decay, half_k, k_dt = 1.0 - self.gain * dt, 0.5 * self.gain, self.gain * dt
        self._r = r = [
            decay * r0 + half_k * (x + y) - k_dt * (t - 0.5 * (g - p + g0 - p0))
            for r0, x, y, t, g, p, g0, p0 in zip(
                self._r,
                now.joints(now.mass_step, now.joint_mass_step),
                prev.joints(prev.mass_step, prev.joint_mass_step),
                tau.tolist(),
                bias,
                passive,
                self._bias_prev,
                self._passive_prev,
                strict=True,
            )
        ]
        self.residual[:] = r
        self._bias_prev, self._passive_prev = bias, passive
        return self.residual
