"""ros2_control's hardware services (controller_manager_msgs 4.46.0) from hild's ``list_hardware`` and
``list_interfaces`` JSON services.

What the fields mean here, as ros2_control's controller_manager.cpp fills them: a hild hardware component drives
several joints and runs on the cycle: ``type`` ``system``, ``is_async`` false, ``rw_rate`` the cycle's rate,
``plugin_name`` ``hild/<driver>``. Its command interfaces are those ``list_interfaces`` names for its joints
(``<joint>/<field>``, ``double``): ``is_claimed`` when a controller holds one (the JSON's ``claimed_by``),
``is_available`` while the component is active. Its state interfaces are every joint's ``position``, ``velocity``
and ``effort``, and its sensors' (``<sensor>/force.x``, …: ``list_hardware``'s ``sensors``), available while it is
active or inactive and never claimed (ros2_control claims none). Lifecycle states:
hild's ``unconfigured``, ``inactive`` and ``active`` are ROS's (ids 1, 2, 3); hild's ``fault`` has no ROS state and
is reported as id 0 (unknown) with the label ``fault``.

``set_hardware_component_state`` ``active`` / ``inactive`` → hild's ``set_hardware_state``: inactive, the component
is still read and written every cycle (the supervisor holds its joints: its drives stay enabled), but its command
interfaces are unavailable and the controllers claiming them are deactivated. A faulted component is refused with
how an operator recovers it (``reset``, then ``enable``: reset also releases the e-stop, which a state request must
not do on the side); any other state is refused as not offered.
"""

from __future__ import annotations

import json
from typing import Any

from hild.api.ros2 import types
from hild.api.ros2.node import RosNode
from hild.api.services import Services

PACKAGE = "controller_manager_msgs"
STATE = "lifecycle_msgs/msg/State"
STATE_IDS = {"unconfigured": 1, "inactive": 2, "active": 3}  # lifecycle_msgs/State primary states
ACTIVE, INACTIVE = 3, 2
STATE_FIELDS = ("position", "velocity", "effort")
DATA_TYPE = "double"
UINT16_MAX = 65535


def ros_state(state: str) -> Any:
    return types.message(STATE, id=STATE_IDS.get(state, 0), label=state)


def interface(name: str, available: bool, claimed: bool) -> Any:
    return types.message(
        f"{PACKAGE}/msg/HardwareInterface", name=name, data_type=DATA_TYPE, is_available=available, is_claimed=claimed
    )


def target_of(state: Any) -> str:
    """``active``, ``inactive``, or the label/id asked for: by id, or by label when the id is 0 (ros2controlcli
    sends both; rclcpp_lifecycle's State takes either)."""
    by_id = {ACTIVE: "active", INACTIVE: "inactive"}
    if int(state.id) in by_id:
        return by_id[int(state.id)]
    label = str(state.label).strip().lower()
    return label if int(state.id) == 0 and label else f"{state.label or ''} (id {state.id})".strip()


class HardwareServices:
    """Declared under the manager's node, as ros2_control's are."""

    def __init__(self, face: RosNode, services: Services, node: str, update_rate: float) -> None:
        self.face = face
        self.services = services
        self.rate = min(round(update_rate), UINT16_MAX)
        self.set_name = face.name(f"{node}/set_hardware_component_state")
        for short, kind, serve in (
            ("list_hardware_components", "ListHardwareComponents", self._components),
            ("list_hardware_interfaces", "ListHardwareInterfaces", self._interfaces),
            ("set_hardware_component_state", "SetHardwareComponentState", self._set_state),
        ):
            face.declare_service(f"{node}/{short}", f"{PACKAGE}/srv/{kind}", serve)

    def _read(self, service: str, key: str) -> list[dict[str, Any]]:
        return list(json.loads(self.services.read(service, b"")).get(key, []))

    def _listing(self) -> tuple[list[dict[str, Any]], dict[str, str | None]]:
        """The hardware, and each command interface's claimer (None: free)."""
        claims = {i["name"]: i.get("claimed_by") for i in self._read("list_interfaces", "interfaces")}
        return self._read("list_hardware", "hardware"), claims

    @staticmethod
    def _command_interfaces(hardware: dict[str, Any], claims: dict[str, str | None]) -> list[Any]:
        joints = set(hardware.get("joints", []))
        available = hardware["state"] == "active"
        return [
            interface(name, available, claimer is not None)
            for name, claimer in claims.items()
            if name.rsplit("/", 1)[0] in joints
        ]

    @staticmethod
    def _state_interfaces(hardware: dict[str, Any]) -> list[Any]:
        available = hardware["state"] in ("active", "inactive")  # an inactive component is still read
        joints = [interface(f"{j}/{f}", available, False) for j in hardware.get("joints", []) for f in STATE_FIELDS]
        sensors = [interface(i, available, False) for s in hardware.get("sensors", []) for i in s["state_interfaces"]]
        return joints + sensors

    async def _components(self, request: Any) -> Any:
        hardware, claims = self._listing()
        components = [
            types.message(
                f"{PACKAGE}/msg/HardwareComponentState",
                name=h["name"],
                type="system",
                is_async=False,
                rw_rate=self.rate,
                class_type="",
                plugin_name=f"hild/{h['driver']}",
                state=ros_state(h["state"]),
                command_interfaces=self._command_interfaces(h, claims),
                state_interfaces=self._state_interfaces(h),
            )
            for h in hardware
        ]
        return types.message(f"{PACKAGE}/srv/ListHardwareComponents_Response", component=components)

    async def _interfaces(self, request: Any) -> Any:
        hardware, claims = self._listing()
        return types.message(
            f"{PACKAGE}/srv/ListHardwareInterfaces_Response",
            command_interfaces=[i for h in hardware for i in self._command_interfaces(h, claims)],
            state_interfaces=[i for h in hardware for i in self._state_interfaces(h)],
        )

    async def _set_state(self, request: Any) -> Any:
        name, target = str(request.name), target_of(request.target_state)
        reason: str | None
        if target in ("active", "inactive"):
            reply = await self.services.handle(
                "set_hardware_state", json.dumps({"name": name, "state": target}).encode()
            )
            reason = None if reply.get("ok") else str(reply.get("error"))
        else:
            reason = f"{name} {target}: not a state hild offers (inactive and active only)"
        if reason is not None:
            self.face.refused(self.set_name, reason)
        found = {h["name"]: h for h in self._read("list_hardware", "hardware")}.get(name)
        state = ros_state(found["state"]) if found is not None else types.message(STATE, id=0, label="")
        return types.message(f"{PACKAGE}/srv/SetHardwareComponentState_Response", ok=reason is None, state=state)
