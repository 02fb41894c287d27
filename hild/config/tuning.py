"""The daemon's own parameters, beside its controllers': what an operator tunes on the robot while it runs.

They are the parameters of the node ros2_control users know as ``controller_manager`` (``hild ctl param list
controller_manager``): the cycle's ``update_rate`` (read-only: fixed by the config); each joint's hold gains
(ramped in by the supervisor, so a held joint's torque never steps) and soft-limit margin (only ever wider than the
config's, and refused while the joint or its target is outside the range it would leave); and a scale of every
joint's velocity limit for commands (at most 1). Nothing a client sends raises a position, velocity or effort
limit above the config's.
"""

from __future__ import annotations

from typing import Any

from hild.config.model import Gains
from hild.config.params import Field, Params, dynamic

MANAGER = "controller_manager"  # the node name; a controller may not take it


class JointTuning(Params):
    hold: Gains = dynamic(description="Gains while the joint is held (no controller commands it); ramped in.")
    soft_margin: float = dynamic(
        ge=0.0, description="rad inside the hard position limits commands are kept; never less than the config's."
    )


class ManagerParams(Params):
    update_rate: float = Field(description="Hz of the cycle; fixed by the config while the robot runs.")
    velocity_scale: float = dynamic(
        default=1.0, gt=0.0, le=1.0, description="Of every joint's velocity limit, for commands (slew, velocity)."
    )
    joints: dict[str, JointTuning] = Field(description="Per joint, by name.")

    @classmethod
    def of(cls, config: Any) -> ManagerParams:
        """As the config sets them."""
        return cls(
            update_rate=config.update_rate,
            joints={
                name: JointTuning(hold=joint.hold, soft_margin=joint.limits.soft_margin)
                for name, joint in config.joints.items()
            },
        )
