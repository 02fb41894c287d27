"""Message and service definitions rosbags' Jazzy store lacks, as data, each with the release it was copied from.

Only fields matter to CDR and to the RIHS01 hash: comments and constants are left out. A service is written as
its request and response field lists; ``types`` adds the ``_Event`` message and the service struct rosidl
generates (REP-2016). A change here changes the type hash, and a peer with another hash sees nothing: keep each
definition equal to the distro's release named beside it. tests/api/ros2/released/ holds those released files;
test_released.py holds these definitions equal to them, and test_against_rosidl.py their hashes to rosidl's.
"""

from __future__ import annotations

from typing import NamedTuple


class ServiceDefinition(NamedTuple):
    request: str
    response: str
    source: str


class ActionDefinition(NamedTuple):
    """An action's goal, result and feedback; ``types`` derives the SendGoal/GetResult services and the
    FeedbackMessage the way rosidl does."""

    goal: str
    result: str
    feedback: str
    source: str


# controller_manager_msgs, ros2_control 4.46.0, the jazzy branch's newest tag (2026-07-01). Since 4.28.0 (2025-04)
# ControllerState has is_async and update_rate (#2102) and SwitchController's response a message (#2088): with the
# older definitions a current Jazzy `ros2 control` and hild have different hashes and never meet.
CONTROLLER_MANAGER = "ros2_control 4.46.0 (jazzy), controller_manager_msgs"
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
bool is_async
uint16 update_rate
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
    "controller_manager_msgs/msg/HardwareInterface": (
        """
string name
string data_type
bool is_available
bool is_claimed
""",
        CONTROLLER_MANAGER,
    ),
    "controller_manager_msgs/msg/HardwareComponentState": (
        """
string name
string type
bool is_async
uint16 rw_rate
string class_type
string plugin_name
lifecycle_msgs/State state
controller_manager_msgs/HardwareInterface[] command_interfaces
controller_manager_msgs/HardwareInterface[] state_interfaces
""",
        CONTROLLER_MANAGER,
    ),
}

# control_msgs 5.8.0, the jazzy branch's newest tag (these files unchanged since the 4.x of Humble; the indices
# rolling added to FollowJointTrajectory's feedback, #67, are not in jazzy).
CONTROL_MSGS = "control_msgs 5.8.0 (jazzy), control_msgs"
MESSAGES.update(
    {
        "control_msgs/msg/JointTolerance": (
            """
string name
float64 position
float64 velocity
float64 acceleration
""",
            CONTROL_MSGS,
        ),
        "control_msgs/msg/GripperCommand": (
            """
float64 position
float64 max_effort
""",
            CONTROL_MSGS,
        ),
        "control_msgs/msg/JointComponentTolerance": (
            """
string joint_name
uint16 component
float64 position
float64 velocity
float64 acceleration
""",
            CONTROL_MSGS,
        ),
    }
)

ACTIONS: dict[str, ActionDefinition] = {
    "control_msgs/action/FollowJointTrajectory": ActionDefinition(
        goal="""
trajectory_msgs/JointTrajectory trajectory
trajectory_msgs/MultiDOFJointTrajectory multi_dof_trajectory
control_msgs/JointTolerance[] path_tolerance
control_msgs/JointComponentTolerance[] component_path_tolerance
control_msgs/JointTolerance[] goal_tolerance
control_msgs/JointComponentTolerance[] component_goal_tolerance
builtin_interfaces/Duration goal_time_tolerance
""",
        result="""
int32 error_code
string error_string
""",
        feedback="""
std_msgs/Header header
string[] joint_names
trajectory_msgs/JointTrajectoryPoint desired
trajectory_msgs/JointTrajectoryPoint actual
trajectory_msgs/JointTrajectoryPoint error
string[] multi_dof_joint_names
trajectory_msgs/MultiDOFJointTrajectoryPoint multi_dof_desired
trajectory_msgs/MultiDOFJointTrajectoryPoint multi_dof_actual
trajectory_msgs/MultiDOFJointTrajectoryPoint multi_dof_error
""",
        source=CONTROL_MSGS,
    ),
    # parallel_gripper's two actions (hild/api/ros2/gripper_command.py): MoveIt's GripperCommand, and the
    # ParallelGripperCommand ros2_controllers' parallel_gripper_action_controller serves.
    "control_msgs/action/GripperCommand": ActionDefinition(
        goal="control_msgs/GripperCommand command",
        result="float64 position\nfloat64 effort\nbool stalled\nbool reached_goal",
        feedback="float64 position\nfloat64 effort\nbool stalled\nbool reached_goal",
        source=CONTROL_MSGS,
    ),
    "control_msgs/action/ParallelGripperCommand": ActionDefinition(
        goal="sensor_msgs/JointState command",
        result="sensor_msgs/JointState state\nbool stalled\nbool reached_goal",
        feedback="sensor_msgs/JointState state",
        source=CONTROL_MSGS,
    ),
}

