"""Virtual walls: the commanded tool point stays inside a box and out of half-spaces (docs/safety.md, "Virtual
walls").

Applied on the cycle to the controllers' commands, after the controller manager's update and before the
supervisor's command, to the joints an active controller commands with a position this cycle. Each wall is a
half-space ``n·p ≤ b`` (``n`` its outward unit normal, ``b`` the wall pulled in by ``margin``); the tool point
``p(q)`` comes from the arm model (``hild.dynamics.tool.ToolPoint``). Per cycle:

1. The command is first limited as the supervisor will limit it (soft limits, then at most ``velocity · dt`` from
   the last command), so the pose checked is the pose sent.
2. **Lead.** Each wall is pulled in by ``lead_time`` × the measured tool's speed toward it: a position-controlled
   arm runs behind its command and carries on past a command that stops. (Skipped when even the largest speed the
   joints' measured velocities allow, ``ToolPoint.reach``, could not bring a bound to the command.)
3. **Braking envelope.** From the last command's tool point at distance ``h`` inside a wall, the new one may come
   at most ``min(h, dt·√(2·deceleration·h))`` closer: the commanded tool's speed toward a wall never exceeds
   ``√(2·deceleration·h)``, so it brakes to a stop *on* the wall rather than stopping dead at full speed. A last
   command already beyond a wall (the arm was pushed there, or a controller took over there) may not go deeper,
   only back.
4. **Projection.** A command beyond those bounds is moved back by the minimum-norm joint correction of the
   violated rows ``Δq = −Aᵀ(AAᵀ + λI)⁻¹·excess`` (``A = N·J``: the walls' normals times the tool's position
   Jacobian, columns of the corrected joints only), re-limited to the slew bound and iterated (``ITERATIONS``);
   what is still beyond by more than ``TOLERANCE`` then is not sent: the last command is repeated (a stop).
   Every correction stays within the supervisor's slew bound (step 1), so the corrected command never jumps.
5. **Velocity.** The velocity feed-forward of the corrected joints loses its component toward each engaged wall
   beyond the envelope's speed there (zero on the wall itself): the drive is never told to keep moving into it.

With ``self_collision`` (``hild.dynamics.collision.SelfCollision``), the command that results is then checked
against the model's collision geometry: a pose where two of the arm's bodies would touch, reached from a last
command where they did not, is refused — the corrected joints repeat their last command, with no velocity
feed-forward — and that is an event too (once per refusal, released after ``RELEASE_TIME`` without one).

A held joint, a faulted one and a joint commanded without a position are never moved: a hold never fights a wall.
Engagement and release are events, once per wall: engaged when it first corrects a command, released when it has
corrected nothing for ``RELEASE_TIME``. Allocation: the per-cycle lists of the joints' values (as in the supervisor)
while a position controller runs; a few arrays of at most walls × joints more while a wall corrects, and the
contact list while MuJoCo finds a contact.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from hild.arrays import JointState, ServoCommand
from hild.controller import JointLimitArrays
from hild.interfaces import ClaimMasks
from hild.modes import JointMode

RELEASE_TIME = 0.1  # s without a correction before a wall is released (no event chatter while sliding along it)
ITERATIONS = 3  # projections per cycle: the tool point is not linear in q
TOLERANCE = 1e-4  # m still beyond a bound after the iterations: the command stops instead
INSIDE = 1e-6  # m: each projection aims this far inside, so rounding leaves it on the safe side
DAMPING = 1e-8  # m²: keeps the projection bounded where the walls' rows are nearly singular
SOURCE = "walls"
_CONTROLLED = int(JointMode.CONTROLLED)


class ToolKinematics(Protocol):
    frame: str
    reach: np.ndarray

    def __len__(self) -> int: ...
    def position(self, q: np.ndarray, out: np.ndarray | None = None) -> np.ndarray: ...
    def jacobian(self, out: np.ndarray) -> np.ndarray: ...


class Collider(Protocol):
    def touching(self, q: np.ndarray) -> tuple[str, str] | None: ...


@dataclass(frozen=True)
class Walls:
    """Half-spaces ``normals[k]·p ≤ offsets[k]`` (unit outward normals; the walls themselves, no margin)."""

    names: tuple[str, ...]
    normals: np.ndarray  # walls × 3
    offsets: np.ndarray  # walls

    @classmethod
    def of(cls, cfg: Any) -> Walls:
        """From ``safety.walls``: the box's six faces (``x_min`` … ``z_max``), then the planes."""
        names: list[str] = []
        normals: list[Sequence[float]] = []
        points: list[Sequence[float]] = []
        if cfg.box is not None:
            for axis, word in enumerate("xyz"):
                for side, corner in ((-1.0, cfg.box.min), (1.0, cfg.box.max)):
                    normal = [0.0, 0.0, 0.0]
                    normal[axis] = side
                    names.append(f"box {word}_{'max' if side > 0 else 'min'}")
                    normals.append(normal)
                    points.append(corner)
        for k, plane in enumerate(cfg.planes):
            names.append(plane.name or f"plane[{k}]")
            normals.append(plane.normal)
            points.append(plane.point)
        n = np.array(normals, dtype=float).reshape(-1, 3)
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        return cls(tuple(names), n, np.einsum("ij,ij->i", n, np.array(points, dtype=float).reshape(-1, 3)))

    def depth(self, point: np.ndarray) -> float:
        """How far ``point`` lies beyond the walls (m): the largest signed distance, negative when inside all."""
        return float((self.normals @ point - self.offsets).max())

    def deepest(self, point: np.ndarray) -> str:
        return self.names[int(np.argmax(self.normals @ point - self.offsets))]


