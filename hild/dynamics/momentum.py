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
``MjData`` still holds. When the model's passive force is its joint damping alone (checked at construction),
``−D·q̇`` is added here instead of calling ``mj_passive``. The 6–14 per-joint sums are plain Python floats: a numpy
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

CHECK_STATES = 3  # random readings the damping-only passive force is checked at


class _Reading:
    """One ``MjData`` holding a reading: its kinematics, mass matrix (``qM``) and ``qfrc_bias`` at (q, q̇)."""

    def __init__(self, model: mujoco.MjModel, qposadr: np.ndarray, dofadr: np.ndarray) -> None:
        self.model = model
        self.data = d = mujoco.MjData(model)
        d.qpos[:] = model.qpos0
        d.qvel[:] = 0.0
        self.qpos, self.qvel, self.passive = d.qpos, d.qvel, d.qfrc_passive  # cached: MjData builds views per access
        self.qposadr, self.dofadr = qposadr, dofadr
        self.bias = np.zeros(model.nv)
        self.mass_step = np.zeros(model.nv)  # M of this reading × the velocity step
        # The joints' entries as prebuilt views when they are one block of the model (the usual case).
        qb, db = contiguous_slice(qposadr), contiguous_slice(dofadr)
        self.qpos_view = self.qpos[qb] if qb is not None else None
        self.qvel_view = self.qvel[db] if db is not None else None
        self.joint_bias = self.bias[db] if db is not None else None
        self.joint_mass_step = self.mass_step[db] if db is not None else None
        self.joint_passive = self.passive[db] if db is not None else None

    def evaluate(self, q: np.ndarray, qd: np.ndarray, passive: bool) -> None:
        m, d = self.model, self.data
        if self.qpos_view is not None and self.qvel_view is not None:
            np.copyto(self.qpos_view, q)
            np.copyto(self.qvel_view, qd)
        else:
            np.put(self.qpos, self.qposadr, q)
            np.put(self.qvel, self.dofadr, qd)
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_makeM(m, d)  # composite rigid bodies plus armature, into qM
        mujoco.mj_comVel(m, d)
        if passive:
            mujoco.mj_passive(m, d)
        mujoco.mj_rne(m, d, 0, self.bias)  # without acceleration: C q̇ + g, i.e. qfrc_bias

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
        self._dofs = [int(a) for a in dofadr]
        self._damping_only = _passive_is_damping(m, qposadr, dofadr)  # else mj_passive at every reading
        # qfrc_passive = −D·q̇ is added per joint; with another passive force, known − D·q̇ comes from mj_passive.
        self._damping = [float(m.dof_damping[a]) if self._damping_only else 0.0 for a in self._dofs]
        self._now = _Reading(m, qposadr, dofadr)  # this reading
        self._prev = _Reading(m, qposadr, dofadr)  # the previous one: the interval's start
        self._step = np.zeros(m.nv)  # q̇_k − q̇_{k−1} over every dof (0 where not a joint of ours)

        self.residual = np.zeros(n)
        self._r = [0.0] * n  # the residual as floats: the recursion's state
        self._known_prev = [0.0] * n  # qfrc_bias − qfrc_passive − D·q̇ at the interval's start
        self._qd_prev = [0.0] * n

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
        now.evaluate(q, qd, not self._damping_only)
        self._known_prev = self._known(now)
        self._qd_prev = qd.tolist()
        self._r = [0.0] * len(self._r)
        self.residual.fill(0.0)

    def update(self, q: np.ndarray, qd: np.ndarray, tau: np.ndarray, dt: float) -> np.ndarray:
        """Advance over the interval that ends at this reading (``q``, ``qd``) and return ``residual``.

        ``tau``: the joint torque that acted over the interval, net of friction the model does not hold (the
        caller subtracts the identified friction)."""
        self._prev, self._now = prev, now = self._now, self._prev  # the last reading is the interval's start
        m = self.model
        now.evaluate(q, qd, not self._damping_only)
        np.subtract(now.qvel, prev.qvel, out=self._step)
        mujoco.mj_mulM(m, now.data, now.mass_step, self._step)
        mujoco.mj_mulM(m, prev.data, prev.mass_step, self._step)
        known, v = self._known(now), qd.tolist()
        # r_k = K·e_k = (1 − K·dt)·r_{k−1} + K·(½(M_k + M_{k−1})·Δq̇ − (τ − ½(known_k + known_{k−1}))·dt), with
        # known = qfrc_bias + D·q̇ (+ the rest of −qfrc_passive when the model has more than damping).
        decay, half_k, k_dt = 1.0 - self.gain * dt, 0.5 * self.gain, self.gain * dt
        self._r = r = [
            decay * r0 + half_k * (x + y) - k_dt * (t - 0.5 * (g + g0 + c * (v1 + v0)))
            for r0, x, y, t, g, g0, c, v1, v0 in zip(
                self._r,
                now.joints(now.mass_step, now.joint_mass_step),
                prev.joints(prev.mass_step, prev.joint_mass_step),
                tau.tolist(),
                known,
                self._known_prev,
                self._damping,
                v,
                self._qd_prev,
                strict=True,
            )
        ]
        self.residual[:] = r
        self._known_prev, self._qd_prev = known, v
        return self.residual

    def _known(self, reading: _Reading) -> list[float]:
        """``qfrc_bias − qfrc_passive`` per joint at ``reading``, less the damping ``D·q̇`` the update adds."""
        bias = reading.joints(reading.bias, reading.joint_bias)
        if self._damping_only:
            return bias
        passive = reading.joints(reading.passive, reading.joint_passive)
        return [g - p for g, p in zip(bias, passive, strict=True)]


def _passive_is_damping(model: mujoco.MjModel, qposadr: np.ndarray, dofadr: np.ndarray) -> bool:
    """Whether ``mj_passive`` gives exactly ``−dof_damping·q̇`` here (no springs, tendons, fluid or gravity
    compensation), tried at a few random readings of the joints: then the observer need not call it."""
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    for _ in range(CHECK_STATES):
        data.qpos[:] = model.qpos0
        data.qvel[:] = 0.0
        data.qpos[qposadr] = rng.uniform(-1.0, 1.0, len(qposadr))
        data.qvel[dofadr] = rng.uniform(-2.0, 2.0, len(dofadr))
        mujoco.mj_forward(model, data)
        expected = -model.dof_damping * data.qvel
        if not np.allclose(data.qfrc_passive, expected, rtol=1e-12, atol=1e-12):
            return False
    return True
