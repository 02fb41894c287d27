"""The controller manager's own parameters on ``/controller_manager``: ``update_rate``, and what the spawner and
``ros2 control load_controller`` set before a load.

ros2_control 4.46's spawner sets ``<c>.params_file`` (absolute paths), ``<c>.type`` and ``<c>.fallback_controllers``
on the manager, one ``set_parameters`` call each, then calls ``load_controller {name}``, which reads them
(controller_manager.cpp: ``load_controller(name)``). hild keeps them per controller in :class:`PendingLoads`; the
load service (``hild.api.ros2.lifecycle``) reads them. ros2_control keeps them as the manager's parameters after the
load; so does hild (a later load of the same name uses them again unless they are set anew).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from hild.api.ros2.parameters import Entry

LOAD_KEYS = ("type", "params_file", "fallback_controllers")
DESCRIPTIONS = {
    "type": "the controller's type for its next load_controller: a ros2_control plugin name list_controller_types "
    "lists, or a hild type",
    "params_file": "absolute paths of ROS parameter files on the robot PC; load_controller reads the controller's "
    "section (<controller>: {ros__parameters: {...}}) as its hild params",
    "fallback_controllers": "controllers activated when this one fails, given to its next load_controller",
}
UPDATE_RATE = "Hz: the cycle's rate, the config's update_rate; read-only (fixed while the daemon runs)"
WHAT_IS_KEPT = (
    "the controller manager has update_rate (read-only) and, per controller to load, <controller>.type, "
    "<controller>.params_file and <controller>.fallback_controllers"
)


@dataclass
class PendingLoads:
    """``<controller>.<key>`` values set on the manager, by controller name: what its next load uses."""

    values: dict[str, dict[str, Any]] = field(default_factory=dict)

    def of(self, controller: str) -> dict[str, Any]:
        return dict(self.values.get(controller, {}))


def checked(name: str, value: Any) -> tuple[str, str, Any]:
    """``(controller, key, value)`` of a parameter the manager takes; ValueError (the reason) otherwise."""
    if name == "update_rate":
        raise ValueError(
            "update_rate is read-only: it is the cycle's rate, the config's update_rate, fixed while the daemon runs"
        )
    controller, dot, key = name.rpartition(".")
    if key == "node_options_args" and controller:
        raise ValueError(
            f"{name}: hild's controllers are not ROS nodes with arguments of their own: --controller-ros-args "
            "(remappings, …) cannot apply"
        )
    if not dot or not controller or key not in LOAD_KEYS:
        raise ValueError(f"{name!r}: {WHAT_IS_KEPT}")
    if key == "type":
        if not isinstance(value, str) or not value:
            raise ValueError(f"{name} must be a non-empty string, the controller's type")
        return controller, key, value
    if key == "params_file" and isinstance(value, str):
        value = [value]  # ros2_control takes a string or a string array
    if not isinstance(value, list) or not all(isinstance(item, str) and item for item in value):
        raise ValueError(f"{name} must be a string array")
    if key == "params_file":
        relative = [path for path in value if not path.startswith("/")]
        if relative:
            raise ValueError(f"{name}: {relative[0]!r} is not an absolute path (it is read on the robot PC)")
    return controller, key, list(value)


class ManagerParameters:
    """The store behind ``/controller_manager``'s parameter services."""

    def __init__(self, update_rate: float, pending: PendingLoads) -> None:
        self.update_rate = round(update_rate)
        self.pending = pending

    def entries(self) -> dict[str, Entry]:
        out = {"update_rate": Entry("update_rate", self.update_rate, True, UPDATE_RATE)}
        for controller, values in sorted(self.pending.values.items()):
            for key, value in values.items():
                name = f"{controller}.{key}"
                out[name] = Entry(name, value, False, DESCRIPTIONS[key])
        return out

    async def set(self, values: dict[str, Any]) -> str | None:
        """All checked before any is kept: all or nothing."""
        try:
            accepted = [checked(name, value) for name, value in values.items()]
        except ValueError as exc:
            return str(exc)
        for controller, key, value in accepted:
            self.pending.values.setdefault(controller, {})[key] = value
        return None
