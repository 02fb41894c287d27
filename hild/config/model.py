"""The robot config file, as a schema.

One YAML file per robot. This module only says what a well-formed file looks like; what its parts must agree
on (joints named by controllers exist, each joint has exactly one hardware component, …) is checked in
``loader.py`` once the plugins' own parameter models are known.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

from pydantic import Field, PositiveFloat, field_validator, model_validator

from hild.config.params import Params

SafeAction = Literal["hold", "damp", "disable"]


class RobotSection(Params):
    name: str = Field(pattern=r"^[A-Za-z0-9_\-]+$", description="Robot name; the Zenoh key prefix hild/<name>.")
    model: str | None = Field(
        default=None,
        description="MJCF or URDF of the arm, relative to this file. Enables gravity feed-forward in hold.",
    )


class ClockSection(Params):
    source: Literal["wall", "sim"] = Field(
        default="wall",
        description="wall: real time (hardware, real-time twin). sim: lockstep simulation clock t = k·dt.",
    )
    real_time_factor: float = Field(
        default=1.0, ge=0.0, description="Sim clock only: pace at this multiple of real time; 0 = as fast as possible."
    )


class Transmission(Params):
    """Joint ↔ actuator: ``q_joint = direction · q_actuator / reduction + offset``."""

    reduction: float = Field(default=1.0, gt=0.0)
    direction: Literal[1, -1] = 1
    offset: float = 0.0

    @field_validator("reduction", "offset")
    @classmethod
    def _finite(cls, v: float) -> float:
        if not math.isfinite(v):
            raise ValueError("must be a finite number")
        return v


SensorType = Literal["force_torque", "imu"]
# The plausible range of each limited quantity, per sensor type (docs/config.md, "Sensors"): a typical wrist F/T
# sensor's rating, and the usual full scale of a MEMS IMU (2000 °/s, 16 g).
SENSOR_LIMITS: dict[str, dict[str, float]] = {
    "force_torque": {"force": 500.0, "torque": 50.0},
    "imu": {"angular_velocity": 35.0, "linear_acceleration": 160.0},
}


class SensorLimits(Params):
    """The largest plausible magnitude of each component of a sensor's values; a reading beyond it is rejected."""

    force: PositiveFloat | None = Field(default=None, description="N, force_torque only (default 500).")
    torque: PositiveFloat | None = Field(default=None, description="N·m, force_torque only (default 50).")
    angular_velocity: PositiveFloat | None = Field(default=None, description="rad/s, imu only (default 35).")
    linear_acceleration: PositiveFloat | None = Field(default=None, description="m/s², imu only (default 160).")

    def ranges(self, kind: str) -> dict[str, float]:
        """This sensor type's limits, the defaults where none is given."""
        return {key: getattr(self, key) or default for key, default in SENSOR_LIMITS[kind].items()}


class SensorSection(Params):
    type: SensorType = Field(description="force_torque (force.x … torque.z) or imu (orientation, angular_velocity, "
                             "linear_acceleration).")  # fmt: skip
    frame_id: str = Field(min_length=1, description="The link (frame) the values are expressed in.")
    params: dict[str, Any] = Field(default_factory=dict, description="Driver parameters of this sensor.")
    limits: SensorLimits = Field(default_factory=SensorLimits)
    frozen_cycles: int = Field(
        default=50,
        ge=2,
        le=100_000,
        description="A reading bit-identical to the previous ones for this many readings in a row is rejected as "
        "frozen (a real sensor's values carry noise).",
    )

    @model_validator(mode="after")
    def _limits_of_its_type(self) -> SensorSection:
        given = [key for key in SensorLimits.model_fields if getattr(self.limits, key) is not None]
        foreign = [key for key in given if key not in SENSOR_LIMITS[self.type]]
        if foreign:
            allowed = ", ".join(SENSOR_LIMITS[self.type])
            raise ValueError(f"limits {foreign} do not apply to {self.type} sensors (their limits: {allowed})")
        return self


class HardwareSection(Params):
    driver: str = Field(description="Name of a driver in the hild.drivers entry-point group (mock, mujoco, …).")
    params: dict[str, Any] = Field(default_factory=dict, description="Driver parameters; see the driver's docs.")
    joints: dict[str, Transmission] = Field(
        min_length=1, description="Joints this component drives, each with its transmission."
    )
    sensors: dict[Annotated[str, Field(pattern=r"^[A-Za-z0-9_\-]+$")], SensorSection] = Field(
        default_factory=dict,
        description="Sensors this component reads (state interfaces only); names unique across the robot.",
    )


