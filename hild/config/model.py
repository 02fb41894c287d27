"""The robot config file, as a schema.

One YAML file per robot. This module only says what a well-formed file looks like; what its parts must agree
on (joints named by controllers exist, each joint has exactly one hardware component, …) is checked in
``loader.py`` once the plugins' own parameter models are known.
"""

from __future__ import annotations

import math
from typing import Any, Literal

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


class HardwareSection(Params):
    driver: str = Field(description="Name of a driver in the hild.drivers entry-point group (mock, mujoco, …).")
    params: dict[str, Any] = Field(default_factory=dict, description="Driver parameters; see the driver's docs.")
    joints: dict[str, Transmission] = Field(
        min_length=1, description="Joints this component drives, each with its transmission."
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


class JointSection(Params):
    limits: JointLimits
    hold: Gains = Field(description="Gains used while the joint is held (no controller commands it).")
    position_gains: Gains | None = Field(
        default=None, description="Defaults for a position claim; the hold gains when not given."
    )
    velocity_gains: VelocityGains | None = Field(
        default=None, description="Default kd for a velocity claim; the hold kd when not given."
    )


class ControllerSection(Params):
    type: str = Field(description="Name in the hild.controllers entry-point group.")
    params: dict[str, Any] = Field(default_factory=dict)
    autostart: bool = Field(default=False, description="Activate when the daemon starts.")
    fallback_controllers: list[str] = Field(
        default_factory=list, description="Activated when this controller fails in update()."
    )


class SafetySection(Params):
    stale_feedback_cycles: int = Field(
        default=10, ge=1, description="A joint without fresh feedback for this many cycles faults."
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
        default=True, description="Add gravity feed-forward from robot.model in hold and position modes."
    )


class ZenohSection(Params):
    mode: Literal["peer", "router", "client"] = "peer"
    listen: list[str] = Field(default_factory=lambda: ["tcp/127.0.0.1:7447"])
    connect: list[str] = Field(default_factory=list)
    multicast_scouting: bool = False
    config_file: str | None = Field(default=None, description="A Zenoh JSON5 config file, applied first.")
    config: dict[str, Any] = Field(
        default_factory=dict, description="Extra Zenoh config keys (dotted paths → values), applied last."
    )


class TelemetrySection(Params):
    enabled: bool = Field(default=False, description="rerun telemetry (see docs/config.md).")

    @field_validator("enabled")
    @classmethod
    def _not_yet(cls, v: bool) -> bool:
        if v:
            raise ValueError("false: rerun telemetry is not implemented in this version")
        return v


class RealtimeSection(Params):
    priority: int = Field(default=0, ge=0, le=99, description="SCHED_FIFO priority of the cycle thread; 0 = off.")
    cpu_affinity: list[int] = Field(default_factory=list, description="CPUs the cycle thread may run on.")
    lock_memory: bool = Field(default=False, description="mlockall(MCL_CURRENT|MCL_FUTURE|MCL_ONFAULT).")
    timer_slack_ns: int = Field(default=1, ge=1, description="Timer slack of the cycle thread.")
    gc_freeze: bool = Field(default=True, description="gc.collect(); gc.freeze() after start-up.")
    switch_interval: float = Field(
        default=0.0005, gt=0.0, le=0.1, description="sys.setswitchinterval: how long another thread may hold the GIL."
    )


class RobotConfig(Params):
    robot: RobotSection
    update_rate: float = Field(ge=1.0, le=10000.0, description="Cycle rate in Hz (500–1000 typical).")
    clock: ClockSection = Field(default_factory=ClockSection)
    hardware: dict[str, HardwareSection] = Field(min_length=1)
    joints: dict[str, JointSection] = Field(min_length=1)
    controllers: dict[str, ControllerSection] = Field(default_factory=dict)
    safety: SafetySection = Field(default_factory=SafetySection)
    zenoh: ZenohSection = Field(default_factory=ZenohSection)
    telemetry: TelemetrySection = Field(default_factory=TelemetrySection)
    realtime: RealtimeSection = Field(default_factory=RealtimeSection)
