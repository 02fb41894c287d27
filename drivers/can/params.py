"""Config parameters of the CAN host drivers (``mit_can``, ``odrive_can``): what a ``hardware.params`` block holds.

Validation here covers single values; the cross-checks that need the whole block and the component's joints
(overlapping ids, unknown models, motors missing for a joint) are the drivers' ``review`` so ``hild check`` can
list every reason at once.
"""

from __future__ import annotations

from typing import Literal

from drivers.can.bus import BusSpec
from hild.config.params import Field, Params

MAX_STANDARD_ID = 0x7FF


class CanDriverParams(Params):
    """What every CAN host driver shares: the bus, its recovery, and how long lifecycle hooks wait."""

    bus: BusSpec = Field(description="The bus this component owns (one component = one bus).")
    bus_recovery: Literal["reopen", "none"] = Field(
        default="reopen",
        description="On an operator reset after a bus fault: reopen the bus, or only clear the latched fault "
        "(when the kernel restarts the controller itself, e.g. socketcan restart-ms).",
    )
    reply_timeout_ms: float = Field(
        default=200.0, gt=0.0, le=10_000.0, description="How long configure/activate wait for the drives' replies."
    )
    send_failure_cycles: int = Field(
        default=3, ge=1, description="Cycles in a row with a full send queue before the component faults."
    )
    event_interval: float = Field(
        default=1.0, gt=0.0, description="Seconds between two events summarising ignored (bad or unknown) frames."
    )


class RangeOverrides(Params):
    """Replace single mapping ranges of a motor model (symmetric: ±value)."""

    p_max: float | None = Field(default=None, gt=0.0, allow_inf_nan=False, description="rad")
    v_max: float | None = Field(default=None, gt=0.0, allow_inf_nan=False, description="rad/s")
    t_max: float | None = Field(default=None, gt=0.0, allow_inf_nan=False, description="Nm")

    def as_dict(self) -> dict[str, float]:
        return {k: v for k, v in self.model_dump().items() if v is not None}


class MitMotorParams(Params):
    id: int = Field(ge=0, le=MAX_STANDARD_ID, description="Motor CAN id (Damiao ESC_ID, T-Motor driver id, …).")
    reply_id: int | None = Field(
        default=None,
        ge=0,
        le=MAX_STANDARD_ID,
        description="Damiao: this motor's MST_ID (default: master_id). Other flavours derive it from the id.",
    )
    model: str = Field(description="Motor model, for the mapping ranges (e.g. DM4310, AK80-9, motion_mode).")
    ranges: RangeOverrides | None = Field(default=None, description="Overrides of the model's ranges.")


class MitCanParams(CanDriverParams):
    flavour: Literal["damiao", "tmotor", "myactuator"]
    master_id: int = Field(
        default=0, ge=0, le=MAX_STANDARD_ID, description="Host id: T-Motor reply id; Damiao default MST_ID."
    )
    motors: dict[str, MitMotorParams] = Field(min_length=1, description="One entry per joint of this component.")
    timeout_ms: float | None = Field(
        default=None,
        ge=0.0,
        le=200_000.0,
        description="Damiao CAN watchdog written at configure (TIMEOUT register, 50 µs units); default 100 ms, "
        "0 disables. Other flavours have no such register.",
    )
    status_poll_ms: float | None = Field(
        default=None,
        ge=0.0,
        description="MyActuator: read each motor's error flags and temperature (native 0x9A) every this many ms; "
        "default 100, 0 disables. Motion-mode replies carry neither.",
    )
    on_deactivate: Literal["disable", "hold"] = Field(
        default="disable",
        description="disable: motors go limp on stop. hold: they keep their last command (until a watchdog fires).",
    )


class ODriveAxisParams(Params):
    node_id: int = Field(ge=0, le=0x3F, description="The axis' CAN node id (0..63).")


class ODriveCanParams(CanDriverParams):
    axes: dict[str, ODriveAxisParams] = Field(min_length=1, description="One entry per joint of this component.")
    encoder_rate_ms: float = Field(
        default=0.0,
        ge=0.0,
        description="0: ask each axis for its encoder estimates every cycle (RTR). >0: the axes send them "
        "cyclically at this period (axis.config.can.encoder_msg_rate_ms) and nothing is requested.",
    )
    heartbeat_rate_ms: float = Field(
        default=100.0, gt=0.0, description="The axes' heartbeat period (axis.config.can.heartbeat_msg_rate_ms)."
    )
    heartbeat_timeout_ms: float | None = Field(
        default=None, gt=0.0, description="An axis without a heartbeat for this long is stale; default 3 periods."
    )
    on_deactivate: Literal["idle", "hold"] = Field(
        default="idle", description="idle: axes disarm on stop. hold: they stay in closed loop at the last input."
    )

    @property
    def heartbeat_timeout(self) -> float:
        return (self.heartbeat_timeout_ms or 3.0 * self.heartbeat_rate_ms) / 1000.0


# ---- CANopen CiA 402 (``cia402``) --------------------------------------------------------------------------------
Cia402Mode = Literal["csp", "csv", "cst"]