class PositionLimits(Params):
    lower: float
    upper: float

    @model_validator(mode="after")
    def _ordered(self) -> PositionLimits:
        if not (math.isfinite(self.lower) and math.isfinite(self.upper)):
            raise ValueError("lower and upper must be finite numbers")
        if self.lower >= self.upper:
            raise ValueError(f"lower ({self.lower}) must be below upper ({self.upper})")
        return self


class JointLimits(Params):
    position: PositionLimits
    soft_margin: float = Field(
        default=0.0, ge=0.0, description="Commands are kept this far inside the hard position limits (rad)."
    )
    velocity: PositiveFloat = Field(description="rad/s; also bounds how fast a commanded position may move.")
    effort: PositiveFloat = Field(description="N·m; the predicted drive torque is kept within ±effort.")
    acceleration: PositiveFloat | None = Field(
        default=None, description="rad/s²; needed by controllers that plan motion (joint_trajectory, servo)."
    )
    jerk: PositiveFloat | None = Field(
        default=None, description="rad/s³; needed by controllers that plan motion (joint_trajectory, servo)."
    )

    @model_validator(mode="after")
    def _margin_fits(self) -> JointLimits:
        span = self.position.upper - self.position.lower
        if 2 * self.soft_margin >= span:
            raise ValueError(f"soft_margin {self.soft_margin} leaves no room inside position limits (span {span:g})")
        return self


class Gains(Params):
    kp: float = Field(ge=0.0)
    kd: float = Field(ge=0.0)


class VelocityGains(Params):
    kd: float = Field(ge=0.0)


class FrictionModel(Params):
    """A joint's identified friction and effort offset (``hild identify`` writes it): what teach mode compensates
    and the contact observer subtracts before it calls a torque external (docs/safety.md, "Contact")."""

    viscous: float = Field(default=0.0, ge=0.0, description="N·m·s/rad (N·s/m): torque per unit of speed.")
    coulomb: float = Field(default=0.0, ge=0.0, description="N·m (N): torque against the motion at any speed.")
    offset: float = Field(
        default=0.0, description="N·m (N): a constant torque the drive reports or needs at rest (cogging, bias)."
    )
    band: float = Field(
        default=0.02,
        gt=0.0,
        le=1.0,
        description="rad/s (m/s): speed over which the Coulomb term rises from 0 to full (tanh), so it never "
        "chatters around zero speed.",
    )

    @field_validator("viscous", "coulomb", "offset", "band")
    @classmethod
    def _finite(cls, v: float) -> float:
        if not math.isfinite(v):
            raise ValueError("must be a finite number")
        return v


class JointSection(Params):
    limits: JointLimits
    hold: Gains = Field(description="Gains used while the joint is held (no controller commands it).")
    position_gains: Gains | None = Field(
        default=None, description="Defaults for a position claim; the hold gains when not given."
    )
    velocity_gains: VelocityGains | None = Field(
        default=None, description="Default kd for a velocity claim; the hold kd when not given."
    )
    friction: FrictionModel | None = Field(
        default=None, description="Identified friction and effort offset (hild identify); none: not compensated."
    )


class MimicJointSection(Params):
    """A joint nothing commands that follows a robot joint, as URDF ``<mimic>`` says and ros2_control reads it:
    ``position = multiplier·q + offset``, ``velocity = multiplier·q̇`` of the joint it follows."""

    joint: str = Field(description="The robot joint (under joints) it follows.")
    multiplier: float = Field(default=1.0, description="Its position per unit of the followed joint's position.")
    offset: float = Field(default=0.0, description="Its position when the followed joint is at 0 (rad or m).")

    @field_validator("multiplier", "offset")
    @classmethod
    def _finite(cls, v: float) -> float:
        if not math.isfinite(v):
            raise ValueError("must be a finite number")
        return v


class ControllerSection(Params):
    type: str = Field(description="Name in the hild.controllers entry-point group.")
    params: dict[str, Any] = Field(default_factory=dict)
    autostart: bool = Field(default=False, description="Activate when the daemon starts.")
    fallback_controllers: list[str] = Field(
        default_factory=list, description="Activated when this controller fails in update()."
    )
    chain_to: str | None = Field(
        default=None,
        description="A chainable controller (joint_impedance) whose reference interfaces this one claims instead of "
        "the hardware's: what it commands becomes that controller's targets (docs/controllers.md, "
        '"Chained controllers").',
    )


