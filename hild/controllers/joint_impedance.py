"""joint_impedance: per-joint stiffness, damping and feed-forward torque around a target (docs/controllers.md,
"joint_impedance").

Each joint gets the servo law ``τ = k·(p_t − q) + d·(v_t − q̇) + τ_ff + gravity``: a spring of stiffness ``k`` toward
the target position, damping ``d`` toward the target velocity, a feed-forward torque, and the robot model's gravity
torque added on top by the supervisor (``gravity_joints``). Targets come from one of two places:

* **streamed** on its ``target`` input (positions, and optionally velocities, efforts, stiffness, damping per
  joint). After ``command_timeout`` of silence (cycle clock) the target velocity and feed-forward go to 0 and the
  position target stays: the joints hold *compliantly* at the last target, with the stiffness and damping they had;
* **chained**: another controller configured with ``chain_to: <this one>`` claims its reference interfaces
  ``<name>/<joint>/<position|velocity|effort|kp|kd>`` (a joint_trajectory or servo on position and velocity); the
  manager hands it this controller's ``references`` as its command, and this update reads them in the same cycle.
  A field the chained controller does not claim takes this controller's default (velocity and effort 0, the
  configured stiffness and damping); a joint it leaves unwritten in a cycle keeps its last target. The streamed
  input is refused while chained.

Stiffness and damping never jump: they move toward their targets by at most ``stiffness_rate·dt`` and
``damping_rate·dt`` per cycle, are never negative and never above ``max_stiffness``/``max_damping``. The spring's
set point moves at most ``velocity_limit·dt`` per cycle and stays within the soft limits. Activation is bumpless:
the target is the measured position, the gains ramp from what the drive last had.

Drives that apply kp and kd (MIT protocol, the twin) get the law itself: ``position, velocity, effort, kp, kd``.
Drives that do not (``APPLIES_GAINS`` False, the ODrive) cannot: their joints are listed in ``pd_on_effort`` and the
law runs here, once per cycle, on the effort path (``effort = k·(p_t − q) + d·(v_t − q̇) + τ_ff``, kp = kd = 0 to the
drive). That spring is sampled: it sees ``q`` one cycle late and a velocity estimated by the drive, so its stable
stiffness is bounded by the cycle rate (docs/controllers.md, "Drives that do not apply gains").
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from hild.arrays import JointState, ServoCommand
from hild.config.params import Field, Params, dynamic, model_validator
from hild.controller import Controller, ControllerContext, and_more, unknown_keys
from hild.crossing.mailboxes import LatestNumbers
from hild.interfaces import FIELDS, ClaimMasks, interface_name

TARGET_FIELDS = ("positions", "velocities", "efforts", "stiffness", "damping")  # the streamed input's keys
REQUIRED = "positions"


class JointImpedanceParams(Params):
    joints: list[str] = Field(min_length=1, description="Joints commanded, in the order of the per-joint values.")
    stiffness: list[float] = dynamic(
        description="N·m/rad per joint: the spring toward the target when a target gives none (and at start)."
    )
    damping: list[float] = dynamic(description="N·m·s/rad per joint: the damping when a target gives none.")
    max_stiffness: list[float] = dynamic(description="N·m/rad per joint: no target or reference sets more.")
    max_damping: list[float] = dynamic(description="N·m·s/rad per joint: no target or reference sets more.")
    stiffness_rate: float = dynamic(
        default=2000.0, gt=0.0, description="N·m/rad per second: how fast the stiffness moves toward a new value."
    )
    damping_rate: float = dynamic(
        default=200.0, gt=0.0, description="N·m·s/rad per second: how fast the damping moves toward a new value."
    )
    command_timeout: float = dynamic(
        default=0.5,
        gt=0.0,
        description="Seconds without a streamed target after which the joints hold compliantly at the last one "
        "(target velocity and feed-forward 0).",
    )
    gravity_compensation: bool = Field(
        default=True, description="The robot model's gravity torque on top of the effort (needs robot.model)."
    )
    pd_on_effort: list[str] = Field(
        default_factory=list,
        description="Joints whose drive does not apply kp/kd (APPLIES_GAINS False, e.g. ODrive): the law runs in "
        "hild at the cycle rate and reaches the drive as effort; only their effort is claimed.",
    )

    @model_validator(mode="after")
    def _consistent(self) -> JointImpedanceParams:
        n = len(self.joints)
        if len(set(self.joints)) != n:
            raise ValueError(f"joints listed twice in {self.joints}")
        for key in ("stiffness", "damping", "max_stiffness", "max_damping"):
            values = getattr(self, key)
            if len(values) != n:
                raise ValueError(f"{key} needs one value per joint ({n}); found {len(values)}")
            if not all(math.isfinite(v) and v >= 0.0 for v in values):
                raise ValueError(f"{key} must be finite and not negative: {values}")
        for key, cap in (("stiffness", "max_stiffness"), ("damping", "max_damping")):
            over = [j for j, v, m in zip(self.joints, getattr(self, key), getattr(self, cap), strict=True) if v > m]
            if over:
                raise ValueError(f"{key} of {over} above {cap}")
        if stray := [j for j in self.pd_on_effort if j not in self.joints]:
            raise ValueError(f"pd_on_effort names joints it does not command: {stray}")
        return self


class JointImpedanceController(Controller):
    Params = JointImpedanceParams
    params: JointImpedanceParams

    def __init__(self, context: ControllerContext, params: JointImpedanceParams) -> None:
        super().__init__(context, params)
        self._index = context.index_of(params.joints)
        n = len(self._index)
        applies = context.applies_gains
        if applies is not None:
            unable = [j for j, i in zip(params.joints, self._index, strict=True) if not applies[i]]
            if missing := [j for j in unable if j not in params.pd_on_effort]:
                raise ValueError(
                    f"the drives of {missing} do not apply kp/kd (APPLIES_GAINS False): list them in pd_on_effort, "
                    "where the law runs in hild on the effort path"
                )
        self._slot: LatestNumbers = context.mailboxes.latest_numbers("target", 5 * n)
        self._chained_flag = context.mailboxes.flag("chained")  # the API half refuses streamed targets while set
        self.references = ServoCommand.zeros(len(context.joints))
        lim = context.limits
        self._lower, self._upper = lim.lower[self._index], lim.upper[self._index]
        self._soft_lower, self._soft_upper = lim.soft_lower[self._index], lim.soft_upper[self._index]
        self._vmax, self._emax = lim.velocity[self._index], lim.effort[self._index]
        self._pd_here = np.array([j in params.pd_on_effort for j in params.joints], dtype=bool)
        self._direct_cols = np.flatnonzero(~self._pd_here)  # the joints whose drive gets the law
        self._effort_cols = np.flatnonzero(self._pd_here)  # the joints that get it as effort
        self._direct = self._index[self._direct_cols]  # ... as robot indices
        self._on_effort = self._index[self._effort_cols]
        self._all_direct = not self._pd_here.any()
        self._direct_buf, self._effort_buf = np.zeros(len(self._direct)), np.zeros(len(self._on_effort))
        # targets, and the gains and set point as they are ramped/slewed toward them
        self.target_position, self.target_velocity, self.target_effort = np.zeros(n), np.zeros(n), np.zeros(n)
        self.target_stiffness, self.target_damping = np.zeros(n), np.zeros(n)
        self.stiffness, self.damping, self.set_point = np.zeros(n), np.zeros(n), np.zeros(n)
        self._defaults(params)
        self._last_rx = -math.inf
        self._streaming = False
        self._chained: ClaimMasks | None = None
        self._claimed = np.zeros((5, n), dtype=bool)  # per FIELDS row: the chained controller writes it
        self._any_claimed = False
        self._written, self._row = np.zeros(n, dtype=bool), np.zeros(n)
        self._q, self._qd, self._scratch, self._effort = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n)

    def _defaults(self, params: JointImpedanceParams) -> None:
        self._default_k, self._default_d = np.array(params.stiffness), np.array(params.damping)
        self._max_k, self._max_d = np.array(params.max_stiffness), np.array(params.max_damping)

    # ---- the contract ---------------------------------------------------------------------------------------------
    @classmethod
    def claims_for(cls, params: Params) -> list[str]:
        assert isinstance(params, JointImpedanceParams)
        return [
            interface_name(j, f) for j in params.joints for f in (("effort",) if j in params.pd_on_effort else FIELDS)
        ]

    @classmethod
    def reference_interfaces_for(cls, params: Params) -> list[str]:
        assert isinstance(params, JointImpedanceParams)
        return [interface_name(j, f) for j in params.joints for f in FIELDS]

    def gravity_joints(self) -> list[str]:
        assert isinstance(self.params, JointImpedanceParams)
        return list(self.params.joints) if self.params.gravity_compensation else []

    def state_interfaces(self) -> list[str]:
        return [interface_name(j, f) for j in self.params.joints for f in ("position", "velocity")]

    def on_params(self, old: Params) -> None:
        """New defaults and maxima: targets above a new maximum come down to it, at the rate limits."""
        assert isinstance(self.params, JointImpedanceParams)
        self._defaults(self.params)
        np.minimum(self.target_stiffness, self._max_k, out=self.target_stiffness)
        np.minimum(self.target_damping, self._max_d, out=self.target_damping)

    # ---- API side -------------------------------------------------------------------------------------------------
    def inputs(self) -> Mapping[str, Callable[[Any], None]]:
        return {"target": self.accept}

    def accept(self, payload: Any) -> None:
        """Validate ``{"positions": [...], "velocities"?, "efforts"?, "stiffness"?, "damping"?}`` (controller joint
        order; absent: 0 for velocities and efforts, the configured stiffness and damping) and hand it over."""
        if not self.active:
            raise ValueError(f"controller {self.name} is not active")
        if self._chained_flag:
            raise ValueError(f"controller {self.name} is chained: its targets come from the controller chained to it")
        if not isinstance(payload, dict) or REQUIRED not in payload:
            raise ValueError('expected an object {"positions": [...], "velocities"?, "efforts"?, "stiffness"?, '
                             '"damping"?}')  # fmt: skip
        unknown, more = unknown_keys(payload, TARGET_FIELDS)
        if unknown:
            raise ValueError(f"unknown keys {unknown}{and_more(more)} (known: {', '.join(TARGET_FIELDS)})")
        assert isinstance(self.params, JointImpedanceParams)
        n = len(self._index)
        record = np.zeros(5 * n)
        record[3 * n : 4 * n] = self.params.stiffness
        record[4 * n :] = self.params.damping
        bounds = {
            "positions": (self._lower, self._upper),
            "velocities": (-self._vmax, self._vmax),
            "efforts": (-self._emax, self._emax),
            "stiffness": (np.zeros(n), np.array(self.params.max_stiffness)),
            "damping": (np.zeros(n), np.array(self.params.max_damping)),
        }
        for k, key in enumerate(TARGET_FIELDS):
            if key in payload:
                record[k * n : (k + 1) * n] = self._values(key, payload[key], *bounds[key])
        self._slot.put(record)

    def _values(self, key: str, values: Any, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        n = len(self._index)
        if not isinstance(values, list) or len(values) != n:
            found = f"{len(values)} values" if isinstance(values, list) else type(values).__name__
            raise ValueError(f"{key}: expected {n} values for {self.params.joints}; found {found}")
        if not all(isinstance(v, int | float) and not isinstance(v, bool) for v in values):
            raise ValueError(f"{key} must be numbers")
        arr = np.array(values, dtype=float)
        if not np.isfinite(arr).all():
            raise ValueError(f"{key} must be finite (no NaN or inf)")
        outside = np.flatnonzero((arr < lo) | (arr > hi))
        if outside.size:
            i = int(outside[0])
            joint = self.params.joints[i]
            raise ValueError(f"{key} {arr[i]:g} for {joint} is outside [{lo[i]:g}, {hi[i]:g}]")
        return arr

    # ---- cycle side -----------------------------------------------------------------------------------------------
    def set_chained(self, claimed: ClaimMasks | None) -> None:
        """Which of its references a chained controller writes; the current targets stay until it writes them."""
        self._chained = claimed
        self._claimed[:] = False
        if claimed is not None:
            for row, name in enumerate(FIELDS):
                getattr(claimed, name).take(self._index, out=self._claimed[row])
        self._any_claimed = bool(self._claimed.any())
        self._chained_flag.set(self._any_claimed)
        self._slot.clear()
        self._streaming = False
        self._last_rx = -math.inf

    def on_activate(self, state: JointState, last_command: ServoCommand) -> None:
        """Bumpless: the target is where the joints are, at rest; the gains ramp from what the drive last had."""
        q = state.position[self._index]
        start = np.where(np.isfinite(q), q, last_command.position[self._index])
        self.target_position[:] = start
        self.set_point[:] = start
        self.target_velocity[:] = 0.0
        self.target_effort[:] = 0.0
        self.target_stiffness[:] = self._default_k
        self.target_damping[:] = self._default_d
        np.clip(last_command.kp[self._index], 0.0, self._max_k, out=self.stiffness)
        np.clip(last_command.kd[self._index], 0.0, self._max_d, out=self.damping)
        self.stiffness[self._pd_here] = np.minimum(self._default_k[self._pd_here], self.stiffness[self._pd_here])
        self._slot.clear()
        self._last_rx = -math.inf
        self._streaming = False

    def update(self, t: float, dt: float, state: JointState, command: ServoCommand) -> None:
        if self._any_claimed:
            self._take_references()
        else:
            self._take_stream(t)
        self._ramp(dt)
        if self._all_direct:  # the usual case: every drive applies the law
            idx = self._index
            command.position[idx] = self.set_point
            command.velocity[idx] = self.target_velocity
            command.effort[idx] = self.target_effort
            command.kp[idx] = self.stiffness
            command.kd[idx] = self.damping
        else:
            self._write_mixed(state, command)
        command.written[self._index] = True

    def _write_mixed(self, state: JointState, command: ServoCommand) -> None:
        cols, buf, direct = self._direct_cols, self._direct_buf, self._direct
        for source, name in (
            (self.set_point, "position"),
            (self.target_velocity, "velocity"),
            (self.target_effort, "effort"),
            (self.stiffness, "kp"),
            (self.damping, "kd"),
        ):
            source.take(cols, out=buf)
            getattr(command, name)[direct] = buf
        self._pd_on_effort(state, command)

    def _take_stream(self, t: float) -> None:
        fresh = self._slot.take()
        if fresh is not None:
            n = len(self._index)
            self.target_position[:] = fresh[:n]
            self.target_velocity[:] = fresh[n : 2 * n]
            self.target_effort[:] = fresh[2 * n : 3 * n]
            self.target_stiffness[:] = fresh[3 * n : 4 * n]
            self.target_damping[:] = fresh[4 * n :]
            self._last_rx = t
            self._streaming = True
        elif self._streaming and t - self._last_rx > self.params.command_timeout:
            self._streaming = False
            self.target_velocity[:] = 0.0
            self.target_effort[:] = 0.0
            self.context.emit_event(
                "warning",
                f"no target for {self.params.command_timeout:g} s: holding compliantly at the last one",
            )

    def _take_references(self) -> None:
        """The chained controller's references of this cycle: claimed fields of the joints it wrote; a field it does
        not claim takes the default; a joint it did not write keeps its last targets."""
        refs, idx, written, row = self.references, self._index, self._written, self._row
        refs.written.take(idx, out=written)
        claimed = self._claimed
        for k, (target, default) in enumerate(
            (
                (self.target_position, None),
                (self.target_velocity, 0.0),
                (self.target_effort, 0.0),
                (self.target_stiffness, self._default_k),
                (self.target_damping, self._default_d),
            )
        ):
            getattr(refs, FIELDS[k]).take(idx, out=row)
            if default is not None:
                np.copyto(target, default, where=written & ~claimed[k])
            np.copyto(target, row, where=written & claimed[k])
        np.clip(self.target_stiffness, 0.0, self._max_k, out=self.target_stiffness)
        np.clip(self.target_damping, 0.0, self._max_d, out=self.target_damping)

    def _ramp(self, dt: float) -> None:
        """Gains toward their targets at the rate limits; the set point toward the target at the velocity limit,
        within the soft limits (a non-finite target from a buggy chained controller is never adopted)."""
        p = self.params
        s = self._scratch
        for value, target, rate in (
            (self.stiffness, self.target_stiffness, p.stiffness_rate),
            (self.damping, self.target_damping, p.damping_rate),
        ):
            np.subtract(target, value, out=s)
            np.clip(s, -rate * dt, rate * dt, out=s)
            np.add(value, s, out=value)
        np.clip(self.stiffness, 0.0, self._max_k, out=self.stiffness)
        np.clip(self.damping, 0.0, self._max_d, out=self.damping)
        np.clip(self.target_position, self._soft_lower, self._soft_upper, out=s)
        np.subtract(s, self.set_point, out=s)
        np.clip(s, -self._vmax * dt, self._vmax * dt, out=s)
        np.add(self.set_point, s, out=self.set_point)

    def _pd_on_effort(self, state: JointState, command: ServoCommand) -> None:
        """The law on the joints whose drive does not apply gains: τ = k·(p − q) + d·(v − q̇) + τ_ff, as effort."""
        q, qd, effort = self._q, self._qd, self._effort
        state.position.take(self._index, out=q)
        state.velocity.take(self._index, out=qd)
        np.subtract(self.set_point, q, out=effort)
        effort *= self.stiffness
        np.subtract(self.target_velocity, qd, out=q)
        q *= self.damping
        effort += q
        effort += self.target_effort
        effort.take(self._effort_cols, out=self._effort_buf)
        command.effort[self._on_effort] = self._effort_buf
