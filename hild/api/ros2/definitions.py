"""Message and service definitions rosbags' Jazzy store lacks, as data, each with the release it was copied from.

Only fields matter to CDR and to the RIHS01 hash: comments and constants are left out. A service is written as
its request and response field lists; ``types`` adds the ``_Event`` message and the service struct rosidl
generates (REP-2016). A change here changes the type hash, and a peer with another hash sees nothing: keep each
definition equal to the distro's release named beside it.
"""

from __future__ import annotations

from typing import NamedTuple


class ServiceDefinition(NamedTuple):
    request: str
    response: str
    source: str


# controller_manager_msgs, ros2_control 4.20.0 (jazzy branch; ControllerState as of 4.13.0, #1021).
CONTROLLER_MANAGER = "ros2_control 4.20.0 (jazzy), controller_manager_msgs"
MESSAGES: dict[str, tuple[str, str]] = {
    "controller_manager_msgs/msg/ChainConnection": (
        """
string name
string[] reference_interfaces
""",
        CONTROLLER_MANAGER,
    ),
    "controller_manager_msgs/msg/ControllerState": (
        """
string name
string state
string type
string[] claimed_interfaces
string[] required_command_interfaces
string[] required_state_interfaces
bool is_chainable
bool is_chained
string[] exported_state_interfaces
string[] reference_interfaces
controller_manager_msgs/ChainConnection[] chain_connections
""",
        CONTROLLER_MANAGER,
    ),
}

SERVICES: dict[str, ServiceDefinition] = {
    "controller_manager_msgs/srv/ListControllers": ServiceDefinition(
        "", "controller_manager_msgs/ControllerState[] controller", CONTROLLER_MANAGER
    ),
    "controller_manager_msgs/srv/SwitchController": ServiceDefinition(
        """
string[] activate_controllers
string[] deactivate_controllers
int32 strictness
bool activate_asap
builtin_interfaces/Duration timeout
""",
        "bool ok",
        CONTROLLER_MANAGER,
    ),
}

# SwitchController.strictness values (constants: not part of the hash).
BEST_EFFORT = 1
STRICT = 2