class PlausibilitySection(Params):
    """What a reading must satisfy before anything uses it (docs/safety.md, "Plausibility before trust")."""

    margin: float = Field(
        default=0.05, ge=0.0, le=0.5, description="rad beyond the hard limits a reading may lie (a joint on its stop)."
    )
    speed_factor: float = Field(
        default=3.0,
        ge=1.0,
        le=100.0,
        description="A reading further from the last accepted one than factor × velocity limit × the time since is "
        "rejected as a jump.",
    )
    step_tolerance: float = Field(
        default=0.002, ge=0.0, le=0.1, description="rad added to that bound: encoder quantisation and noise."
    )


class ContactThresholds(Params):
    """A joint's two levels of external torque (N·m; N for a prismatic joint), as the observer estimates it."""

    contact: float = Field(gt=0.0, description="Above it: a contact event (no stop).")
    collision: float = Field(gt=0.0, description="Above it: the collision reflex and a latched fault.")

    @model_validator(mode="after")
    def _ordered(self) -> ContactThresholds:
        if not (math.isfinite(self.contact) and math.isfinite(self.collision)):
            raise ValueError("thresholds must be finite")
        if self.contact > self.collision:
            raise ValueError(f"contact threshold {self.contact:g} is above the collision threshold {self.collision:g}")
        return self


class ContactForce(Params):
    """Cartesian contact detection: the external force at the tool that the joints' torques imply
    (docs/safety.md, "Contact", "At the tool")."""

    contact: float = Field(gt=0.0, description="N: above it, a contact event (no stop).")
    collision: float = Field(gt=0.0, description="N: above it, the collision reflex and a latched fault.")
    bandwidth: float = Field(
        default=300.0,
        gt=0.0,
        le=5000.0,
        description="1/s: a second low-pass on the force estimate (after the observer's own), against the noise of "
        "the drives' quantised velocity replies; bandwidth × the cycle period must stay below 1.",
    )
    baseline: float = Field(
        default=0.1,
        gt=0.0,
        le=10.0,
        description="s: the time constant of the force's recent average; a change from it by more than a threshold "
        "is a sudden contact, whatever the model's slow error.",
    )
    damping: float = Field(
        default=0.02,
        gt=0.0,
        le=1.0,
        description="m: the damped least squares' λ; near a singularity a force is seen σ²/(σ² + λ²) of its size.",
    )

    @model_validator(mode="after")
    def _ordered(self) -> ContactForce:
        values = (self.contact, self.collision, self.bandwidth, self.baseline, self.damping)
        if not all(math.isfinite(v) for v in values):
            raise ValueError("force thresholds and filters must be finite")
        if self.contact > self.collision:
            raise ValueError(
                f"force contact threshold {self.contact:g} N is above the collision threshold {self.collision:g} N"
            )
        return self


class ContactSection(Params):
    """The external torque estimate and the collision reflex (docs/safety.md, "Contact")."""

    enabled: bool = Field(
        default=False,
        description="Run the momentum observer on robot.model every cycle, publish tau_ext and react to contacts.",
    )
    observer_gain: float = Field(
        default=150.0,
        gt=0.0,
        le=5000.0,
        description="1/s: the observer's bandwidth K (tau_ext follows a step in the external torque as "
        "1 − e^(−K·t)); K × the cycle period must stay below 1.",
    )
    torque: Literal["reply", "command"] = Field(
        default="reply",
        description="The motor torque the observer uses: the drive's torque reply where it reports one (else the "
        "command's predicted torque), or always the torque predicted from the servo command.",
    )
    contact: float = Field(default=5.0, gt=0.0, description="N·m: the default contact threshold of every joint.")
    collision: float = Field(default=10.0, gt=0.0, description="N·m: the default collision threshold of every joint.")
    joints: dict[str, ContactThresholds] = Field(
        default_factory=dict, description="Per-joint thresholds, overriding the defaults."
    )
    model_margin: float = Field(
        default=0.1,
        ge=0.0,
        le=1.0,
        description="Both thresholds rise by this fraction of the joint's (low-passed) motor torque: the model's "
        "relative error (masses ±10 %: 0.1), so fast motion and abrupt stops do not read as contacts.",
    )
    reflex: Literal["hold", "retract"] = Field(
        default="hold",
        description="On collision: hold compliantly where the arm is, or retract along the recent path first.",
    )
    reflex_stiffness: float = Field(
        default=0.25,
        ge=0.0,
        le=1.0,
        description="The reflex's kp as a fraction of each joint's hold kp (kd stays the hold kd).",
    )
    retract_distance: float = Field(
        default=0.005, gt=0.0, le=0.1, description="m the tool goes back along its recent path (reflex: retract)."
    )
    retract_time: float = Field(default=0.2, gt=0.0, le=2.0, description="s the retract takes.")
    tool_site: str | None = Field(
        default=None,
        description="The model's site whose path the retract measures; default: the origin of the last joint's body.",
    )
    force: ContactForce | None = Field(
        default=None,
        description="Cartesian thresholds (N) on the external force at the tool (tool_site, default the model's "
        "tool site); none: per-joint thresholds only.",
    )

    @model_validator(mode="after")
    def _ordered(self) -> ContactSection:
        if self.contact > self.collision:
            raise ValueError(f"contact threshold {self.contact:g} is above the collision threshold {self.collision:g}")
        return self

    def thresholds(self, joint: str) -> ContactThresholds:
        return self.joints.get(joint) or ContactThresholds(contact=self.contact, collision=self.collision)


