"""MoveIt 2 for hild's arm6 twin, on a machine with ROS 2 Jazzy and rmw_zenoh_cpp (docs/ros2.md, "MoveIt against the
arm6 twin"): move_group, robot_state_publisher (TF for rviz) and rviz2, on the wall clock as the twin runs.

hild is the ros2_control side: it publishes /joint_states and runs the trajectories through its joint_trajectory
controller's follow_joint_trajectory action (config/moveit_controllers.yaml). Nothing here simulates the arm.
"""

from launch import LaunchDescription
from launch_ros.actions import Node
from moveit_configs_utils import MoveItConfigsBuilder

WALL_CLOCK = {"use_sim_time": False}  # hild stamps with the wall clock and publishes no /clock


def generate_launch_description() -> LaunchDescription:
    config = (
        MoveItConfigsBuilder("arm6", package_name="arm6_moveit_config")
        .robot_description(file_path="config/arm6.urdf")
        .robot_description_semantic(file_path="config/arm6.srdf")
        .robot_description_kinematics(file_path="config/kinematics.yaml")
        .joint_limits(file_path="config/joint_limits.yaml")
        .trajectory_execution(file_path="config/moveit_controllers.yaml")
        .planning_pipelines(pipelines=["ompl"])
        .to_moveit_configs()
    )
    move_group = Node(
        package="moveit_ros_move_group",
        executable="move_group",
        output="screen",
        parameters=[config.to_dict(), WALL_CLOCK],
    )
    state_publisher = Node(
        package="robot_state_publisher",
        executable="robot_state_publisher",
        output="log",
        parameters=[config.robot_description, WALL_CLOCK],
    )
    rviz = Node(
        package="rviz2",
        executable="rviz2",
        output="log",
        arguments=["-d", str(config.package_path / "config/moveit.rviz")],
        parameters=[
            config.robot_description,
            config.robot_description_semantic,
            config.robot_description_kinematics,
            config.planning_pipelines,
            config.joint_limits,
            WALL_CLOCK,
        ],
    )
    return LaunchDescription([move_group, state_publisher, rviz])
