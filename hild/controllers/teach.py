"""teach: hand-guiding. The joints go limp (kp = 0) with light damping, carried by the model's gravity and the
identified friction, so a hand moves the arm and it stays where it is left (docs/controllers.md, "teach").

What stays enforced (docs/safety.md, "Teach mode"): above ``speed_limit`` the damping rises so a thrown arm brakes;
within ``wall_zone`` of a soft position limit a virtual spring pushes back (with the brake's damping); the
supervisor's own limits, faults and e-stop apply as to any controller. Releasing a joint (``teach off``) brakes it to
a stop, within ``release_time``, before it is handed to hold: the supervisor latches the position at the cycle this
controller stops writing the joint, so a joint still moving then would be pulled back by the hold spring.

Friction: the config's ``joints.<j>.friction`` (``hild.dynamics.friction``) is compensated with its offset in full
but only ``friction_compensation`` of its viscous and Coulomb terms, and the Coulomb term through a tanh at least
``stiction_band`` wide. At rest the compensation is the offset alone, so the joint's own stiction holds a released
arm; moving, the hand feels the rest of the friction, never less than none: the joint stays passive even when the
identified friction is somewhat too high.

Each cycle: kp 0, kd the damping (raised by the brake), velocity 0, position the reading, effort friction
compensation plus the wall spring; the supervisor adds gravity on top (``gravity_joints``). Damping goes through the
drive's kd by default (MIT drives, the twin: applied at the drive's rate); ``damping_via: effort`` computes it here
instead, for drives that do not apply hild's gains (ODrive: kd 0 is its torque mode).
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable, Mapping
from typing import Any, Literal

import numpy as np

from hild.arrays import JointState, ServoCommand
from hild.config.params import Field, Params, dynamic, model_validator
from hild.controller import Controller, ControllerContext, and_more, unknown_keys
from hild.crossing.mailboxes import LatestNumbers
from hild.dynamics.friction import FrictionArrays
from hild.interfaces import FIELDS, interface_name

BRAKE_RAMP = 0.25  # of speed_limit: the damping reaches brake damping at (1 + BRAKE_RAMP) x speed_limit
SETTLED_TIME = 0.02  # s a releasing joint must stay below release_speed before it is handed to hold


class TeachParams(Params):
    joints: list[str] = Field(min_length=1, description="Joints in teach mode, in the order of the teach input.")
    damping: dict[str, float] = dynamic(
        default_factory=dict,
        description="N·m·s/rad per joint, overriding damping_scale for that joint: what the hand feels per unit speed.",
    )
    damping_scale: float = dynamic(
        default=0.5,
        ge=0.0,
        le=5.0,
        description="Damping as a fraction of the joint's position kd (position_gains, else hold): a released arm "
        "stops within a few inertia/damping time constants.",
    )
    friction_compensation: float = dynamic(
        default=0.8,
        ge=0.0,
        le=1.0,
        description="Share of the identified viscous and Coulomb friction compensated (the offset: in full). Below "
        "1 the joint stays passive when the identification is a little high.",
    )
    stiction_band: float = dynamic(
        default=0.05,
        gt=0.0,
        le=1.0,
        description="rad/s: the Coulomb compensation rises as tanh(v / band), band at least this wide: near rest "
        "it fades out, so the joint's own stiction holds a released arm.",
    )
    speed_limit: float = dynamic(
        default=0.5,
        gt=0.0,
        le=1.0,
        description="Fraction of each joint's velocity limit above which the damping rises to brake damping.",
    )
    brake_damping_scale: float = dynamic(
        default=1.0,
        gt=0.0,
        le=5.0,
        description="Brake damping as a fraction of the joint's position kd: above the speed limit, in a wall zone, "
        "and while releasing.",
    )
    wall_zone: float = dynamic(
        default=0.1,
        gt=0.0,
        description="rad (m): within this of a soft position limit a virtual spring pushes the joint back.",
    )
    wall_stiffness_scale: float = dynamic(
        default=1.0,
        ge=0.0,
        le=5.0,
        description="The wall spring as a fraction of the joint's position kp (N·m/rad per rad of penetration).",
    )
    release_time: float = dynamic(
        default=0.5,
        gt=0.0,
        le=5.0,
        description="s: at most this long a released joint brakes before it is handed to hold, stopped or not.",
    )
    release_speed: float = dynamic(
        default=0.01, gt=0.0, description="rad/s (m/s): below this a releasing joint counts as stopped."
    )
    damping_via: Literal["drive", "effort"] = Field(
        default="drive",
        description="drive: the damping is the command's kd (the drive applies it); effort: computed here from the "
        "measured speed and sent as effort (drives that ignore kd, e.g. ODrive, at the cycle rate only).",
    )
    start_released: bool = Field(
        default=False, description="Activate with every joint held (released); the teach input turns joints on."
    )

    @model_validator(mode="after")
    def _consistent(self) -> TeachParams:
        if len(set(self.joints)) != len(self.joints):
            raise ValueError(f"joints listed twice in {self.joints}")
        stray = [j for j in self.damping if j not in self.joints]
        if stray:
            raise ValueError(f"damping names joints not in joints: {stray}")
        bad = [j for j, d in self.damping.items() if not (math.isfinite(d) and d >= 0.0)]
        if bad:
            raise ValueError(f"damping must be finite and ≥ 0 (N·m·s/rad): {bad}")
        return self


class Phase(enum.IntEnum):
    TEACH = 0
    RELEASING = 1  # braking to a stop before it is handed to hold
    RELEASED = 2  # not written: the supervisor holds it where it stopped


_TEACH, _RELEASING, _RELEASED = int(Phase.TEACH), int(Phase.RELEASING), int(Phase.RELEASED)


class TeachController(Controller):
    Params = TeachParams

    def __init__(self, context: ControllerContext, params: TeachParams) -> None:
        super().__init__(context, params)
        self._index = context.index_of(params.joints)
        n = len(params.joints)
        self._slot: LatestNumbers = context.mailboxes.latest_numbers("teach", n)
        whole = context.friction or FrictionArrays.zeros(len(context.joints))
        self._identified = FrictionArrays(
            whole.viscous[self._index], whole.coulomb[self._index], whole.offset[self._index], whole.band[self._index]
        )
        # Per joint, plain lists: the cycle's loop reads and writes them without numpy scalars.
        self._phase = [int(Phase.TEACH)] * n
        self._released_at = [0.0] * n  # cycle time a release began
        self._settled = [0.0] * n  # s below release_speed while releasing
        self._rows: list[tuple[int, float, float, float, float, float, float]] = []  # _derive
        self._friction_torque = np.zeros(n)
        self._q = np.zeros(n)
        self._v = np.zeros(n)
        self._derive()

    @classmethod
    def claims_for(cls, params: Params) -> list[str]:
        assert isinstance(params, TeachParams)
        return [interface_name(j, f) for j in params.joints for f in FIELDS]

    def gravity_joints(self) -> list[str]:
        return list(self.params.joints)  # type: ignore[attr-defined]

    def state_interfaces(self) -> list[str]:
        return [interface_name(j, f) for j in self.params.joints for f in ("position", "velocity")]  # type: ignore[attr-defined]

    # ---- derived per-joint constants -----------------------------------------------------------------------------
    def on_params(self, old: Params) -> None:
        self._derive()

    def _derive(self) -> None:
        """Per-joint arrays from the params and the robot (between cycles: at construction and on new params)."""
        p: TeachParams = self.params  # type: ignore[assignment]
        idx, lim = self._index, self.context.limits
        gains = self.context.gains
        kp = gains.position_kp[idx] if gains is not None else np.zeros(len(idx))
        kd = gains.position_kd[idx] if gains is not None else np.zeros(len(idx))
        self.damping = np.array([p.damping.get(j, p.damping_scale * kd[k]) for k, j in enumerate(p.joints)])
        self.brake = np.maximum(p.brake_damping_scale * kd, self.damping)
        self.speed_limit = p.speed_limit * lim.velocity[idx]
        self.wall_stiffness = p.wall_stiffness_scale * kp
        span = lim.soft_upper[idx] - lim.soft_lower[idx]
        zone = np.minimum(p.wall_zone, 0.5 * span)
        self.wall_lower = lim.soft_lower[idx] + zone
        self.wall_upper = lim.soft_upper[idx] - zone
        share = p.friction_compensation
        ident = self._identified
        self.friction = FrictionArrays(
            ident.viscous * share, ident.coulomb * share, ident.offset.copy(), np.maximum(ident.band, p.stiction_band)
        )
        self._via_effort = p.damping_via == "effort"
        self._rows = list(  # one swap between cycles: update reads either the old rows or the new
            zip(
                self._index.tolist(),
                self.damping.tolist(),
                self.brake.tolist(),
                self.speed_limit.tolist(),
                self.wall_lower.tolist(),
                self.wall_upper.tolist(),
                self.wall_stiffness.tolist(),
                strict=True,
            )
        )

    # ---- API side -------------------------------------------------------------------------------------------------
    def inputs(self) -> Mapping[str, Callable[[Any], None]]:
        return {"teach": self.accept}

    def accept(self, payload: Any) -> None:
        """``{"teach": [true | false | null, ...]}`` in the controller's joint order: put the joint in teach (true),
        release it to hold (false: it brakes to a stop first) or leave it as it is (null)."""
        if not self.active:
            raise ValueError(f"controller {self.name} is not active")
        if not isinstance(payload, dict) or "teach" not in payload:
            raise ValueError('expected an object {"teach": [true | false | null per joint]}')
        unknown, more = unknown_keys(payload, ("teach",))
        if unknown:
            raise ValueError(f"unknown field(s) {unknown}{and_more(more)} (allowed: teach)")
        flags = payload["teach"]
        n = len(self._index)
        if not isinstance(flags, list) or len(flags) != n or not all(f is None or isinstance(f, bool) for f in flags):
            joints = self.params.joints  # type: ignore[attr-defined]
            raise ValueError(f"teach must be a list of {n} values true, false or null for {joints}")
        self._slot.put([math.nan if f is None else 1.0 if f else 0.0 for f in flags])

    def set_teach(self, joints: Mapping[str, bool]) -> None:
        """Turn the named joints of this controller on (teach) or off (released to hold); the others stay as they
        are. API side: raises ValueError for a joint it does not teach or when it is not active."""
        names: list[str] = self.params.joints  # type: ignore[attr-defined]
        missing = [j for j in joints if j not in names]
        if missing:
            raise ValueError(f"{self.name} does not teach {missing} (its joints: {names})")
        self.accept({"teach": [joints.get(j) for j in names]})

    # ---- cycle side -----------------------------------------------------------------------------------------------
    def on_activate(self, state: JointState, last_command: ServoCommand) -> None:
        self._slot.clear()
        start = Phase.RELEASED if self.params.start_released else Phase.TEACH  # type: ignore[attr-defined]
        self._phase[:] = [int(start)] * len(self._phase)
        self._settled[:] = [0.0] * len(self._settled)

    def update(self, t: float, dt: float, state: JointState, command: ServoCommand) -> None:
        phase, settled = self._phase, self._settled
        asked = self._slot.take()
        if asked is not None:
            for k, on in enumerate(asked.tolist()):
                if on != on:  # NaN: as it is
                    continue
                if on and phase[k] != _TEACH:
                    phase[k] = _TEACH
                elif not on and phase[k] == _TEACH:
                    phase[k] = _RELEASING
                    self._released_at[k] = t
                    settled[k] = 0.0
        np.take(state.position, self._index, out=self._q)
        np.take(state.velocity, self._index, out=self._v)
        tau_all = self.friction.torque(self._v, self._friction_torque).tolist()
        q_all, v_all = self._q.tolist(), self._v.tolist()
        p: TeachParams = self.params  # type: ignore[assignment]
        release_speed, release_time, via_effort = p.release_speed, p.release_time, self._via_effort
        o_pos, o_vel, o_eff, o_kp, o_kd, written = (
            command.position,
            command.velocity,
            command.effort,
            command.kp,
            command.kd,
            command.written,
        )
        for k, (i, damping, brake, speed_limit, wall_lower, wall_upper, wall_k) in enumerate(self._rows):
            ph = phase[k]
            if ph == _RELEASED:
                continue
            q, v = q_all[k], v_all[k]
            kd = damping
            speed = v if v >= 0.0 else -v
            if speed > speed_limit:  # a thrown arm: the damping rises to the brake's
                rise = min(1.0, (speed / speed_limit - 1.0) / BRAKE_RAMP)
                kd += (brake - kd) * rise
            effort = tau_all[k]
            if q < wall_lower:
                effort += wall_k * (wall_lower - q)
                kd = brake
            elif q > wall_upper:
                effort -= wall_k * (q - wall_upper)
                kd = brake
            if ph == _RELEASING:
                kd = brake
                settled[k] = settled[k] + dt if speed < release_speed else 0.0
                if settled[k] >= SETTLED_TIME or t - self._released_at[k] >= release_time:
                    phase[k] = _RELEASED  # from this cycle on the supervisor holds it where it is
                    continue
            if via_effort:
                effort -= kd * v
                kd = 0.0
            o_pos[i] = q
            o_vel[i] = 0.0
            o_eff[i] = effort
            o_kp[i] = 0.0
            o_kd[i] = kd
            written[i] = True

    def phases(self) -> list[str]:
        """Each joint's phase on the cycle half: ``teach``, ``releasing`` or ``released`` (tests, the bench)."""
        return [Phase(ph).name.lower() for ph in self._phase]