Vector3 = tuple[float, float, float]


def _finite3(v: Vector3) -> Vector3:
    if not all(math.isfinite(x) for x in v):
        raise ValueError(f"must be three finite numbers, got {list(v)}")
    return v


class WallBox(Params):
    """The box the tool must stay inside, in the model's world frame (the robot's base frame for a fixed arm)."""

    min: Vector3 = Field(description="m: the box's lowest corner (x, y, z).")
    max: Vector3 = Field(description="m: the box's highest corner (x, y, z).")

    @field_validator("min", "max")
    @classmethod
    def _finite(cls, v: Vector3) -> Vector3:
        return _finite3(v)

    @model_validator(mode="after")
    def _not_empty(self) -> WallBox:
        empty = [axis for axis, lo, hi in zip("xyz", self.min, self.max, strict=True) if not lo < hi]
        if empty:
            raise ValueError(f"the box is empty along {', '.join(empty)}: min must be below max on every axis")
        return self


class WallPlane(Params):
    """A half-space wall: the tool stays on the side its normal points away from."""

    name: str | None = Field(default=None, min_length=1, description="Named in events and status; plane[i] if not.")
    point: Vector3 = Field(description="m: a point on the wall, in the world frame.")
    normal: Vector3 = Field(description="The wall's outward normal: it points to where the tool must not go.")

    @field_validator("point", "normal")
    @classmethod
    def _finite(cls, v: Vector3) -> Vector3:
        return _finite3(v)

    @field_validator("normal")
    @classmethod
    def _non_zero(cls, v: Vector3) -> Vector3:
        if math.hypot(*v) < 1e-9:
            raise ValueError("the normal must not be zero: it says which side of the wall is out")
        return v


class WallsSection(Params):
    """Virtual walls for the tool point on the commanded pose (docs/safety.md, "Virtual walls")."""

    enabled: bool = Field(default=False, description="Check every position command against the walls.")
    site: str | None = Field(
        default=None, min_length=1, description="The tool frame: a site of robot.model (default: site tool or flange)."
    )
    body: str | None = Field(
        default=None,
        min_length=1,
        description="The tool frame as a body of robot.model instead of a site (default when the model has no tool "
        "or flange site: the body of the deepest configured joint).",
    )
    tool_offset: Vector3 = Field(default=(0.0, 0.0, 0.0), description="m: the tool point in that frame.")
    box: WallBox | None = Field(default=None, description="The box the tool stays inside.")
    planes: list[WallPlane] = Field(default_factory=list, description="Half-spaces the tool stays out of.")
    margin: float = Field(
        default=0.01, ge=0.0, le=0.5, description="m: the commanded tool point is kept this far inside every wall."
    )
    deceleration: float = Field(
        default=20.0,
        gt=0.0,
        le=1000.0,
        description="m/s²: the commanded tool's speed toward a wall is kept within sqrt(2·deceleration·distance), "
        "so it brakes to a stop on the wall instead of hitting it.",
    )

    lead_time: float = Field(
        default=0.15,
        ge=0.0,
        le=1.0,
        description="s: each wall is pulled in by this × the measured tool's speed toward it, since the arm runs "
        'behind its command and carries on past a command that stops (docs/safety.md, "Virtual walls").',
    )

    self_collision: bool = Field(
        default=False,
        description="Also refuse a commanded pose where two of the arm's bodies would touch (the model's collision "
        "geometry and its own filters: contype/conaffinity, parent-child, <exclude>): the joints hold the last "
        "safe command.",
    )

    @field_validator("tool_offset")
    @classmethod
    def _finite(cls, v: Vector3) -> Vector3:
        return _finite3(v)

    @model_validator(mode="after")
    def _has_walls(self) -> WallsSection:
        if self.site is not None and self.body is not None:
            raise ValueError("give the tool frame as a site or a body, not both")
        if self.enabled and self.box is None and not self.planes and not self.self_collision:
            raise ValueError("walls are enabled but none is given: add a box or planes (or self_collision: true)")
        return self


