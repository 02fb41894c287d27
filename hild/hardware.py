"""The hardware contract: what every backend (CAN servos, MuJoCo twin, mock) implements.

A component drives a fixed list of joints in *actuator space* (transmissions are applied by the engine, outside
drivers). The engine owns the lifecycle and calls the hooks in order, named as a controller's are (and as
ros2_control's): ``on_configure → read (once, so hold starts where the arm is) → on_activate → {read, write}* →
on_deactivate → on_cleanup``.
``read`` and ``write`` run on the cycle thread: they must not block, log, or allocate needlessly. A component that
reads sensors (``SENSOR_TYPES``, ``hild.interfaces``) also fills their values in ``read_sensors``, called right after
its ``read`` in the same cycle.
"""

from __future__ import annotations

import abc
import enum
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

from hild.arrays import JointState, MimicJoint, SensorValues, ServoCommand
from hild.config.params import Params
from hild.interfaces import SensorSpec

__all__ = [
    "ALL_COMMAND_FIELDS",
    "BusUsage",
    "Finding",
    "GainRange",
    "HardwareComponent",
    "HardwareContext",
    "HardwareError",
    "Lifecycle",
    "joint_index",
]

ALL_COMMAND_FIELDS: frozenset[str] = frozenset({"position", "velocity", "effort", "kp", "kd"})


class Lifecycle(enum.StrEnum):
    UNCONFIGURED = "unconfigured"
    INACTIVE = "inactive"
    ACTIVE = "active"
    FAULT = "fault"


class Homing(enum.StrEnum):
    """Where a drive's own homing procedure stands (``HardwareComponent.homing``)."""

    IDLE = "idle"  # never started, or its outcome already reported
    RUNNING = "running"
    ATTAINED = "attained"  # the drive says its home is found; the joint's position origin may have moved
    FAILED = "failed"


@dataclass(frozen=True, slots=True)
class HardwareContext:
    """What a component may know about the daemon it runs in."""

    name: str
    joints: tuple[str, ...]
    config_dir: Path
    update_rate: float
    clock_source: str  # "wall" or "sim"
    emit_event: Callable[[str, str], None]  # (level, message); never call it per cycle
    # The config's mimic joints that follow a joint of this component: a simulation couples them the same way.
    mimic_joints: tuple[MimicJoint, ...] = ()
    sensors: tuple[SensorSpec, ...] = ()  # the sensors it reads, ``offset`` relative to its own part of the values
    sensor_params: Mapping[str, Params] = field(default_factory=dict)  # per sensor: its validated SensorParams

    @property
    def period(self) -> float:
        return 1.0 / self.update_rate


@dataclass(frozen=True, slots=True)
class BusUsage:
    """Traffic one component puts on a shared medium, so ``hild check`` can add up every component's share."""

    bus: str  # a stable name of the medium, e.g. "socketcan:can0"
    bits_per_second: float  # worst case (bit stuffing included) at the configured update rate
    capacity: float  # bits per second the medium carries (nominal bitrate; data phase accounted by the driver)
    ids: frozenset[int] = frozenset()  # identifiers this component uses on it; overlaps across components are errors


@dataclass(frozen=True, slots=True)
class GainRange:
    """The largest gains a drive accepts, in actuator space: above them it clamps them without saying so."""

    kp: float
    kd: float


@dataclass(frozen=True, slots=True)
class Finding:
    """A driver's verdict on its own params, shown by ``hild check``; errors refuse the config."""

    level: str  # "error" | "warning" | "info"
    message: str


class HardwareError(RuntimeError):
    """A component-level failure with a message meant for the operator (bus down, model mismatch, …)."""


