"""The controller contract.

A controller is found by type name in the ``hild.controllers`` entry-point group, built from its validated
``Params``, and driven by the controller manager through ``configure → activate → update* → deactivate →
cleanup``. It only ever sees joint space and the cycle clock ``(t, dt)``; it writes the servo-command fields it
claimed and marks the joints it commanded in ``command.written``. A joint it leaves unwritten is held by the
supervisor, so a controller that has nothing to say simply says nothing.

Inputs (commands from Zenoh) arrive on the API side through ``inputs()``: each callable validates a decoded
JSON payload, raises ``ValueError`` with a reason on bad input, and hands the result to the cycle through a
latest-value mailbox from ``context.mailboxes`` (``latest_numbers``: a fixed-size record of float64s, which the
cycle takes with a copy into an array it owns, without allocating or unpickling). It runs in the client domain:
on the Zenoh thread a sample arrives on when the cycle has a process of its own; in one process, on the cycle
thread at the start of a cycle (the asyncio loop for payloads over 4 KiB). So it must be quick, thread-safe and
never wait on anything.
Outputs (e.g. joint states) leave through :class:`~hild.crossing.ring.SampleRing`\\ s.
"""

from __future__ import annotations

import enum
import itertools
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from hild.action import ActionServer
from hild.arrays import JointState, MimicJoints, SensorView, ServoCommand
from hild.config.model import JointLimits
from hild.config.params import Params
from hild.crossing.mailboxes import InProcess, Mailboxes
from hild.crossing.ring import SampleRing
from hild.dynamics.friction import FrictionArrays
from hild.interfaces import ClaimMasks, SensorLayout
from hild.modes import Source

__all__ = [
    "Controller",
    "ControllerContext",
    "ControllerState",
    "JointGainArrays",
    "JointLimitArrays",
    "ShapedOutput",
    "and_more",
    "unknown_keys",
]

SHOWN_KEYS = 3  # unknown keys a refusal names; the rest are counted


class ControllerState(enum.StrEnum):
    UNCONFIGURED = "unconfigured"
    INACTIVE = "inactive"
    ACTIVE = "active"
    FAILED = "failed"  # raised in update(); inactive until switched on again


@dataclass(frozen=True, slots=True)
class JointLimitArrays:
    lower: np.ndarray
    upper: np.ndarray
    soft_lower: np.ndarray
    soft_upper: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray
    acceleration: np.ndarray  # NaN where the config gives none
    jerk: np.ndarray  # NaN where the config gives none

    @classmethod
    def of(cls, cfg: Any) -> JointLimitArrays:
        """The robot's joint limits from a validated config, in the robot's joint order."""
        js = list(cfg.joints.values())
        lower = np.array([j.limits.position.lower for j in js])
        upper = np.array([j.limits.position.upper for j in js])
        margin = np.array([j.limits.soft_margin for j in js])
        return cls(
            lower=lower,
            upper=upper,
            soft_lower=lower + margin,
            soft_upper=upper - margin,
            velocity=np.array([j.limits.velocity for j in js]),
            effort=np.array([j.limits.effort for j in js]),
            acceleration=np.array([j.limits.acceleration or np.nan for j in js]),
            jerk=np.array([j.limits.jerk or np.nan for j in js]),
        )


@dataclass(frozen=True, slots=True)
class JointGainArrays:
    """The gains a position claim gets per joint unless its controller claims kp and kd (``position_gains``, else
    ``hold``): a controller that shapes a torque through the drive's spring (a gripper bounding its force) needs
    them."""

    position_kp: np.ndarray
    position_kd: np.ndarray

    @classmethod
    def of(cls, cfg: Any) -> JointGainArrays:
        gains = [j.position_gains or j.hold for j in cfg.joints.values()]
        return cls(position_kp=np.array([g.kp for g in gains]), position_kd=np.array([g.kd for g in gains]))