class SafetySection(Params):
    stale_feedback_cycles: int = Field(
        default=10,
        ge=1,
        description="A joint without an accepted reading (none arrived, or it was rejected) for this many cycles "
        "faults — and, if stale_feedback_time is set, for that long too.",
    )
    stale_feedback_time: float = Field(
        default=0.0,
        ge=0.0,
        le=10.0,
        description="s without an accepted reading before a joint faults, counted on top of stale_feedback_cycles: "
        "both must pass. Time is robust to a late cycle (a stalled host misses no replies); cycles are robust "
        "to a slow rate. 0 = cycles only.",
    )
    plausibility: PlausibilitySection = Field(default_factory=PlausibilitySection)
    max_cycle_gap: float = Field(
        default=0.5,
        ge=0.0,
        le=10.0,
        description="s: a cycle that comes this long after the previous one faults every joint (the arm was on its "
        "drives' own watchdogs meanwhile). Shorter gaps are events; controllers resume where they were. 0 = off.",
    )
    stop_descent: float = Field(
        default=0.0,
        ge=0.0,
        le=30.0,
        description="On stop, before the drives are released: a damped descent — kd only, gravity feed-forward "
        "fading out over this many seconds — so an unbraked arm is lowered, not dropped. 0 = none.",
    )
    overspeed_factor: float = Field(
        default=1.5, ge=1.0, description="Measured speed above factor × velocity limit faults the joint."
    )
    max_consecutive_overruns: int = Field(
        default=20, ge=0, description="This many overrun cycles in a row fault every joint; 0 disables."
    )
    fault_action: SafeAction = Field(default="hold", description="What a faulted joint does.")
    estop_action: SafeAction = Field(default="hold", description="What every joint does under e-stop.")
    gravity_compensation: bool = Field(
        default=True,
        description="Add gravity feed-forward from robot.model in hold and position modes, and on top of the effort "
        "of controllers that ask for it (joint_trajectory gravity_compensation).",
    )
    contact: ContactSection = Field(default_factory=ContactSection)
    walls: WallsSection = Field(
        default_factory=WallsSection, description="Virtual walls for the tool (needs robot.model)."
    )


class ZenohSection(Params):
    mode: Literal["peer", "router", "client"] = "peer"
    listen: list[str] = Field(default_factory=lambda: ["tcp/127.0.0.1:7447"])
    connect: list[str] = Field(default_factory=list)
    multicast_scouting: bool = False
    shared_memory: bool = Field(
        default=False,
        description="Zenoh's shared-memory transport on the daemon's session. Off: a receiving session keeps "
        "the 16 MiB pool of every sender that ever sent it 3 KB or more, for the life of the daemon.",
    )
    config_file: str | None = Field(default=None, description="A Zenoh JSON5 config file, applied first.")
    config: dict[str, Any] = Field(
        default_factory=dict, description="Extra Zenoh config keys (dotted paths → values), applied last."
    )


class Ros2Section(Params):
    """Opt-in: the daemon is also a ROS 2 node on rmw_zenoh's wire protocol (docs/ros2.md)."""

    distro: Literal["jazzy"] = Field(
        default="jazzy", description="ROS 2 distribution whose type hashes and messages are used (jazzy only)."
    )
    domain_id: int = Field(default=0, ge=0, le=232, description="ROS_DOMAIN_ID: the first chunk of every key.")
    namespace: str = Field(
        default="/",
        pattern=r"^/([A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*)?$",
        description="ROS namespace of the node and its topics and services: '/' or '/a/b'.",
    )
    node: str = Field(
        default="controller_manager",
        pattern=r"^[A-Za-z_][A-Za-z0-9_]*$",
        description="ROS node name; services live under <namespace>/controller_manager as in ros2_control.",
    )
    robot_description: str | None = Field(
        default=None,
        min_length=1,
        description="URDF published on /robot_description, relative to this file; absent: robot.model if a .urdf.",
    )


