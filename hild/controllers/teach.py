"""teach: hand-guiding. The joints go limp (kp = 0) with light damping, carried by the model's gravity and the
identified friction, so a hand moves the arm and it stays where it is left (docs/controllers.md, "teach").

Holding where left, although the model is never exact (docs/safety.md, "Teach mode"): a **virtual stiction** and a
**gravity-error adaptation**. A joint still (below ``anchor_speed``) for ``anchor_time`` is anchored: a spring
(``anchor_stiffness_scale`` × its position kp) toward the anchor, its torque capped at the breakaway torque τ_s =
``breakaway_force`` × the tool's lever about the joint at this pose (the norm of its column of the tool Jacobian;
never below ``breakaway_floor`` × its effort limit), less the joint's identified Coulomb friction (its own stiction,
which teach leaves in place at rest, is part of the breakaway). A hand pushing harder drags the anchor along (it
follows so |spring| ≤ τ_s), and once the joint moves faster than ``anchor_speed`` the grip fades out over
``ANCHOR_RAMP``: above breakaway the arm moves, below it the arm stays. While anchored, the torque the spring holds
is moved, at the rate 1/``gravity_adaptation_time``, into a per-joint scale of the model's gravity torque (bounded
by ``gravity_adaptation_limit``), the anchor shifting with it so the command does not change: the spring is free
again for the hand, and the learned scale follows the pose as the arm is guided. For ``LEARN_SPAN`` learning times
after a joint enters teach, it is held (anchored whatever its speed), the rate is 1/``gravity_learning_time`` and
the grip exceeds τ_s by the error not yet learned (``gravity_adaptation_limit`` × |gravity|, fading at that rate):
the arm neither sags nor slips while the model's error is learned — and a hand on the arm then is learned too.
Entering teach, the spring starts with the torque the previous command held beyond teach's own feed-forward, and it
grows, fades and is dragged continuously: no step in the command when anchoring or breaking away.

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
from hild.modes import Source

BRAKE_RAMP = 0.25  # of speed_limit: the damping reaches brake damping at (1 + BRAKE_RAMP) x speed_limit
SETTLED_TIME = 0.02  # s a releasing joint must stay below release_speed before it is handed to hold
ANCHOR_RAMP = 0.1  # s for the anchor's grip to grow from none to full (still) or fade back (moving): no step
LEARN_SPAN = 5.0  # gravity_learning_time's: how long after entering teach the fast learning and extra grip last
GRAVITY_FLOOR = 0.01  # of the effort limit: below this gravity torque the scale is learned more slowly


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
    breakaway_force: float = dynamic(
        default=1.0,
        ge=0.0,
        le=50.0,
        description="N at the tool: a still joint is held up to this force's torque about it at the pose (the tool's "
        "lever, from the model's Jacobian); a harder push breaks it away. 0: no anchor (limp, as without stiction).",
    )
    breakaway_floor: float = dynamic(
        default=0.002,
        ge=0.0,
        le=0.1,
        description="The breakaway torque's floor as a fraction of the joint's effort limit: what holds a joint the "
        "tool has no lever about (and every joint when the robot has no model).",
    )
    anchor_speed: float = dynamic(
        default=0.1,
        gt=0.0,
        le=1.0,
        description="rad/s (m/s): below this a joint counts as still and is anchored after anchor_time; above it the "
        "anchor fades. Well above the drives' velocity resolution (a DM8009 through 2:1: ~0.01 rad/s) and above the "
        "speed a residual error of τ_s slides a joint at (τ_s / damping), so such a slide is caught and learned.",
    )
    anchor_time: float = dynamic(
        default=0.05, gt=0.0, le=2.0, description="s a joint must stay still before it is anchored."
    )
    anchor_stiffness_scale: float = dynamic(
        default=1.0,
        gt=0.0,
        le=5.0,
        description="The anchor spring as a fraction of the joint's position kp: how little the arm gives before it "
        "breaks away (breakaway torque / stiffness).",
    )
    gravity_adaptation_time: float = dynamic(
        default=2.0,
        ge=0.0,
        le=60.0,
        description="s: the time constant at which the torque an anchored joint holds becomes a learned scale of "
        "the model's gravity (slow, so a hand's push is not learned away); 0: no adaptation.",
    )
    gravity_learning_time: float = dynamic(
        default=0.1,
        gt=0.0,
        le=5.0,
        description="s: the same, right after a joint enters teach (for LEARN_SPAN of these while anchored), with "
        "the grip raised by the error not yet learned: the model's error is learned before the arm is let go.",
    )
    gravity_adaptation_limit: float = dynamic(
        default=0.2,
        ge=0.0,
        le=1.0,
        description="The learned gravity scale's bound (0.2: the model's gravity torque may be 20 % off either way).",
    )
    tool_site: str | None = Field(
        default=None,
        description="The model's site the breakaway force is applied at; default: a site named tool, flange, tool0 "
        "or tcp, else the last joint's body.",
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
    SOURCE = Source.HAND
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
        self._anchor = [0.0] * n  # where the virtual stiction holds the joint
        self._grip = [0.0] * n  # 0–1: how much of the breakaway torque the anchor holds (ramps, never steps)
        self._still = [0.0] * n  # s below anchor_speed
        self._learning = [0.0] * n  # s anchored since entering teach (fast learning while < LEARN_SPAN × its time)
        self.gravity_scale = [0.0] * n  # learned: the model's gravity torque is off by this share (kept across uses)
        self._rows: list[tuple[int, float, float, float, float, float, float, float, float, float]] = []  # _derive
        self._friction_torque = np.zeros(n)
        self._q = np.zeros(n)
        self._v = np.zeros(n)
        self._g = np.zeros(n)
        self._tool = self._tool_point(context, params)
        self._jacobian = np.zeros((3, len(context.joints)))
        self._squares = np.zeros((3, len(context.joints)))
        self._lever_all = np.zeros(len(context.joints))
        self.lever = np.zeros(n)  # m: the tool's lever about each joint at the last pose (0 without a model)
        self.breakaway = np.zeros(n)  # N·m: τ_s at the last pose
        self._derive()

    @staticmethod
    def _tool_point(context: ControllerContext, params: TeachParams) -> Any:
        """The tool point's Jacobian on the cycle (hild.dynamics.tool), when the robot has a model: None in the
        client domain, where no model path is given and only the API half runs."""
        if context.model_path is None:
            return None
        from hild.dynamics.tool import ToolPoint  # mujoco stays behind this seam

        return ToolPoint(context.model_path, context.joints, site=params.tool_site)

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
        effort = lim.effort[idx]
        self.anchor_stiffness = p.anchor_stiffness_scale * kp
        self.breakaway_floor = p.breakaway_floor * effort
        self._gravity_floor_sq = (GRAVITY_FLOOR * effort) ** 2
        self._rows = list(  # one swap between cycles: update reads either the old rows or the new
            zip(
                self._index.tolist(),
                self.damping.tolist(),
                self.brake.tolist(),
                self.speed_limit.tolist(),
                self.wall_lower.tolist(),
                self.wall_upper.tolist(),
                self.wall_stiffness.tolist(),
                self.anchor_stiffness.tolist(),
                self.breakaway_floor.tolist(),
                self._gravity_floor_sq.tolist(),
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
        self._grip[:] = [0.0] * len(self._grip)
        if start != Phase.TEACH:
            return
        self._measure(state)
        applies = self.context.applies_gains
        offset = self.friction.offset
        for k, i in enumerate(self._index.tolist()):
            # What the previous command held beyond teach's own feed-forward (gravity, the friction offset, the
            # learned scale): the anchor spring starts with it, so activating steps nothing and the arm neither sags
            # nor jumps while the rest of the model's error is learned.
            held = float(last_command.effort[i])
            if applies is None or applies[i]:
                held += float(last_command.kp[i]) * (float(last_command.position[i]) - float(self._q[k]))
            g = float(self._g[k])
            self._enter(k, held - g * (1.0 + self.gravity_scale[k]) - float(offset[k]))

    def _measure(self, state: JointState) -> None:
        """Positions, speeds, the model's gravity and the breakaway torques at this pose (into the arrays)."""
        np.take(state.position, self._index, out=self._q)
        np.take(state.velocity, self._index, out=self._v)
        gravity = self.context.gravity_torque
        if gravity is not None:
            np.take(gravity, self._index, out=self._g)
        tool, pos = self._tool, state.position
        if tool is not None and math.isfinite(float(np.add.reduce(pos))):  # a joint never read: keep the last levers
            tool.position(pos)
            tool.jacobian(self._jacobian)
            np.multiply(self._jacobian, self._jacobian, out=self._squares)
            np.add.reduce(self._squares, axis=0, out=self._lever_all)
            np.sqrt(self._lever_all, out=self._lever_all)
            np.take(self._lever_all, self._index, out=self.lever)
        np.multiply(self.lever, self.params.breakaway_force, out=self.breakaway)  # type: ignore[attr-defined]
        np.maximum(self.breakaway, self.breakaway_floor, out=self.breakaway)
        np.subtract(self.breakaway, self._identified.coulomb, out=self.breakaway)  # the joint's own stiction counts
        np.maximum(self.breakaway, 0.0, out=self.breakaway)

    def _enter(self, k: int, held: float = 0.0) -> None:
        """Joint ``k`` enters teach: anchored at once (held while it learns), its spring preloaded with ``held``
        (N·m, within the grip); the anchor is dragged along continuously should the joint be moving."""
        p: TeachParams = self.params  # type: ignore[assignment]
        q = float(self._q[k])
        self._grip[k] = 1.0 if p.breakaway_force > 0.0 else 0.0
        self._still[k] = p.anchor_time
        self._learning[k] = 0.0
        stiffness = float(self.anchor_stiffness[k])
        bound = self._grip[k] * (float(self.breakaway[k]) + p.gravity_adaptation_limit * abs(float(self._g[k])))
        spring = min(max(held, -bound), bound) if math.isfinite(held) else 0.0
        self._anchor[k] = q + spring / stiffness if stiffness > 0.0 else q

    def update(self, t: float, dt: float, state: JointState, command: ServoCommand) -> None:
        phase, settled = self._phase, self._settled
        self._measure(state)
        asked = self._slot.take()
        if asked is not None:
            for k, on in enumerate(asked.tolist()):
                if on != on:  # NaN: as it is
                    continue
                if on and phase[k] != _TEACH:
                    if phase[k] == _RELEASED:
                        self._enter(k)
                    phase[k] = _TEACH
                elif not on and phase[k] == _TEACH:
                    phase[k] = _RELEASING
                    self._released_at[k] = t
                    settled[k] = 0.0
        tau_all = self.friction.torque(self._v, self._friction_torque).tolist()
        q_all, v_all, g_all, hold_all = self._q.tolist(), self._v.tolist(), self._g.tolist(), self.breakaway.tolist()
        anchor, grip, still, learning, scale = self._anchor, self._grip, self._still, self._learning, self.gravity_scale
        p: TeachParams = self.params  # type: ignore[assignment]
        release_speed, release_time, via_effort = p.release_speed, p.release_time, self._via_effort
        anchoring, anchor_speed, anchor_time = p.breakaway_force > 0.0, p.anchor_speed, p.anchor_time
        adapt_time, learn_time, limit = p.gravity_adaptation_time, p.gravity_learning_time, p.gravity_adaptation_limit
        learn_span, ramp = LEARN_SPAN * learn_time, dt / ANCHOR_RAMP
        o_pos, o_vel, o_eff, o_kp, o_kd, written = (
            command.position,
            command.velocity,
            command.effort,
            command.kp,
            command.kd,
            command.written,
        )
        for k, row in enumerate(self._rows):
            i, damping, brake, speed_limit, wall_lower, wall_upper, wall_k, stiffness, _, g_floor_sq = row
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
            walled = False
            if q < wall_lower:
                effort += wall_k * (wall_lower - q)
                kd, walled = brake, True
            elif q > wall_upper:
                effort -= wall_k * (q - wall_upper)
                kd, walled = brake, True
            if anchoring:  # the virtual stiction and the gravity-error adaptation (module docstring)
                g, hold, rate = g_all[k], hold_all[k], dt / adapt_time if adapt_time > 0.0 else 0.0
                learn = learning[k] < learn_span
                if learn:  # just entered: held while it learns fast, beyond τ_s by what is not learned yet
                    learning[k] += dt
                    hold += limit * (g if g >= 0.0 else -g) * math.exp(-learning[k] / learn_time)
                    rate = dt / learn_time if adapt_time > 0.0 else 0.0
                if walled:  # in a wall zone the wall, not the anchor, decides
                    still[k] = 0.0
                    grip[k] = max(0.0, grip[k] - ramp)
                elif learn:
                    still[k] = anchor_time
                    grip[k] = min(1.0, grip[k] + ramp)
                elif speed <= anchor_speed:
                    still[k] += dt
                    if still[k] >= anchor_time:
                        grip[k] = min(1.0, grip[k] + ramp)
                else:
                    still[k] = 0.0
                    grip[k] = max(0.0, grip[k] - ramp)
                w = grip[k]
                a = anchor[k]
                reach = w * hold / stiffness if stiffness > 0.0 else 0.0
                if a - q > reach:  # pushed past breakaway: the anchor is dragged along
                    a = q + reach
                elif q - a > reach:
                    a = q - reach
                spring = stiffness * (a - q)
                if rate > 0.0 and w > 0.0 and stiffness > 0.0:  # the held torque moves into the gravity scale
                    old = scale[k]
                    new = old + rate * w * spring * g / (g * g + g_floor_sq)
                    new = limit if new > limit else -limit if new < -limit else new
                    scale[k] = new
                    moved = (new - old) * g
                    a -= moved / stiffness  # the spring lets go of what the scale now carries: the sum is unchanged
                    spring -= moved
                anchor[k] = a
                effort += scale[k] * g + spring
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
