"""The external force at the tool, estimated from the joints' external torques (docs/safety.md, "Contact").

A force ``F`` at the tool point shows in the joints as ``τ_ext = J_pᵀ·F`` (``J_p``: the tool point's position
Jacobian), so the force the joints' estimate implies is the damped least-squares solution

    F̂ = argmin ‖J_pᵀF − τ_ext‖² + λ²‖F‖² = (J_p J_pᵀ + λ²I)⁻¹ J_p τ_ext = G τ_ext

A push at the tool is spread over every joint that feels it, each below its own torque threshold; ``F̂`` gathers it
back into one figure in N, wherever the arm is — as Franka's Cartesian collision thresholds do. ``λ`` (m) bounds
the gain: along a direction the tool can barely move (a stretched arm, a singularity: a singular value ``σ`` of
``J_p`` small) ``F̂`` is ``σ²/(σ² + λ²)`` of the force, so a push there is seen less or not at all, never amplified
into a false alarm by the ``1/σ`` a plain pseudo-inverse has.

``F̂`` is judged two ways, and the larger counts (``excess``, N):

* **change**: ``‖F̄ − B‖``, ``F̄`` the estimate through a second low-pass (``bandwidth``: the drives' 12-bit velocity
  replies make the momentum, hence the observer's residual, noisy) and ``B`` its average over the last ``baseline``
  seconds. The model's error (masses, friction) follows the pose and the jerk-limited motion, slowly; a collision
  arrives within milliseconds. Armed once the observer has settled after a (re)start, and again after a collision's
  ``reset`` (`rearm`: the arm stopped, so the model's error changed; a force still pressing counts by its level).
* **level**: ``‖F̄‖ − ‖ |G|·margin ‖``: the whole force, less the worst image at the tool of the model's possible
  error per joint (``model_margin`` × load, N·m, either sign; |G| element-wise) — a force that built up slowly.

Allocation-free per cycle: every array is built here; the 3 × 3 inverse and the filters run on Python floats. ``G``
changes with the pose only, so it is not computed on the way to the command: `refresh` runs after the cycle's
writes, at that cycle's reading, and the next cycle's `judge` uses it — one cycle old: at 3 rad/s, 3 mrad of pose,
well under 1 % of the force.

**Most cycles judge after the writes** (docs/performance.md, "Contact safety"). The next `judge` is affine in the
next ``τ_ext``: with ``H = (1 − a)·F̄ + a·G·τ_ext`` at this cycle's estimate (`predict`, after the writes), the next
``F̄`` is ``H + a·G·Δτ_ext``, and ``‖G·Δτ_ext‖ ≤ ‖G‖_F·‖Δτ_ext‖``. So `quiet` bounds the next ``excess`` by
``max(‖H‖ − bound, ‖H − B‖) + a·‖G‖_F·‖Δτ_ext‖`` — one distance between two lists of floats — and when that bound
is below every level nothing can be reported: the cycle's command does not wait for the judgement, which runs
after the writes on the same numbers (the same arithmetic, later: the same figures to the bit).
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np


class ToolKinematics(Protocol):
    """What the estimate needs from the model (``hild.dynamics.tool.ReadingJacobian``): the tool point's position
    Jacobian at ``q`` (3 × joints), in an array the caller may only read until the next call."""

    def jacobian(self, q: np.ndarray) -> np.ndarray: ...


class ToolForce:
    """After each `judge`: ``force`` (N, world, the filtered estimate F̄), ``change``, ``level`` and ``excess`` (N)."""

    def __init__(
        self,
        tool: ToolKinematics,
        joints: int,
        *,
        damping: float,
        bandwidth: float,
        baseline: float,
        settle: float,
    ) -> None:
        if not (damping > 0.0 and bandwidth > 0.0 and baseline > 0.0 and settle >= 0.0):
            raise ValueError("tool force: damping, bandwidth and baseline must be > 0, settle ≥ 0")
        self.tool = tool
        self.damping2 = float(damping) ** 2
        self.bandwidth = float(bandwidth)
        self.baseline = float(baseline)
        self.settle = float(settle)  # s after a (re)start before a change counts: the observer's own rise
        self.change = self.level = self.excess = math.nan
        self._jac = np.zeros((3, joints))
        self._jac_t = self._jac.T
        self._jjt = np.zeros((3, 3))
        self._inverse = np.zeros((3, 3))
        self._gain = np.zeros((3, joints))  # G = (J Jᵀ + λ²I)⁻¹ J
        self._gain_abs = np.zeros((3, joints))  # |G|
        self.fresh = False  # G computed at least once since the restart
        self._raw = np.zeros(3)
        self._image = np.zeros(3)
        self._bound = 0.0  # ‖ |G|·margin ‖ (N) as of the last refresh
        self._filtered = (math.nan, math.nan, math.nan)  # F̄ and its baseline B, as floats
        self._base = (0.0, 0.0, 0.0)
        self._primed = False
        self._armed_in = 0.0
        # `predict`'s bound on the next judgement: valid after a predict, until the next judge or restart
        self._predicted = False
        self._share = 0.0  # the filter's share ``a`` the prediction assumed (the next judge's dt must give the same)
        self._reach = 0.0  # max(‖H‖ − bound, ‖H − B‖) (N)
        self._norm = 0.0  # ‖G‖_F (1/m), as of the last refresh
        self._told: list[float] = []  # the estimate the prediction was made at

    @property
    def force(self) -> np.ndarray:
        """F̄ (N, world; NaN until judged after a restart): a new array, for the events' words and inspection."""
        return np.array(self._filtered)

    def restart(self) -> None:
        """The observer restarted: forget the filter and the baseline, disarm the change until it settled."""
        self._primed = False
        self.fresh = False
        self._predicted = False
        self._filtered = (math.nan, math.nan, math.nan)
        self.change = self.level = self.excess = math.nan

    def rearm(self) -> None:
        """After a collision's reset: the change counts from here on, once ``settle`` has passed."""
        self._armed_in = self.settle

    def judge(self, q: np.ndarray, tau_ext: np.ndarray, margin: np.ndarray, dt: float) -> float:
        """Estimate the force at the tool for ``tau_ext`` at ``q``, filter it and return ``excess`` (N): the larger of
        its sudden change and its level above the model margin's image (``margin``: N·m per joint, ≥ 0; taken with G
        after a restart, else the image `refresh` computed after the last cycle's writes)."""
        self._predicted = False
        if not self.fresh:
            self.refresh(q, margin)
        self._gain.dot(tau_ext, out=self._raw)  # ndarray.dot with out: on these sizes a third of np.matmul's cost
        fx, fy, fz = self._raw.tolist()
        if self._primed:
            a = min(1.0, self.bandwidth * dt)
            f0, f1, f2 = self._filtered
            fx, fy, fz = f0 + a * (fx - f0), f1 + a * (fy - f1), f2 + a * (fz - f2)
            bx, by, bz = self._base
        else:
            bx, by, bz = fx, fy, fz
            self._primed = True
            self._armed_in = self.settle
        self._filtered = (fx, fy, fz)
        dx, dy, dz = fx - bx, fy - by, fz - bz
        if self._armed_in > 0.0:  # settling: the baseline follows exactly, no change counts
            self._armed_in -= dt
            self._base = (fx, fy, fz)
            change = 0.0
        else:
            w = min(1.0, dt / self.baseline)
            self._base = (bx + w * dx, by + w * dy, bz + w * dz)
            change = math.sqrt(dx * dx + dy * dy + dz * dz)
        level = math.sqrt(fx * fx + fy * fy + fz * fz) - self._bound
        self.change, self.level = change, level
        self.excess = change if change > level else level
        return self.excess

    def refresh(self, q: np.ndarray, margin: np.ndarray) -> None:
        """G at ``q``, the observer's latest reading (the Jacobian, ``(J Jᵀ + λ²I)⁻¹ J``, ``|G|``), and the model
        margin's image at the tool, ``‖ |G|·margin ‖``. The cycle calls it after its writes
        (``ContactMonitor.after_write``): off the path of the command, for the next cycle's `judge`, which so uses a G
        and a margin one cycle old (at 3 rad/s, 3 mrad of pose: well under 1 % of the force; the margin is a
        low-passed load)."""
        jac = self.tool.jacobian(q)  # the tool's array: valid until its next call
        if jac is not self._jac:  # the first time: its transpose as a view, prebuilt (.T makes a new one)
            self._jac, self._jac_t = jac, jac.T
        jac.dot(self._jac_t, out=self._jjt)
        self._invert(self._jjt.tolist())
        self._inverse.dot(self._jac, out=self._gain)
        np.abs(self._gain, out=self._gain_abs)
        self._gain_abs.dot(margin, out=self._image)
        ix, iy, iz = self._image.tolist()
        self._bound = math.sqrt(ix * ix + iy * iy + iz * iz)
        self._norm = math.hypot(*self._gain.ravel().tolist())
        self._predicted = False
        self.fresh = True

    def predict(self, tau_ext: np.ndarray, dt: float) -> None:
        """After the writes, once `judge` ran on this cycle's estimate ``tau_ext`` and `refresh` gave the G the next
        judge uses: what `quiet` needs to bound the next judgement (``H``, its reach; ``dt``: the next cycle's
        period as this one's)."""
        if not (self._primed and self.fresh):
            return
        a = min(1.0, self.bandwidth * dt)
        self._gain.dot(tau_ext, out=self._raw)
        gx, gy, gz = self._raw.tolist()
        f0, f1, f2 = self._filtered
        b0, b1, b2 = self._base
        hx, hy, hz = f0 + a * (gx - f0), f1 + a * (gy - f1), f2 + a * (gz - f2)
        level = math.sqrt(hx * hx + hy * hy + hz * hz) - self._bound
        dx, dy, dz = hx - b0, hy - b1, hz - b2
        change = math.sqrt(dx * dx + dy * dy + dz * dz)
        self._reach = change if change > level else level
        self._share = a
        self._told = tau_ext.tolist()
        self._predicted = True

    def quiet(self, tau_ext: list[float], dt: float, limit: float) -> bool:
        """Whether the next `judge`, on ``tau_ext`` after ``dt``, is sure to find an ``excess`` at most ``limit`` (N):
        then it may run after the writes. False whenever no prediction stands (after a restart, a refresh without
        a predict, a judge) or the period changed."""
        if not self._predicted or min(1.0, self.bandwidth * dt) != self._share:
            return False
        reach = self._reach + self._share * self._norm * math.dist(tau_ext, self._told)
        return reach * (1.0 + 1e-9) + 1e-9 < limit  # float rounding of H's arithmetic against judge's: ~1e-15 N

    def _invert(self, a: list[list[float]]) -> None:
        """``(a + λ²I)⁻¹`` of the symmetric 3 × 3 ``a`` into ``_inverse`` (cofactors: no solver call, no array)."""
        lam = self.damping2
        a00, a01, a02 = a[0][0] + lam, a[0][1], a[0][2]
        a11, a12, a22 = a[1][1] + lam, a[1][2], a[2][2] + lam
        c00 = a11 * a22 - a12 * a12
        c01 = a02 * a12 - a01 * a22
        c02 = a01 * a12 - a02 * a11
        c11 = a00 * a22 - a02 * a02
        c12 = a01 * a02 - a00 * a12
        c22 = a00 * a11 - a01 * a01
        s = 1.0 / (a00 * c00 + a01 * c01 + a02 * c02)  # > 0: λ² > 0 makes the matrix positive definite
        c00, c01, c02, c11, c12, c22 = c00 * s, c01 * s, c02 * s, c11 * s, c12 * s, c22 * s
        self._inverse[:] = ((c00, c01, c02), (c01, c11, c12), (c02, c12, c22))