class FileSinkSpec(Params):
    """Write a ``.rrd`` recording; with rotation, every file is named ``<stem>-<UTC timestamp>.rrd``."""

    kind: Literal["file"]
    path: str = Field(min_length=1, description="Path of the .rrd file, relative to the config file's directory.")
    rotate_mb: PositiveFloat | None = Field(default=None, description="Start a new file past this size (MB).")
    rotate_minutes: PositiveFloat | None = Field(default=None, description="Start a new file after this many minutes.")

    @field_validator("path")
    @classmethod
    def _rrd(cls, v: str) -> str:
        if not v.endswith(".rrd"):
            raise ValueError(f"a rerun recording path ending in .rrd, got {v!r}")
        return v


class SpawnSinkSpec(Params):
    """Start a native rerun viewer on this machine and stream to it."""

    kind: Literal["spawn"]
    port: int = Field(default=9876, ge=1, le=65535, description="Port of the spawned viewer's gRPC server.")
    bind: str = Field(default="127.0.0.1", description="Address the viewer's gRPC server listens on.")


class ConnectSinkSpec(Params):
    """Stream to a viewer (or server) that is already running."""

    kind: Literal["connect"]
    url: str = Field(
        default="rerun+http://127.0.0.1:9876/proxy",
        pattern=r"^(rerun|rerun\+http|rerun\+https)://[^/]+/proxy$",
        description="rerun://, rerun+http:// or rerun+https:// URL ending in /proxy.",
    )


class ServeSinkSpec(Params):
    """Host a gRPC server in the daemon that viewers connect to (``rerun+http://<bind>:<port>/proxy``)."""

    kind: Literal["serve"]
    bind: str = Field(default="127.0.0.1", description="Address to bind; 127.0.0.1 keeps it on this machine.")
    port: int = Field(default=9876, ge=1, le=65535)
    memory_limit: str = Field(default="512MiB", description="Buffer for late viewers; oldest data dropped first.")


TelemetrySink = Annotated[FileSinkSpec | SpawnSinkSpec | ConnectSinkSpec | ServeSinkSpec, Field(discriminator="kind")]


class TelemetrySection(Params):
    """rerun telemetry (docs/telemetry.md): batched off the cycle thread, to one or more sinks."""

    enabled: bool = Field(default=False, description="Record and stream telemetry with rerun.")
    sinks: list[TelemetrySink] = Field(default_factory=list, description="Where telemetry goes; several at once.")
    flush_period: float = Field(default=0.1, ge=0.01, le=5.0, description="Seconds between batches sent to rerun.")
    scalar_rate: float = Field(
        default=0.0, ge=0.0, description="Hz of the joint and loop scalars; 0 = every cycle (capped at update_rate)."
    )
    pose_rate: float = Field(default=30.0, gt=0.0, le=1000.0, description="Hz of the 3D arm pose.")

    @model_validator(mode="after")
    def _needs_a_sink(self) -> TelemetrySection:
        if self.enabled and not self.sinks:
            raise ValueError("telemetry is enabled but has no sinks: add e.g. {kind: file, path: recordings/x.rrd}")
        serve_ports = [s.port for s in self.sinks if isinstance(s, ServeSinkSpec)]
        if len(serve_ports) > 1:
            raise ValueError("at most one serve sink (one gRPC server per daemon)")
        return self


BlackboxTrigger = Literal["fault", "estop", "stall"]