SERVICES: dict[str, ServiceDefinition] = {
    # action_msgs, rcl_interfaces 2.0.x (jazzy): every action's cancel service
    "action_msgs/srv/CancelGoal": ServiceDefinition(
        "action_msgs/GoalInfo goal_info",
        "int8 return_code\naction_msgs/GoalInfo[] goals_canceling",
        "rcl_interfaces 2.0.3 (jazzy)",
    ),
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
        "bool ok\nstring message",
        CONTROLLER_MANAGER,
    ),
    # the controller lifecycle and hardware services (hild/api/ros2/lifecycle.py, hardware.py): a name in, ``ok`` out
    **{
        f"controller_manager_msgs/srv/{name}": ServiceDefinition("string name", "bool ok", CONTROLLER_MANAGER)
        for name in ("LoadController", "ConfigureController", "UnloadController", "CleanupController")
    },
    "controller_manager_msgs/srv/ReloadControllerLibraries": ServiceDefinition(
        "bool force_kill", "bool ok", CONTROLLER_MANAGER
    ),
    "controller_manager_msgs/srv/ListControllerTypes": ServiceDefinition(
        "", "string[] types\nstring[] base_classes", CONTROLLER_MANAGER
    ),
    "controller_manager_msgs/srv/ListHardwareComponents": ServiceDefinition(
        "", "controller_manager_msgs/HardwareComponentState[] component", CONTROLLER_MANAGER
    ),
    "controller_manager_msgs/srv/ListHardwareInterfaces": ServiceDefinition(
        "",
        "controller_manager_msgs/HardwareInterface[] command_interfaces\n"
        "controller_manager_msgs/HardwareInterface[] state_interfaces",
        CONTROLLER_MANAGER,
    ),
    "controller_manager_msgs/srv/SetHardwareComponentState": ServiceDefinition(
        "string name\nlifecycle_msgs/State target_state",
        "bool ok\nlifecycle_msgs/State state",
        CONTROLLER_MANAGER,
    ),
}

# rcl_interfaces 2.0.3 (jazzy): the six parameter services every ROS node offers (hild/api/ros2/parameters.py).
# rosbags has their messages (Parameter, ParameterValue, ParameterDescriptor, …), not the services.
RCL_INTERFACES = "rcl_interfaces 2.0.3 (jazzy), rcl_interfaces"
SERVICES.update(
    {
        "rcl_interfaces/srv/ListParameters": ServiceDefinition(
            "string[] prefixes\nuint64 depth", "rcl_interfaces/ListParametersResult result", RCL_INTERFACES
        ),
        "rcl_interfaces/srv/GetParameters": ServiceDefinition(
            "string[] names", "rcl_interfaces/ParameterValue[] values", RCL_INTERFACES
        ),
        "rcl_interfaces/srv/SetParameters": ServiceDefinition(
            "rcl_interfaces/Parameter[] parameters", "rcl_interfaces/SetParametersResult[] results", RCL_INTERFACES
        ),
        "rcl_interfaces/srv/SetParametersAtomically": ServiceDefinition(
            "rcl_interfaces/Parameter[] parameters", "rcl_interfaces/SetParametersResult result", RCL_INTERFACES
        ),
        "rcl_interfaces/srv/DescribeParameters": ServiceDefinition(
            "string[] names", "rcl_interfaces/ParameterDescriptor[] descriptors", RCL_INTERFACES
        ),
        "rcl_interfaces/srv/GetParameterTypes": ServiceDefinition("string[] names", "uint8[] types", RCL_INTERFACES),
    }
)

# SwitchController.strictness values (constants: not part of the hash); 0 means the manager's default.
BEST_EFFORT = 1
STRICT = 2
AUTO = 3
FORCE_AUTO = 4
