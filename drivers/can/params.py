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