class HardwareComponent(abc.ABC):
    """Base class of every driver, found by name in the ``hild.drivers`` entry-point group.

    Class attributes a driver sets:
    - ``Params``: its parameter model (validated when the config is loaded).
    - ``COMMAND_FIELDS``: the servo-command fields the drive really uses; controllers may only claim these.
    - ``SIMULATED``: True when no real drive is behind it (mock, twin); the config's safety rules then only warn.
    - ``SENSOR_TYPES``: the sensor types it can read (``force_torque``, ``imu``); none by default, and a config that
      gives it sensors is refused. ``SensorParams``: the parameter model of each sensor's ``params``.
    """

    Params: ClassVar[type[Params]] = Params
    COMMAND_FIELDS: ClassVar[frozenset[str]] = ALL_COMMAND_FIELDS
    SIMULATED: ClassVar[bool] = False
    SENSOR_TYPES: ClassVar[frozenset[str]] = frozenset()
    SensorParams: ClassVar[type[Params]] = Params
    APPLIES_GAINS: ClassVar[bool] = True
    """The drive applies the command's kp/kd in its own law, so ``kp·(p − q) + kd·(v − q̇) + ff`` predicts its
    torque and the supervisor may trim ``ff`` against it. False (ODrive in position mode: its own gains) leaves
    only ``ff`` to bound."""

    def __init__(self, context: HardwareContext, params: Params) -> None:
        self.context = context
        self.params = params

    @property
    def joints(self) -> tuple[str, ...]:
        return self.context.joints

    # Config review (class level: runs at load, before anything is opened).
    @classmethod
    def review(cls, params: Params, joints: Sequence[str], update_rate: float) -> list[Finding]:
        """Check params against the joints and rate (e.g. overlapping ids); errors refuse the config."""
        return []

    @classmethod
    def review_files(cls, params: Params, joints: Sequence[str], update_rate: float, config_dir: Path) -> list[Finding]:
        """Like ``review``, for checks that read the files the params name (e.g. a drive's EDS), relative to
        `config_dir` (a missing file is the driver's own finding too)."""
        return []

    @classmethod
    def command_fields(cls, params: Params, joints: Sequence[str]) -> Mapping[str, frozenset[str]]:
        """Per joint, the servo-command fields its drive applies when the params decide them (e.g. a CiA 402
        drive's mode); the loader refuses a controller claiming another. Default: ``COMMAND_FIELDS`` for all."""
        return {joint: cls.COMMAND_FIELDS for joint in joints}

    @classmethod
    def gain_ranges(cls, params: Params, joints: Sequence[str]) -> dict[str, GainRange]:
        """Per joint, the largest kp and kd the drive accepts (actuator space); the loader refuses configured gains
        above them after the transmission. Empty when the drive has no such limit or it is unknown."""
        return {}

    @classmethod
    def bus_usage(cls, params: Params, joints: Sequence[str], update_rate: float) -> list[BusUsage]:
        """The shared media this component loads; the loader sums components per bus (>100 % refused)."""
        return []

    @classmethod
    def files(cls, params: Params) -> dict[str, str]:
        """Param name → a file the component needs, relative to the config's directory; the loader refuses a
        config whose file is missing (``hild check`` says so instead of ``run`` failing)."""
        return {}

    @classmethod
    def holds_at_stop(cls, params: Params) -> bool:
        """True when ``on_deactivate`` leaves the drives holding (e.g. ``on_deactivate: hold``); False when they go
        limp, which drops an unbraked, gravity-loaded joint unless ``safety.stop_descent`` lowers it first."""
        return False

    # Lifecycle hooks (non real-time; may block briefly, may raise HardwareError).
    def on_configure(self) -> None:
        """Open buses or load models and check the hardware matches the config. Drives stay disabled."""

    def on_activate(self) -> None:
        """Enable the drives. Called after one ``read`` so the first command is a hold where the arm is."""

    def on_deactivate(self) -> None:
        """Leave the drives in their safe state (disabled, or holding when the drive can do it alone)."""

    def on_cleanup(self) -> None:
        """Release buses, files and threads."""

    # Cycle hooks (real time).
    @abc.abstractmethod
    def read(self, t: float, dt: float, state: JointState) -> None:
        """Fill ``state`` (actuator space, in ``joints`` order) with the newest feedback.

        Set ``state.fresh[i] = False`` when joint ``i`` had no new feedback this cycle and ``state.fault[i]`` to the
        drive's fault code (0 = healthy).
        """

    @abc.abstractmethod
    def write(self, t: float, dt: float, command: ServoCommand) -> None:
        """Send ``command`` (actuator space) to the drives."""

    def read_sensors(self, t: float, dt: float, values: SensorValues) -> None:
        """Fill ``values`` (this component's sensors, in ``context.sensors`` order, each at its ``offset``) with the
        newest readings, in place; set ``values.fresh[k] = False`` for a sensor with no new reading this cycle.
        Called right after ``read`` in every cycle, only when the component has sensors."""

    # Reporting.
    def health(self) -> str | None:
        """A component-level fault still present (e.g. ``"bus off"``), or None when healthy."""
        return None

    def describe_fault(self, code: int) -> str:
        """Turn a per-joint fault code from ``read`` into words for events and status."""
        return f"drive fault code {code:#x}"

    def clear_faults(self) -> None:
        """Clear drive-side faults on an operator ``reset``. Must not re-enable a drive by itself."""

    def confirming(self) -> bool:
        """True while a state-changing command (clear-error, enable) is still being repeated until the drive's
        replies confirm it: the engine answers an operator ``reset`` only once this is over (bounded)."""
        return False

    def persistent_errors(self) -> dict[str, str]:
        """Joint → the drive's own words for an error still reported after every clear-error try; the engine's
        ``reset`` refuses naming it, and the joint's fault says it, until the drive stops reporting it."""
        return {}

    def enable(self, joint: str | None = None) -> list[str]:
        """Operator command: enable a drive a fault disabled (one joint, or all). Never called automatically;
        returns the joints enabled, which the next reads confirm."""
        raise HardwareError(f"driver {type(self).__name__} enables its drives only at start-up")

    def set_zero(self, joint: str) -> None:
        """Make the drive's current position its zero. Only ever called on an explicit operator command."""
        raise HardwareError(f"driver {type(self).__name__} cannot set a zero position")

    def gains_applied(self) -> list[bool]:
        """Per joint of this component: does the command's kp/kd reach the joint's torque (``APPLIES_GAINS`` for
        all by default)? A driver whose joints differ (CiA 402: CST yes, CSP/CSV no) says so per joint."""
        return [self.APPLIES_GAINS] * len(self.joints)

    def start_homing(self, joint: str) -> None:
        """Operator command (between cycles): start the drive's own homing of `joint` (CiA 402 mode 6).

        The engine calls it only for a held, still joint that no controller claims; until `homing` reports the
        end, the component ignores the servo command for that joint (the drive moves by itself), the engine lets no
        controller claim it and hold follows the measured position (the gate re-anchored on each reading: the
        drive may move its origin). At the end the component puts the drive back in its cyclic mode, aimed at
        where it is, before `homing` reports ATTAINED or FAILED: from then on the engine commands it again.
        Raises HardwareError, in words for the operator, when the drive cannot home."""
        raise HardwareError(f"driver {type(self).__name__} cannot home its drives")

    def stop_homing(self, joint: str) -> None:
        """Abort a running homing of `joint` (e-stop, a fault of the joint, shutdown): the drive halts under its own
        deceleration and returns to its cyclic mode aimed at where it is; `homing` then reports FAILED ("stopped").
        Called between cycles or from the cycle; a joint that is not homing is left alone."""

    def homing(self, joint: str) -> tuple[Homing, str]:
        """Where the homing of `joint` stands, with the drive's words when it failed. Polled every cycle while it
        runs (on the cycle thread: cheap, no I/O); reading ATTAINED or FAILED returns the component to IDLE."""
        return Homing.IDLE, ""


def joint_index(joints: Sequence[str]) -> dict[str, int]:
    return {name: i for i, name in enumerate(joints)}