@dataclass(frozen=True)
class ControllerContext:
    robot: str
    name: str
    joints: tuple[str, ...]  # every joint of the robot, in the robot's order
    limits: JointLimitArrays
    update_rate: float
    emit_event: Callable[[str, str], None]  # (level, message); events only, never per cycle
    notify: Callable[[], None]  # wakes the client domain after writing an output
    joint_modes: np.ndarray | None = None  # the supervisor's live JointMode per robot joint (read-only)
    gains: JointGainArrays | None = None  # the robot's position gains per joint, in the robot's order
    # The robot's sensors: their accepted values and fresh flags, read-only and live on the cycle (zeros in the
    # client domain, where only the API half runs) — hild.arrays.SensorView.
    sensors: SensorView = field(default_factory=lambda: SensorView(SensorLayout()))
    # The doors between the controller's API half and its cycle half: plain objects in one process, cells of the
    # shared region when the cycle runs in a process of its own (hild.crossing.mailboxes).
    mailboxes: Mailboxes = field(default_factory=InProcess)
    # Joints nothing commands that follow a robot joint (the config's mimic_joints): reported, never commanded.
    mimic_joints: MimicJoints = field(default_factory=lambda: MimicJoints((), ()))
    # Per robot joint: does its drive apply the command's kp and kd (``HardwareComponent.APPLIES_GAINS``)? False for
    # an ODrive, which runs its own gains: a controller that wants a spring there computes it itself on the effort
    # path. None where nothing filled it (the client domain's API half): take every drive as applying them.
    applies_gains: np.ndarray | None = None
    # The contact observer's external torque estimate per robot joint (safety.contact), live on the cycle: NaN
    # while it cannot run; None when it is off, and in the client domain.
    external_torque: np.ndarray | None = None
    # The robot's identified joint friction (joints.<j>.friction), in the robot's order: what teach mode compensates.
    friction: FrictionArrays | None = None
    # The supervisor's gravity feed-forward per robot joint (robot.model), live on the cycle: the torque it computed
    # in the last cycle at the accepted pose. None without a gravity model, and in the client domain.
    gravity_torque: np.ndarray | None = None
    # The robot's model file (robot.model, resolved), for a controller that needs the arm's kinematics on the cycle
    # (teach: the tool's lever about each joint). None without one, and in the client domain.
    model_path: Path | None = None

    def index_of(self, names: Sequence[str]) -> np.ndarray:
        lookup = {j: i for i, j in enumerate(self.joints)}
        missing = [n for n in names if n not in lookup]
        if missing:
            raise ValueError(f"unknown joints {missing} (robot joints: {list(self.joints)})")
        return np.array([lookup[n] for n in names], dtype=np.intp)


@dataclass(frozen=True)
class ShapedOutput:
    """An output published on a key of its controller's own, ``hild/<robot>/<controller>/<name>`` (two controllers
    of one type never collide), as messages of its own shape: ``message(seq, stamp, fields)`` turns a ring sample
    (``fields``: each field's values) into the JSON object sent."""

    ring: SampleRing
    message: Callable[[int, float, dict[str, list[float]]], dict[str, Any]]


