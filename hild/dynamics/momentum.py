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

Runs on the cycle thread: every array is allocated here, and ``update`` allocates nothing.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

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
        m, n, nv = self.model, len(self.joint_names), self.model.nv
        self._data = d = mujoco.MjData(m)
        d.qpos[:] = m.qpos0
        d.qvel[:] = 0.0
        # Cached views: attribute access on MjData builds a new ndarray each time.
        self._qpos, self._qvel = d.qpos, d.qvel
        self._bias_all, self._passive_all = d.qfrc_bias, d.qfrc_passive
        self._qposadr, self._dofadr = qposadr, dofadr
        qb, db = contiguous_slice(qposadr), contiguous_slice(dofadr)
        self._qpos_view = self._qpos[qb] if qb is not None else None
        self._qvel_view = self._qvel[db] if db is not None else None
        self._full = np.zeros((nv, nv))
        self._flat = (dofadr[:, None] * nv + dofadr[None, :]).ravel()  # the joints' block of the full matrix
        self._rne = np.zeros(nv)
        if hasattr(d, "qM"):  # MuJoCo 3: mj_fullM(m, dst, qM)
            qm, full = d.qM, self._full
            self._dense_mass = lambda: mujoco.mj_fullM(m, full, qm)
        else:  # MuJoCo 4: mj_fullM(m, d, dst)
            self._dense_mass = lambda: mujoco.mj_fullM(m, d, self._full)

        self.residual = np.zeros(n)
        self.momentum = np.zeros(n)  # p = M(q)·q̇ at the last update
        self._estimate = np.zeros(n)  # p̂
        self._mass = np.zeros((n, n))
        self._mass_flat = self._mass.reshape(-1)  # a view, prebuilt: reshape makes a new one each call
        self._mass_prev = np.zeros((n, n))
        self._mass_prev_flat = self._mass_prev.reshape(-1)
        self._mass_step = np.zeros((n, n))
        self._known = np.zeros(n)  # qfrc_bias − qfrc_passive at this reading
        self._known_prev = np.zeros(n)
        self._qd_prev = np.zeros(n)
        self._qd_mid = np.zeros(n)
        self._tmp = np.zeros(n)
        self._tmp2 = np.zeros(n)

    def __len__(self) -> int:
        return len(self.joint_names)

    def reset(self, q: np.ndarray, qd: np.ndarray) -> None:
        """Start again at this reading: ``p̂ = p``, ``r = 0``."""
        self._evaluate(q, qd)
        np.copyto(self._estimate, self.momentum)
        np.copyto(self._mass_prev, self._mass)
        np.copyto(self._known_prev, self._known)
        np.copyto(self._qd_prev, qd)
        self.residual.fill(0.0)

    def update(self, q: np.ndarray, qd: np.ndarray, tau: np.ndarray, dt: float) -> np.ndarray:
        """Advance over the interval that ends at this reading (``q``, ``qd``) and return ``residual``.

        ``tau``: the joint torque that acted over the interval, net of friction the model does not hold (the
        caller subtracts the identified friction)."""
        self._evaluate(q, qd)
        est, tmp, tmp2, mid = self._estimate, self._tmp, self._tmp2, self._qd_mid
        # ∫Ṁq̇ dt ≈ (M_k − M_{k−1})·½(q̇_k + q̇_{k−1})
        np.add(qd, self._qd_prev, out=mid)
        mid *= 0.5
        np.subtract(self._mass, self._mass_prev, out=self._mass_step)
        np.dot(self._mass_step, mid, out=tmp)
        est += tmp
        # ∫(τ − (bias − passive) + r) dt, bias and passive by the trapezoid
        np.add(self._known, self._known_prev, out=tmp2)
        tmp2 *= -0.5
        tmp2 += tau
        tmp2 += self.residual
        tmp2 *= dt
        est += tmp2
        # r = K (p − p̂)
        np.subtract(self.momentum, est, out=self.residual)
        self.residual *= self.gain
        # This reading is the next interval's start.
        self._mass_prev, self._mass = self._mass, self._mass_prev
        self._mass_prev_flat, self._mass_flat = self._mass_flat, self._mass_prev_flat
        self._known_prev, self._known = self._known, self._known_prev
        np.copyto(self._qd_prev, qd)
        return self.residual

    def _evaluate(self, q: np.ndarray, qd: np.ndarray) -> None:
        """M(q) (the joints' block), p = M q̇, and qfrc_bias − qfrc_passive at (q, q̇), into the current buffers."""
        m, d = self.model, self._data
        if self._qpos_view is not None and self._qvel_view is not None:
            np.copyto(self._qpos_view, q)
            np.copyto(self._qvel_view, qd)
        else:
            np.put(self._qpos, self._qposadr, q)
            np.put(self._qvel, self._dofadr, qd)
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_makeM(m, d)  # composite rigid bodies plus armature, into qM
        mujoco.mj_comVel(m, d)
        mujoco.mj_passive(m, d)
        mujoco.mj_rne(m, d, 0, self._rne)  # without acceleration: C q̇ + g, i.e. qfrc_bias
        self._dense_mass()
        np.take(self._full, self._flat, out=self._mass_flat)
        np.dot(self._mass, qd, out=self.momentum)
        np.take(self._rne, self._dofadr, out=self._known)
        np.take(self._passive_all, self._dofadr, out=self._tmp)
        self._known -= self._tmp
