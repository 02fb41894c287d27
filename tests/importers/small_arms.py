"""Small arms the dynamics tests write themselves: a chain of links in a vertical plane, each joint with its own
mass, limits, friction and interfaces, and the controller YAML that goes with it — the way a description package
writes them (a gz_ros2_control system, a JointTrajectoryController with constraints and, for effort, gains)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any


@dataclass(frozen=True)
class Link:
    joint: str
    length: float = 0.4  # m, along the link; its mass sits in the middle
    mass: float = 1.0  # kg
    effort: float = 40.0  # N·m
    velocity: float = 2.0  # rad/s
    friction: float = 0.0  # N·m (URDF <dynamics friction>)
    damping: float = 0.1  # N·m·s/rad
    start: float = 0.0  # rad, the state interface's initial_value
    axis: str = "0 1 0"  # y: the arm swings in the vertical x-z plane; "0 0 1" turns about the vertical


def urdf(name: str, links: list[Link], interface: str) -> str:
    """A URDF: a 0.1 m base on the world, then one revolute joint and one box link per ``links`` entry."""
    parts = [
        '<?xml version="1.0"?>',
        f'<robot name="{name}">',
        '  <link name="world"/>',
        '  <joint name="fixed" type="fixed"><parent link="world"/><child link="base_link"/></joint>',
        '  <link name="base_link">',
        '    <inertial><origin xyz="0 0 0.05"/><mass value="5"/>',
        '      <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>',
        "  </link>",
    ]
    parent, offset = "base_link", 0.1
    for k, link in enumerate(links):
        child = f"link{k + 1}"
        half = link.length / 2
        moment = max(link.mass * link.length**2 / 12, 1e-4)
        parts += [
            f'  <joint name="{link.joint}" type="revolute">',
            f'    <parent link="{parent}"/><child link="{child}"/>',
            f'    <origin xyz="0 0 {offset}"/><axis xyz="{link.axis}"/>',
            f'    <limit lower="-2.6" upper="2.6" effort="{link.effort}" velocity="{link.velocity}"/>',
            f'    <dynamics damping="{link.damping}" friction="{link.friction}"/>',
            "  </joint>",
            f'  <link name="{child}">',
            f'    <inertial><origin xyz="0 0 {half}"/><mass value="{link.mass}"/>',
            f'      <inertia ixx="{moment:.6g}" ixy="0" ixz="0" iyy="{moment:.6g}" iyz="0" izz="1e-4"/></inertial>',
            "  </link>",
        ]
        parent, offset = child, link.length
    parts += ['  <ros2_control name="GazeboSimSystem" type="system">']
    parts += ["    <hardware><plugin>gz_ros2_control/GazeboSimSystem</plugin></hardware>"]
    for link in links:
        parts += [
            f'    <joint name="{link.joint}">',
            f'      <command_interface name="{interface}"/>',
            f'      <state_interface name="position"><param name="initial_value">{link.start}</param>'
            "</state_interface>",
            '      <state_interface name="velocity"/>',
            "    </joint>",
        ]
    parts += ["  </ros2_control>", "</robot>", ""]
    return "\n".join(parts)


def controllers_yaml(
    links: list[Link],
    interfaces: list[str],
    *,
    update_rate: int = 250,
    gains: dict[str, dict[str, float]] | None = None,
    trajectory: float = 0.0,
    goal: float = 0.0,
    goal_time: float = 0.5,
    stopped_velocity: float = 0.01,
) -> str:
    """controller_manager with a JointStateBroadcaster and one JointTrajectoryController over every joint;
    ``trajectory``/``goal``: each joint's path and goal tolerance (0: not given)."""
    joints = [link.joint for link in links]
    lines = [
        "controller_manager:",
        "  ros__parameters:",
        f"    update_rate: {update_rate}",
        "    joint_state_broadcaster:",
        "      type: joint_state_broadcaster/JointStateBroadcaster",
        "    arm_controller:",
        "      type: joint_trajectory_controller/JointTrajectoryController",
        "arm_controller:",
        "  ros__parameters:",
        f"    joints: [{', '.join(joints)}]",
        f"    command_interfaces: [{', '.join(interfaces)}]",
        "    state_interfaces: [position, velocity]",
        "    constraints:",
        f"      goal_time: {goal_time}",
        f"      stopped_velocity_tolerance: {stopped_velocity}",
    ]
    for joint in joints:
        given = {k: v for k, v in (("trajectory", trajectory), ("goal", goal)) if v}
        if given:
            lines.append(f"      {joint}: {{{', '.join(f'{k}: {v}' for k, v in given.items())}}}")
    if gains:
        lines.append("    gains:")
        lines += [f"      {j}: {{{', '.join(f'{k}: {v}' for k, v in g.items())}}}" for j, g in gains.items()]
    return "\n".join(lines) + "\n"


def write_arm(
    directory: Path, name: str, links: list[Link], interface: str, interfaces: list[str], **options: Any
) -> tuple[Path, Path]:
    """``<name>.urdf`` and ``<name>_controllers.yaml`` in ``directory``; their paths."""
    directory.mkdir(parents=True, exist_ok=True)
    description, controllers = directory / f"{name}.urdf", directory / f"{name}_controllers.yaml"
    description.write_text(urdf(name, links, interface))
    controllers.write_text(controllers_yaml(links, interfaces, **options))
    return description, controllers