class Cia402HomingParams(Params):
    """The drive's own homing (mode 6), run only on an explicit ``hild ctl home JOINT``."""

    method: int = Field(
        default=37, ge=-128, le=127, description="0x6098 homing method (37: the current position is home)."
    )
    offset: float = Field(default=0.0, allow_inf_nan=False, description="0x607C home offset, rad (actuator).")
    speed_switch: float | None = Field(
        default=None, gt=0.0, description="0x6099:1, rad/s (actuator); default: the drive's (EDS) value."
    )
    speed_zero: float | None = Field(
        default=None, gt=0.0, description="0x6099:2, rad/s (actuator); default: the drive's (EDS) value."
    )
    acceleration: float | None = Field(
        default=None, gt=0.0, description="0x609A, rad/s² (actuator); default: the drive's (EDS) value."
    )
    timeout: float = Field(default=30.0, gt=0.0, description="Seconds before an unfinished homing is a failure.")


class Cia402DriveParams(Params):
    """One drive (one joint): its node id and what turns its units into actuator space."""

    node_id: int = Field(ge=1, le=127, description="CANopen node id (1..127).")
    mode: Cia402Mode | None = Field(default=None, description="csp, csv or cst; default: the component's mode.")
    eds: str | None = Field(default=None, description="This drive's EDS/DCF, if not the component's.")
    counts_per_rev: float | None = Field(
        default=None,
        gt=0.0,
        description="Position units (0x6064, 0x607A) per revolution of the actuator shaft; default from the EDS: "
        "0x608F encoder increments per motor revolution × 0x6091 motor revolutions per shaft revolution.",
    )
    velocity_factor: float = Field(
        default=1.0,
        gt=0.0,
        description="Velocity units (0x606C, 0x60FF) per position unit per second (1: the drive's velocity is in "
        "position units/s).",
    )
    rated_torque: float | None = Field(
        default=None,
        gt=0.0,
        description="N·m that torque values (0x6071, 0x6077, 0x60B2; per mille of rated torque) refer to; default "
        "from the EDS: 0x6076 (mN·m).",
    )
    max_torque: float | None = Field(
        default=None, gt=0.0, description="Written to 0x6072 (N·m → per mille); default: the drive's value."
    )
    following_error_window: float | None = Field(
        default=None,
        gt=0.0,
        description="CSP following-error window written to 0x6065 (rad, actuator); default: the drive's value.",
    )
    following_error_timeout_ms: int | None = Field(
        default=None, ge=0, le=65535, description="0x6066, ms; default: the drive's value."
    )
    homing: Cia402HomingParams | None = Field(default=None, description="The drive's homing; none: cannot home.")


class Cia402Params(CanDriverParams):
    """``cia402``: CANopen drives with the CiA 402 profile, cyclic synchronous modes, one bus per component."""

    eds: str = Field(description="The drives' EDS or DCF (relative to the config's directory).")
    mode: Cia402Mode = Field(default="csp", description="csp, csv or cst: the cyclic synchronous mode of every drive.")
    drives: dict[str, Cia402DriveParams] = Field(min_length=1, description="One entry per joint of this component.")
    sync: Literal["produce", "external"] = Field(
        default="produce",
        description="produce: hild sends SYNC after each cycle's RPDOs. external: another master produces it; hild "
        "only sends RPDOs and reads the TPDOs that SYNC triggers.",
    )
    sync_id: int = Field(default=0x80, ge=1, le=MAX_STANDARD_ID, description="COB-ID of SYNC (0x1005).")
    velocity_feedback: Literal["derived", "pdo"] = Field(
        default="derived",
        description="derived: velocity from consecutive SYNC-latched positions, so one TPDO per drive and cycle "
        "fits classic CAN (statusword, position, torque: 8 bytes). pdo: 0x606C in a second TPDO (or in the one "
        "FD frame).",
    )
    heartbeat_ms: int = Field(
        default=100, ge=0, le=65535, description="Producer heartbeat time written to each drive (0x1017); 0: none."
    )
    heartbeat_timeout_ms: float | None = Field(
        default=None, gt=0.0, description="A drive without a heartbeat for this long is stale; default 3 periods."
    )
    quick_stop_option: int | None = Field(
        default=None, ge=-32768, le=32767, description="0x605A quick stop option code; default: the drive's value."
    )
    on_deactivate: Literal["disable", "hold"] = Field(
        default="disable",
        description="disable: drives go to Switch On Disabled on stop (confirmed). hold: they stay in Operation "
        "Enabled at their last target.",
    )
    brakes: bool = Field(
        default=False,
        description="The motors have holding brakes the drives apply themselves when they leave Operation Enabled "
        "(CiA 402 brake control): disabling never drops the arm, so hild check does not ask for stop_descent "
        "(which a CSP/CSV drive cannot follow: it holds whatever position it is sent).",
    )

    @property
    def heartbeat_timeout(self) -> float:
        """Seconds; 0 when the drives produce no heartbeat."""
        if self.heartbeat_timeout_ms is not None:
            return self.heartbeat_timeout_ms / 1000.0
        return 3.0 * self.heartbeat_ms / 1000.0