class RecordingSection(Params):
    """Episodes and the flight recorder (docs/recording.md): every cycle, off the cycle, in MCAP files."""

    enabled: bool = Field(
        default=True,
        description="Keep the cycle log (every cycle's row, in shared memory) and run the recorder process: "
        "episodes on request, black boxes on the triggers. Off: the cycle writes no cycle log.",
    )
    dir: str = Field(
        default="recordings",
        min_length=1,
        description="Where episodes and black boxes are written; relative to the config file's directory.",
    )
    blackbox_seconds: float = Field(
        default=10.0,
        ge=0.0,
        description="Seconds of every cycle the flight recorder keeps and writes on a trigger; 0: no black box.",
    )
    blackbox_on: list[BlackboxTrigger] = Field(
        default_factory=lambda: ["fault", "estop", "stall"],
        description="What writes a black box: a fault latches, an e-stop engages, the cycle stalls.",
    )
    stall_after: float = Field(
        default=0.5, gt=0.0, description="s without a new cycle while live that counts as a stall."
    )
    fps: float = Field(default=30.0, gt=0.0, description="An episode's dataset frame rate unless its start says.")
    chunk_period: float = Field(
        default=0.1,
        ge=0.01,
        le=0.2,
        description="s between MCAP chunks, each valid alone: a crash loses at most the last one.",
    )
    fsync: bool = Field(default=True, description="fsync each chunk, so a power cut loses at most the last one.")
    min_free_mb: float = Field(
        default=200.0, ge=0.0, description="An episode stops, with an event, when the disk has less free (MB)."
    )

    @field_validator("blackbox_on")
    @classmethod
    def _once_each(cls, v: list[str]) -> list[str]:
        twice = sorted({t for t in v if v.count(t) > 1})
        if twice:
            raise ValueError(f"each trigger at most once ({', '.join(twice)} listed more than once)")
        return v


class RealtimeSection(Params):
    priority: int = Field(default=0, ge=0, le=99, description="SCHED_FIFO priority of the cycle thread; 0 = off.")
    cpu_affinity: list[int] = Field(default_factory=list, description="CPUs the cycle thread may run on.")
    client_cpu_affinity: list[int] = Field(
        default_factory=list,
        description="CPUs the client domain (the daemon: Zenoh, the API, planning, status) may run on; keep them "
        "apart from cpu_affinity to give the cycle a core of its own. Empty: any.",
    )
    lock_memory: bool = Field(default=False, description="mlockall(MCL_CURRENT|MCL_FUTURE|MCL_ONFAULT).")
    timer_slack_ns: int = Field(default=1, ge=1, description="Timer slack of the cycle thread.")
    spin_us: int = Field(
        default=200,
        ge=0,
        le=10_000,
        description="The cycle thread sleeps to this long before each deadline, then spins: longer is steadier "
        "on a machine whose idle CPU wakes slowly (VMs), at the cost of CPU time. At least the period (e.g. 1000 "
        "at 1 kHz): the cycle never sleeps, it spins through the whole period (for an isolated core).",
    )
    cpu_dma_latency_us: int | None = Field(
        default=None,
        ge=0,
        le=1_000_000,
        description="Hold /dev/cpu_dma_latency at this many µs while running (0: no CPU enters a deep idle state, "
        "so the cycle never wakes on a cold core); needs write access to the device (root or a udev rule).",
    )
    gc_freeze: bool = Field(default=True, description="gc.collect(); gc.freeze() after start-up.")
    cycle_process: bool = Field(
        default=True,
        description="Run the cycle in a process of its own (hardware, supervisor, controllers' update), apart from "
        "everything done for clients (Zenoh, decoding, planning, status, telemetry), so no client can reach its "
        'interpreter lock (docs/architecture.md, "Three processes").',
    )
    switch_interval: float = Field(
        default=0.0005, gt=0.0, le=0.1, description="sys.setswitchinterval: how long another thread may hold the GIL."
    )


class RobotConfig(Params):
    robot: RobotSection
    update_rate: float = Field(ge=1.0, le=10000.0, description="Cycle rate in Hz (500–1000 typical).")
    clock: ClockSection = Field(default_factory=ClockSection)
    hardware: dict[str, HardwareSection] = Field(min_length=1)
    joints: dict[str, JointSection] = Field(min_length=1)
    mimic_joints: dict[str, MimicJointSection] = Field(
        default_factory=dict,
        description="Joints that follow a robot joint (a gripper's linkage): reported in joint_states after the "
        "robot's joints; the twin checks its model couples them the same way.",
    )
    controllers: dict[str, ControllerSection] = Field(default_factory=dict)
    safety: SafetySection = Field(default_factory=SafetySection)
    zenoh: ZenohSection = Field(default_factory=ZenohSection)
    ros2: Ros2Section | None = Field(default=None, description="Present: speak ROS 2 over Zenoh (docs/ros2.md).")
    telemetry: TelemetrySection = Field(default_factory=TelemetrySection)
    recording: RecordingSection = Field(default_factory=RecordingSection)
    realtime: RealtimeSection = Field(default_factory=RealtimeSection)
