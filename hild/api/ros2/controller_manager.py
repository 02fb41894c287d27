"""``/controller_manager/list_controllers`` and ``switch_controller`` (controller_manager_msgs), answered by hild's
services layer: ``list_controllers`` from the same reply the JSON API gives, ``switch_controller`` as the JSON
request it is, through ``Services.handle`` (the same checks, the same cycle hop, the same refusals).

What ros2_control's fields mean here (its controller_manager.cpp, 4.46.0): ``state`` is ``unconfigured``,
``inactive`` or ``active`` (``ros2 control set_controller_state`` reads it to choose configure or switch);
``claimed_interfaces`` are the command interfaces an active controller holds (none when inactive);
``required_command_interfaces`` what its configuration claims when active, ``required_state_interfaces`` what it
reads, both empty while it is unconfigured, as ros2_control reports them; every hild controller runs on the cycle,
so ``is_async`` is false and ``update_rate`` is the cycle's rate. Chains as ros2_control reports them:
``is_chainable`` for a controller that exports ``reference_interfaces`` (``<controller>/<joint>/<field>``),
``is_chained`` while an active controller claims some of them, and a chained controller's ``chain_connections``
name the controller it chains to and the references it claims (its ``claimed_interfaces`` too).
"""

from __future__ import annotations

import json
from typing import Any

from hild.api.ros2 import types
from hild.api.ros2.definitions import AUTO, BEST_EFFORT, FORCE_AUTO, STRICT
from hild.api.ros2.node import RosNode
from hild.api.services import Services

LIST_CONTROLLERS = "controller_manager_msgs/srv/ListControllers"
SWITCH_CONTROLLER = "controller_manager_msgs/srv/SwitchController"
CONTROLLER_STATE = "controller_manager_msgs/msg/ControllerState"
CHAIN_CONNECTION = "controller_manager_msgs/msg/ChainConnection"
# hild controller type → the ros2_control plugin a ROS tool expects to see
PLUGIN_NAMES = {
    "joint_state_broadcaster": "joint_state_broadcaster/JointStateBroadcaster",
    "forward_command": "forward_command_controller/ForwardCommandController",
    "joint_trajectory": "joint_trajectory_controller/JointTrajectoryController",
    "parallel_gripper": "parallel_gripper_action_controller/GripperActionController",
    "force_torque_sensor_broadcaster": "force_torque_sensor_broadcaster/ForceTorqueSensorBroadcaster",
}
HILD_TYPES = {plugin: kind for kind, plugin in PLUGIN_NAMES.items()}
HILD_PREFIX = "hild/"  # a type without a ros2_control plugin name: hild/<type>
UINT16_MAX = 65535
# strictness → what hild cannot do instead, said in the reply (ros2_control 4.46 itself runs both as BEST_EFFORT,
# with a log line: a client that asked for them would get something else without knowing)
UNSUPPORTED = {
    AUTO: "strictness AUTO (3) is not supported: hild activates no chain by itself (name every controller of a "
    "chain); use STRICT (2) or BEST_EFFORT (1)",
    FORCE_AUTO: "strictness FORCE_AUTO (4) is not supported: hild deactivates only the controllers named in "
    "deactivate_controllers; name the ones holding the joints (list_controllers shows their claimed interfaces)",
}


