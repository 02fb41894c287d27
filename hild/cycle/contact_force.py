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

Allocation-free per cycle: every array is built here; the 3 × 3 inverse and the filters run on Python floats. To
stay within a few µs a cycle, ``G`` is refreshed in two halves on alternate cycles (the Jacobian at this cycle's
``q``, then ``G`` from it), so the ``G`` a cycle uses is one to two cycles old: at 3 rad/s, 3–6 mrad of pose, about
1 % of the force.
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
        self.force = np.full(3, np.nan)
        self.change = self.level = self.excess = math.nan
        self._jac = np.zeros((3, joints))
        self._jjt = np.zeros((3, 3))
        self._inverse = np.zeros((3, 3))
        self._gain = np.zeros((3, joints))  # G = (J Jᵀ + λ²I)⁻¹ J
        self._gain_abs = np.zeros((3, joints))  # |G|
        self._phase = 0  # 0: the Jacobian is refreshed this cycle, 1: G from it
        self._fresh = False  # G computed at least once since the restart
        self._raw = np.zeros(3)
        self._image = np.zeros(3)
        self._filtered = [0.0, 0.0, 0.0]
        self._base = [0.0, 0.0, 0.0]
        self._primed = False
        self._armed_in = 0.0

    def restart(self) -> None:
        """The observer restarted: forget the filter and the baseline, disarm the change until it settled."""
        self._primed = False
        self._fresh = False
        self.force.fill(np.nan)
        self.change = self.level = self.excess = math.nan

    def rearm(self) -> None:
        """After a collision's reset: the change counts from here on, once ``settle`` has passed."""
        self._armed_in = self.settle

    def judge(self, q: np.ndarray, tau_ext: np.ndarray, margin: np.ndarray, dt: float) -> float:
        """Estimate the force at the tool for ``tau_ext`` at ``q``, filter it and return ``excess`` (N): the larger of
        its sudden change and its level above the model margin's image (``margin``: N·m per joint, ≥ 0)."""
        self._estimate(q, tau_ext, margin)
        fx, fy, fz = self._raw.tolist()
        ix, iy, iz = self._image.tolist()
        bound = math.sqrt(ix * ix + iy * iy + iz * iz)
        f, b = self._filtered, self._base
        if not self._primed:
            f[0], f[1], f[2] = fx, fy, fz
            b[0], b[1], b[2] = fx, fy, fz
            self._primed = True
            self._armed_in = self.settle
        else:
            a = min(1.0, self.bandwidth * dt)
            f[0] += a * (fx - f[0])
            f[1] += a * (fy - f[1])
            f[2] += a * (fz - f[2])
        dx, dy, dz = f[0] - b[0], f[1] - b[1], f[2] - b[2]
        change = math.sqrt(dx * dx + dy * dy + dz * dz)
        if self._armed_in > 0.0:  # settling: the baseline follows exactly, no change counts
            self._armed_in -= dt
            b[0], b[1], b[2] = f[0], f[1], f[2]
            change = 0.0
        else:
            w = min(1.0, dt / self.baseline)
            b[0] += w * dx
            b[1] += w * dy
            b[2] += w * dz
        self.force[0], self.force[1], self.force[2] = f[0], f[1], f[2]
        level = math.sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]) - bound
        self.change, self.level = change, level
        self.excess = change if change > level else level
        return self.excess

    def _estimate(self, q: np.ndarray, tau_ext: np.ndarray, margin: np.ndarray) -> None:
        """``_raw`` = G·tau_ext and ``_image`` = |G|·margin, G refreshed in halves (both at once after a restart).
        ``ndarray.dot`` with ``out``, not ``np.matmul``: on these sizes it costs a third as much."""
        if not self._fresh or self._phase == 0:
            self._jac = self.tool.jacobian(q)  # the tool's array: read again next cycle, before its next call
        if not self._fresh or self._phase == 1:
            jac = self._jac
            jac.dot(jac.T, out=self._jjt)
            self._invert(self._jjt.tolist())
            self._inverse.dot(jac, out=self._gain)
            np.abs(self._gain, out=self._gain_abs)
        self._fresh = True
        self._phase ^= 1
        self._gain.dot(tau_ext, out=self._raw)
        self._gain_abs.dot(margin, out=self._image)

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
        inv = self._inverse
        inv[0, 0], inv[0, 1], inv[0, 2] = c00 * s, c01 * s, c02 * s
        inv[1, 0], inv[1, 1], inv[1, 2] = c01 * s, c11 * s, c12 * s
        inv[2, 0], inv[2, 1], inv[2, 2] = c02 * s, c12 * s, c22 * s
