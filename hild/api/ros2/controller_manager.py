"""``/controller_manager/list_controllers`` and ``switch_controller`` (controller_manager_msgs), answered by hild's
services layer: ``list_controllers`` from the same reply the JSON API gives, ``switch_controller`` as the JSON
request it is, through ``Services.handle`` (the same checks, the same cycle hop, the same refusals).
"""

from __future__ import annotations

import json
from typing import Any

from hild.api.ros2 import types
from hild.api.ros2.definitions import STRICT
from hild.api.ros2.node import RosNode
from hild.api.services import Services

LIST_CONTROLLERS = "controller_manager_msgs/srv/ListControllers"
SWITCH_CONTROLLER = "controller_manager_msgs/srv/SwitchController"
# hild controller type → the ros2_control plugin a ROS tool expects to see
PLUGIN_NAMES = {
    "joint_state_broadcaster": "joint_state_broadcaster/JointStateBroadcaster",
    "forward_command": "forward_command_controller/ForwardCommandController",
    "joint_trajectory": "joint_trajectory_controller/JointTrajectoryController",
}


class ControllerManager:
    """The two services, declared under the node's name as ros2_control's controller manager has them."""

    def __init__(self, face: RosNode, services: Services, node: str) -> None:
        self.face = face
        self.services = services
        self.switch_name = face.name(f"{node}/switch_controller")
        face.declare_service(f"{node}/list_controllers", LIST_CONTROLLERS, self._list_controllers)
        face.declare_service(f"{node}/switch_controller", SWITCH_CONTROLLER, self._switch_controller)

    async def _list_controllers(self, request: Any) -> Any:
        body = self.services.read("list_controllers", b"")
        reply = json.loads(body)
        states = []
        for c in reply.get("controllers", []):
            claimed = list(c.get("claimed", []))
            states.append(
                types.message(
                    "controller_manager_msgs/msg/ControllerState",
                    name=c["name"],
                    state="active" if c["state"] == "active" else "inactive",
                    type=PLUGIN_NAMES.get(c["type"], f"hild/{c['type']}"),
                    claimed_interfaces=claimed,
                    required_command_interfaces=claimed,
                    required_state_interfaces=[],
                    is_chainable=False,
                    is_chained=False,
                    exported_state_interfaces=[],
                    reference_interfaces=[],
                    chain_connections=[],
                )
            )
        return types.message(f"{LIST_CONTROLLERS}_Response", controller=states)

    async def _switch_controller(self, request: Any) -> Any:
        """ros2_control's request as hild's JSON request, through ``Services.handle``: the same validation."""
        body = {
            "activate": list(request.activate_controllers),
            "deactivate": list(request.deactivate_controllers),
            "strict": request.strictness == STRICT,
        }
        reply = await self.services.handle("switch_controllers", json.dumps(body).encode())
        ok = bool(reply.get("ok"))
        if not ok:
            self.face.refused(self.switch_name, str(reply.get("error")))
        return types.message(f"{SWITCH_CONTROLLER}_Response", ok=ok)