class ControllerManager:
    """The two services, declared under the node's name as ros2_control's controller manager has them."""

    def __init__(self, face: RosNode, services: Services, node: str, update_rate: float) -> None:
        self.face = face
        self.services = services
        self.update_rate = min(round(update_rate), UINT16_MAX)
        self.switch_name = face.name(f"{node}/switch_controller")
        face.declare_service(f"{node}/list_controllers", LIST_CONTROLLERS, self._list_controllers)
        face.declare_service(f"{node}/switch_controller", SWITCH_CONTROLLER, self._switch_controller)

    async def _list_controllers(self, request: Any) -> Any:
        reply = json.loads(self.services.read("list_controllers", b""))
        states = [self._state(c) for c in reply.get("controllers", [])]
        return types.message(f"{LIST_CONTROLLERS}_Response", controller=states)

    def _state(self, controller: dict[str, Any]) -> Any:
        """One JSON ``list_controllers`` entry as a ControllerState."""
        state = controller["state"] if controller["state"] in ("active", "unconfigured") else "inactive"
        configured = state != "unconfigured"
        claims = list(controller.get("claimed", []))  # hild's JSON lists the claims in every state
        return types.message(
            CONTROLLER_STATE,
            name=controller["name"],
            state=state,
            type=plugin_name(controller["type"]),
            is_async=False,
            update_rate=self.update_rate,
            claimed_interfaces=claims if state == "active" else [],
            required_command_interfaces=claims if configured else [],
            required_state_interfaces=list(controller.get("state_interfaces", [])) if configured else [],
            is_chainable=bool(controller.get("is_chainable", False)),
            is_chained=bool(controller.get("is_chained", False)),
            exported_state_interfaces=[],
            reference_interfaces=list(controller.get("reference_interfaces", [])),
            chain_connections=[
                types.message(CHAIN_CONNECTION, name=c["name"], reference_interfaces=list(c["reference_interfaces"]))
                for c in controller.get("chain_connections", [])
            ],
        )

    async def _switch_controller(self, request: Any) -> Any:
        """ros2_control's request as hild's JSON request, through ``Services.handle``: the same validation.

        ``activate_asap`` needs nothing: a switch applies between two cycles, the first one it can, and hild's
        interfaces have nothing to become ready, so it is as soon as possible either way. ``timeout`` bounds the
        wait for the cycle, capped at the services' own timeout (zero: that timeout, as ros2_control's zero is its
        default of one second)."""
        refusal = switch_refusal(request)
        if refusal is not None:
            return self._reply(False, refusal)
        body = {
            "activate": list(request.activate_controllers),
            "deactivate": list(request.deactivate_controllers),
            "strict": request.strictness == STRICT,
        }
        wait = seconds(request.timeout) or None
        reply = await self.services.handle("switch_controllers", json.dumps(body).encode(), timeout=wait)
        if not reply.get("ok"):
            return self._reply(False, str(reply.get("error")))
        return self._reply(True, switched_message(reply))

    def _reply(self, ok: bool, message: str) -> Any:
        if not ok:
            self.face.refused(self.switch_name, message)
        return types.message(f"{SWITCH_CONTROLLER}_Response", ok=ok, message=message)


def plugin_name(kind: str) -> str:
    """hild's controller type as the ros2_control plugin a ROS tool expects (``hild/<type>`` when there is none)."""
    return PLUGIN_NAMES.get(kind, f"{HILD_PREFIX}{kind}")


def hild_type(plugin: str) -> str:
    """``plugin_name``'s inverse; anything else is taken as a hild type name (hild's load checks it)."""
    return HILD_TYPES.get(plugin, plugin.removeprefix(HILD_PREFIX))


def switch_refusal(request: Any) -> str | None:
    """Why hild cannot do what this SwitchController request asks, or None (0 is ros2_control's default,
    BEST_EFFORT)."""
    if request.strictness in UNSUPPORTED:
        return UNSUPPORTED[request.strictness]
    if request.strictness not in (0, BEST_EFFORT, STRICT):
        return f"unknown strictness {request.strictness} (BEST_EFFORT 1, STRICT 2, AUTO 3, FORCE_AUTO 4)"
    if seconds(request.timeout) < 0:
        return f"timeout must not be negative, not {seconds(request.timeout):g} s"
    return None


def seconds(duration: Any) -> float:
    """A builtin_interfaces/Duration in seconds."""
    return float(duration.sec) + float(duration.nanosec) * 1e-9


def switched_message(reply: dict[str, Any]) -> str:
    """What a switch did, from hild's reply; a best-effort switch's error names what it dropped."""
    names = {key: ", ".join(reply.get(key) or []) or "none" for key in ("activated", "deactivated")}
    message = f"switched controllers: activated {names['activated']}; deactivated {names['deactivated']}"
    return f"{message} ({reply['error']})" if reply.get("error") else message