class Controller:
    """Base class; override what you need. ``claims`` must not change while the controller is loaded."""

    Params: ClassVar[type[Params]] = Params
    # Who moves the joints this controller commands (hild.modes.Source): recorded per joint every cycle. A controller
    # with more than one kind of input sets ``self.source`` on the cycle side when the kind changes.
    SOURCE: ClassVar[Source] = Source.STREAM

    def __init__(self, context: ControllerContext, params: Params) -> None:
        self.context = context
        self.params = params
        self.source: Source = self.SOURCE
        self._active = context.mailboxes.flag("active")
        # A chainable controller's references (see reference_interfaces_for): allocated at construction over the
        # robot's joints, written by the controllers chained to it each cycle before its own update.
        self.references: ServoCommand | None = None

    @property
    def name(self) -> str:
        return self.context.name

    @property
    def active(self) -> bool:
        """Whether the controller manager has it active: readable by the API half in either domain, so inputs
        and goals for an inactive controller are refused before anything crosses."""
        return bool(self._active)

    def set_active(self, active: bool) -> None:
        """The controller manager's: set after ``on_activate`` succeeds, cleared before ``on_deactivate``."""
        self._active.set(active)

    @classmethod
    def claims_for(cls, params: Params) -> list[str]:
        """Command interfaces this controller claims with these params (checked when the config loads)."""
        return []

    @classmethod
    def joints_for(cls, params: Params) -> list[str]:
        """Joints this controller refers to (checked against the robot when the config loads)."""
        return list(getattr(params, "joints", []) or [])

    @classmethod
    def robot_problems(cls, params: Params, limits: Mapping[str, JointLimits]) -> list[str]:
        """What this controller needs from the robot's joint limits and does not find (checked at load)."""
        return []

    @classmethod
    def sensor_interfaces_for(cls, params: Params) -> list[str]:
        """Sensor state interfaces (``<sensor>/force.x``, …) this controller reads with these params: the config is
        refused when no sensor provides one (checked when it loads, like ``claims_for``)."""
        return []

    def claims(self) -> list[str]:
        return self.claims_for(self.params)

    # ---- chaining (ros2_control's chainable controllers; docs/controllers.md, "Chained controllers") ----------
    @classmethod
    def reference_interfaces_for(cls, params: Params) -> list[str]:
        """The reference interfaces this controller exports with these params, as ``<joint>/<field>`` (the manager
        names them ``<controller>/<joint>/<field>``): another controller configured with ``chain_to: <this one>``
        claims them instead of the hardware's, and what it writes lands in ``self.references``, which this one reads
        in its own update of the same cycle. None by default: a controller that exports some is *chainable* and
        allocates ``self.references`` (a :class:`ServoCommand` over the robot's joints) in its constructor."""
        return []

    def reference_interfaces(self) -> list[str]:
        return self.reference_interfaces_for(self.params)

    def set_chained(self, claimed: ClaimMasks | None) -> None:
        """The manager's, between two cycles, whenever the active controllers chained to this one change: which of
        its references they write, per joint and field (``claimed.position[i]``, …), or None when none is chained
        to it any more. A joint whose reference is claimed takes its targets from ``self.references`` (those with
        ``references.written`` set this cycle); the others keep what the controller does unchained. Must not step
        the command: a reference nobody wrote yet is the controller's current target."""

    def gravity_joints(self) -> list[str]:
        """Joints on which the supervisor adds the robot model's gravity torque (``robot.model``) to this controller's
        effort command, as a real arm's own driver does under an effort-interface controller; each must be one whose
        effort it claims. None by default: a claimed effort is the controller's alone. Must not change while the
        controller is loaded. Limits apply to the sum (docs/safety.md, "Gravity on top of an effort command")."""
        return []

    def state_interfaces(self) -> list[str]:
        """The measured values this controller reads, as ``<joint>/<position|velocity|effort>`` or a sensor's
        ``<sensor>/<value>``: what ros2_control lists as a controller's required state interfaces
        (``list_controllers`` reports them). None by default: a controller that reads the state says so. Must not
        change while the controller is loaded."""
        return []

    def on_configure(self) -> None:
        """Allocate what update() needs."""

    def on_activate(self, state: JointState, last_command: ServoCommand) -> None:
        """Start from the measured state (or ``last_command``, by option): a switch never steps the command."""

    def on_deactivate(self) -> None:
        """Stop; the supervisor already holds the joints this controller leaves."""

    def on_cleanup(self) -> None:
        """Release what on_configure took."""

    def set_params(self, params: Params) -> None:
        """New values of this controller's dynamic parameters (``hild.config.params.dynamic``), already validated:
        set by the controller manager between two cycles in the cycle half, and in the API half once the cycle has
        taken them. Both halves then run :meth:`on_params`."""
        old, self.params = self.params, params
        self.on_params(old)

    def on_params(self, old: Params) -> None:
        """Derive what depends on ``self.params`` again, without a step in the command (a gain is ramped, a new
        tolerance applies to what comes next). Quick and without I/O: it runs between two cycles."""

    def on_client_domain_lost(self, t: float, reason: str) -> None:
        """The client domain ended while the cycle ran (cycle thread, before the next ``update``): nobody can
        follow, cancel or receive the results of what this controller runs for clients. End it with ``reason``
        (goals aborted, queued goals never started); streamed inputs time out by themselves."""

    def update(self, t: float, dt: float, state: JointState, command: ServoCommand) -> None:
        """Write claimed fields for the joints commanded now and set ``command.written`` for them."""

    def inputs(self) -> Mapping[str, Callable[[Any], None]]:
        """Named command inputs (API side, see above). Each raises ValueError with a reason on bad input."""
        return {}

    def subscriptions(self) -> Mapping[str, Callable[[Any], None]]:
        """Other robots' outputs this controller reads (API side, like ``inputs``): absolute Zenoh keys (e.g.
        ``hild/<leader>/joint_states``) → a callable given each decoded message. Handed over like an input, but
        samples arriving while the controller is inactive are dropped silently (a publisher streams whether or not
        anyone follows), and the callable is expected to judge the content itself: it is not a client to refuse."""
        return {}

    def action_server(self) -> ActionServer[Any] | None:
        """The cycle half of the goals of a controller that runs goals; the API builds their client half
        (:class:`hild.api.goals.GoalEndpoint`) and its ``goal``/``cancel``/``result``/``feedback`` keys from it."""
        return None

    def outputs(self) -> Mapping[str, SampleRing | ShapedOutput]:
        """Named outputs the API publishes: a ring's key is ``hild/<robot>/<name>``, a :class:`ShapedOutput`'s
        ``hild/<robot>/<controller>/<name>``."""
        return {}


# ---- validating a decoded message (an input, a goal): controllers and the API refuse unknown keys alike ------
def unknown_keys(obj: Mapping[str, Any], allowed: Collection[str]) -> tuple[list[str], int]:
    """Up to ``SHOWN_KEYS`` keys of ``obj`` that ``allowed`` lacks, and how many more there are.

    Work in ``len(allowed) + SHOWN_KEYS``, whatever the size of ``obj``: a refusal that sorted and joined all the
    keys of a 90 000-key object held the GIL for 45 ms to build an 889 000-character error. When every unknown key
    is shown they are sorted (the error reads as it always did); otherwise the first ones, in the sender's order.
    """
    count = len(obj) - sum(1 for key in allowed if key in obj)
    if count <= 0:
        return [], 0
    shown = list(itertools.islice((key for key in obj if key not in allowed), SHOWN_KEYS))
    if len(shown) == count:
        shown.sort()
    return shown, count - len(shown)


def and_more(more: int) -> str:
    """`` and N more`` after a list that ``unknown_keys`` cut short, else nothing."""
    return f" and {more} more" if more else ""