class WallGuard:
    def __init__(
        self,
        tool: ToolKinematics,
        walls: Walls,
        *,
        margin: float,
        deceleration: float,
        lead_time: float,
        limits: JointLimitArrays,
        update_rate: float,
        emit: Callable[[str, str, str], None],
        collision: Collider | None = None,
    ) -> None:
        """Everything the cycle touches is allocated here. ``emit(level, source, text)``: the engine's events."""
        n, k = len(tool), len(walls.names)
        self.tool, self.walls = tool, walls
        self.margin, self.deceleration, self.lead_time = margin, deceleration, lead_time
        self.emit = emit
        self._bound = walls.offsets - margin
        self._bound_list = self._bound.tolist()
        self._reach = tool.reach.tolist()  # per joint: the most the tool moves per rad (m) or per m
        self._soft_lower, self._soft_upper = limits.soft_lower.tolist(), limits.soft_upper.tolist()
        self._vmax = limits.velocity.tolist()
        self._q, self._prev = np.zeros(n), np.zeros(n)
        self._lo, self._hi = np.zeros(n), np.zeros(n)
        self._ours, self._ours_v = np.zeros(n), np.zeros(n)  # 1.0 for the joints corrected (position, velocity)
        self._along_prev, self._along = np.zeros(k), np.zeros(k)  # normals · tool point
        self._upper, self._excess = np.zeros(k), np.zeros(k)
        self._effective = np.zeros(k)  # each wall's bound this cycle: margin and the measured speed's lead taken off
        self._speed, self._toward = np.zeros(3), np.zeros(k)  # the measured tool's velocity; its part toward each wall
        self._jac = np.zeros((3, n))
        self._release_after = max(1, round(RELEASE_TIME * update_rate))
        self._quiet = [0] * k  # cycles since each engaged wall last corrected; -1: not engaged
        self._quiet[:] = [-1] * k
        self.engaged: tuple[str, ...] = ()  # published: the walls engaged now, for status
        self.change_seq = 0
        self.corrections = 0  # cycles in which a command was corrected (tests, the bench)
        self._count = k
        self.collision = collision  # safety.walls.self_collision: refuse commanded poses where the arm touches itself
        self.refused: tuple[str, ...] = ()  # published: the pair of bodies of the refusal going on, else ()
        self._refused_quiet = 0
        self.refusals = 0  # cycles in which a command was refused (tests, the bench)

    @property
    def frame(self) -> str:
        return self.tool.frame

    def measured_depth(self, q: np.ndarray) -> float:
        """How far the tool at joint positions ``q`` lies beyond the walls themselves (margin not counted), in m;
        negative inside. For tests and the bench (it moves the private pose: not between a cycle's two calls)."""
        return self.walls.depth(self.tool.position(q))

    def status(self) -> dict[str, Any]:
        return {"tool": self.tool.frame, "engaged": list(self.engaged), "self_collision": list(self.refused)}

    # ---- the cycle --------------------------------------------------------------------------------------------
    def apply(
        self,
        dt: float,
        state: JointState,
        command: ServoCommand,
        last: ServoCommand,
        masks: ClaimMasks,
        modes: np.ndarray,
    ) -> None:
        """Correct ``command`` in place (``last``: the final command of the previous cycle, as sent)."""
        q_meas = state.position.tolist()
        c_pos, written = command.position.tolist(), command.written.tolist()
        claims, v_claims, mode_all = masks.position.tolist(), masks.velocity.tolist(), modes.tolist()
        l_pos, l_kp = last.position.tolist(), last.kp.tolist()
        q, prev, lo, hi, ours, ours_v = self._q, self._prev, self._lo, self._hi, self._ours, self._ours_v
        found = False
        for i, measured in enumerate(q_meas):
            target = c_pos[i]
            if written[i] and claims[i] and mode_all[i] <= _CONTROLLED and math.isfinite(target):
                found = True
                # The supervisor's slew limit starts from the last stiff command, else from the reading.
                origin = l_pos[i] if l_kp[i] > 0.0 else measured
                step = self._vmax[i] * dt
                low = max(self._soft_lower[i], origin - step)
                high = min(self._soft_upper[i], origin + step)
                prev[i], lo[i], hi[i] = origin, low, high
                q[i] = min(max(target, low), high)
                ours[i], ours_v[i] = 1.0, 1.0 if v_claims[i] else 0.0
            else:
                prev[i] = q[i] = lo[i] = hi[i] = measured
                ours[i] = ours_v[i] = 0.0
        if not found or not math.isfinite(sum(q_meas)):
            self._quiet_cycle()
            self._accepted()
            return
        if self._count:
            self._keep_inside(dt, state, command)
        if self.collision is not None:
            self._refuse_collisions(command)

    def _keep_inside(self, dt: float, state: JointState, command: ServoCommand) -> None:
        """Steps 2–5 of the module docstring on ``_q`` (the command, limited as the supervisor will limit it)."""
        q, ours = self._q, self._ours
        qd_meas = state.velocity.tolist()
        speed = sum(abs(v) * r for v, r in zip(qd_meas, self._reach, strict=True))  # ≥ the measured tool's speed
        if not math.isfinite(speed):
            speed = 0.0
        normals, tool = self.walls.normals, self.tool
        np.matmul(normals, tool.position(self._prev), out=self._along_prev)
        np.matmul(normals, tool.position(q), out=self._along)
        # Fast path: with every wall pulled in by the most the lead could take, nothing is beyond a bound.
        self._bounds(dt, self.lead_time * speed, None)
        if not self._beyond():
            self._quiet_cycle()
            return
        if self.lead_time > 0.0 and speed > 0.0:
            self._lead(state)
            self._bounds(dt, 0.0, self._toward.tolist())
            self._measure(q)  # back to the command's pose (the lead moved the private pose)
            if not self._beyond():
                self._quiet_cycle()
                return
        hit = self._excess > 0.0
        self._project()
        self._limit_velocity(command.velocity, hit)
        np.copyto(command.position, q, where=ours > 0.0)
        self.corrections += 1
        self._engage(hit)

    def _refuse_collisions(self, command: ServoCommand) -> None:
        """A command that would make the arm touch itself, from a last command that did not, is not sent: the
        corrected joints repeat their last command with no velocity feed-forward (a stop). A last command already
        in collision (the arm was pushed there while held) is not held against: the arm may move out of it."""
        assert self.collision is not None
        pair = self.collision.touching(self._q)
        if pair is None or self.collision.touching(self._prev) is not None:
            self._accepted()
            return
        np.copyto(command.position, self._prev, where=self._ours > 0.0)
        np.copyto(command.velocity, 0.0, where=self._ours_v > 0.0)
        np.copyto(self._q, self._prev)
        self.refusals += 1
        self._refused_quiet = 0
        if not self.refused:
            self.refused = pair
            self.emit(
                "warning",
                SOURCE,
                f"self-collision: {pair[0]} and {pair[1]} would touch at the commanded pose; the command is refused "
                "and the joints hold the last safe command",
            )
            self.change_seq += 1

    def _accepted(self) -> None:
        if self.refused:
            self._refused_quiet += 1
            if self._refused_quiet >= self._release_after:
                self.refused = ()
                self.emit("info", SOURCE, "self-collision: commands are accepted again")
                self.change_seq += 1

    def _lead(self, state: JointState) -> None:
        """The measured tool's speed toward each wall (``_toward``, ≥ 0): the arm runs behind its command by about
        ``lead_time`` × that, and would carry on that far past a command that stopped on the wall."""
        self.tool.position(state.position)
        self.tool.jacobian(self._jac)
        np.matmul(self._jac, state.velocity, out=self._speed)
        np.matmul(self.walls.normals, self._speed, out=self._toward)
        np.maximum(self._toward, 0.0, out=self._toward)

    def _bounds(self, dt: float, lead: float, toward: list[float] | None) -> None:
        """Each wall's bound on ``normal · point`` this cycle (``_upper``): the wall minus the margin, pulled in by
        ``lead`` (m) or by ``lead_time`` × ``toward`` (m/s per wall), then the braking envelope from the last
        command. The bound only grows with the distance left, so the largest pull-in gives the smallest bounds."""
        two_a_dt2 = 2.0 * self.deceleration * dt * dt
        upper, effective, bound, lead_time = self._upper, self._effective, self._bound_list, self.lead_time
        for k, along in enumerate(self._along_prev.tolist()):
            wall = bound[k] - (lead if toward is None else lead_time * toward[k])
            effective[k] = wall
            inside = wall - along
            if inside <= 0.0:  # the last command is beyond (or on) it: no deeper
                upper[k] = along
            else:
                upper[k] = along + min(inside, math.sqrt(two_a_dt2 * inside))

    def _beyond(self) -> bool:
        np.subtract(self._along, self._upper, out=self._excess)
        return bool(self._excess.max() > 0.0)

    def _measure(self, q: np.ndarray) -> None:
        np.matmul(self.walls.normals, self.tool.position(q), out=self._along)
        np.subtract(self._along, self._upper, out=self._excess)

    def _rows(self, active: np.ndarray, columns: np.ndarray) -> np.ndarray:
        """The active walls' rows ``normal · ∂point/∂q`` at the last pose measured, restricted to ``columns``."""
        self.tool.jacobian(self._jac)
        np.multiply(self._jac, columns, out=self._jac)
        return self.walls.normals[active] @ self._jac

    def _project(self) -> None:
        q, excess = self._q, self._excess
        for _ in range(ITERATIONS):
            active = excess > 0.0
            rows = self._rows(active, self._ours)
            gram = rows @ rows.T
            gram.flat[:: len(gram) + 1] += DAMPING
            q -= rows.T @ np.linalg.solve(gram, excess[active] + INSIDE)
            np.clip(q, self._lo, self._hi, out=q)
            self._measure(q)
            if not excess.max() > 0.0:
                return
        if excess.max() > TOLERANCE:  # not reachable within one step: stop where the last command was
            np.copyto(q, self._prev)
            self._measure(q)

    def _limit_velocity(self, velocity: np.ndarray, hit: np.ndarray) -> None:
        """Remove the feed-forward's speed toward each engaged wall beyond what its envelope allows there."""
        if not self._ours_v.any():
            return
        rows = self._rows(hit, self._ours_v)
        inside = np.maximum(self._effective[hit] - self._along[hit], 0.0)
        allowed = np.sqrt(2.0 * self.deceleration * inside)
        over = rows @ velocity - allowed
        fast = over > 0.0
        if fast.any():
            rows = rows[fast]
            gram = rows @ rows.T
            gram.flat[:: len(gram) + 1] += DAMPING
            velocity -= rows.T @ np.linalg.solve(gram, over[fast])

    # ---- engagement -------------------------------------------------------------------------------------------
    def _engage(self, hit: np.ndarray) -> None:
        quiet, hits = self._quiet, hit.tolist()
        new = [k for k, h in enumerate(hits) if h and quiet[k] < 0]
        for k, cycles in enumerate(quiet):
            if hits[k]:
                quiet[k] = 0
            elif cycles >= 0:
                self._count_quiet(k)
        for k in new:
            self.emit(
                "warning",
                SOURCE,
                f"virtual wall {self.walls.names[k]} engaged: the tool's command ({self.tool.frame}) is held inside it",
            )
        if new:
            self._publish()

    def _quiet_cycle(self) -> None:
        for k, cycles in enumerate(self._quiet):
            if cycles >= 0:
                self._count_quiet(k)

    def _count_quiet(self, k: int) -> None:
        self._quiet[k] += 1
        if self._quiet[k] >= self._release_after:
            self._quiet[k] = -1
            self.emit("info", SOURCE, f"virtual wall {self.walls.names[k]} released")
            self._publish()

    def _publish(self) -> None:
        self.engaged = tuple(name for name, cycles in zip(self.walls.names, self._quiet, strict=True) if cycles >= 0)
        self.change_seq += 1
