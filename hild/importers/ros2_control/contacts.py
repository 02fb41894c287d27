"""Which contacts the twin ignores: links of the robot that touch by construction — never the world.

MuJoCo collides the convex hull of every collision mesh. Exported meshes of neighbouring links overlap (the two
sides of a joint sit into each other) and a concave link's hull covers its neighbours, so a twin built from them
fights itself from its first step: a joint jammed by friction, a kick that faults it. ROS simulators and MoveIt
answer this with a list of link pairs never to collide; the twin gets the same (``exclude_contacts``):

* **adjacent links** — the two rigid groups a movable joint connects (links welded by fixed joints are one group)
  — always. MuJoCo's own parent filter skips most of them, but not a joint whose parent is welded to the world:
  the robot's base, exactly where exported meshes overlap;
* **any other pair of robot links penetrating at the twin's start pose**, unless the user keeps them.

The robot is every link a movable joint moves, and the base each such chain stands on (with the links welded
below the URDF's root). Everything else welded to the root is the world — a table, a post — and keeps its
contacts: the arm must stop when it hits them.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from hild.dynamics.inspection import body_contacts
from hild.importers.ros2_control.report import Report
from hild.importers.ros2_control.urdf import Robot

Pair = tuple[str, str]


def excluded_contacts(
    robot: Robot, twin_urdf: Path, start: Mapping[str, float], keep_overlaps: bool, report: Report
) -> list[Pair]:
    """The body pairs the twin must not collide, each reported with its reason; ``start``: the twin's start pose."""
    group = _rigid_groups(robot)
    members: dict[str, list[str]] = {}
    for link in robot.links:
        members.setdefault(group[link], []).append(link)
    part_of_robot = _robot_links(robot)
    solid = {name for name, link in robot.links.items() if link.collision and name in part_of_robot}
    pairs: list[Pair] = []
    for joint in robot.joints.values():
        if not joint.movable or joint.parent not in group or joint.child not in group:
            continue
        joined = [
            (a, b)
            for a in members[group[joint.parent]]
            for b in members[group[joint.child]]
            if a in solid and b in solid
        ]
        if joined:
            pairs += joined
            listed = ", ".join(f"{a}–{b}" for a, b in joined)
            report.approximated(
                joint.where, f"joint {joint.name!r}: the twin ignores contacts between the links it joins: {listed}"
            )
    adjacent = {frozenset(p) for p in pairs}
    for contact in body_contacts(twin_urdf, start):
        pair = (contact.first, contact.second)
        if frozenset(pair) in adjacent or group.get(pair[0], pair[0]) == group.get(pair[1], pair[1]):
            continue
        where = robot.links[pair[1]].where if pair[1] in robot.links else robot.where
        overlap = f"links {pair[0]!r} and {pair[1]!r} overlap by {contact.depth * 1000:.3g} mm at the start pose"
        if not (pair[0] in part_of_robot and pair[1] in part_of_robot):
            report.approximated(where, f"{overlap}: one is not part of the robot, so the twin pushes them apart")
        elif keep_overlaps:
            report.approximated(where, f"{overlap}: contacts kept (--keep-self-contacts); the twin pushes them apart")
        else:
            pairs.append(pair)
            report.approximated(
                where,
                f"{overlap}: the twin ignores their contacts (MuJoCo collides the convex hull of each collision "
                "mesh; --keep-self-contacts keeps them)",
            )
    return pairs


def _rigid_groups(robot: Robot) -> dict[str, str]:
    """Link → a representative of the links welded to it by fixed joints (one MuJoCo weld body)."""
    parent: dict[str, str] = {name: name for name in robot.links}

    def find(link: str) -> str:
        while parent[link] != link:
            link = parent[link]
        return link

    for joint in robot.joints.values():
        if joint.type == "fixed" and joint.parent in parent and joint.child in parent:
            parent[find(joint.child)] = find(joint.parent)
    return {link: find(link) for link in robot.links}


def _robot_links(robot: Robot) -> set[str]:
    """Links a movable joint moves, and the chain of fixed links each moving chain stands on (the base)."""
    children: dict[str, list[str]] = {}
    parent_joint = {}
    for joint in robot.joints.values():
        children.setdefault(joint.parent, []).append(joint.child)
        parent_joint[joint.child] = joint
    moving: set[str] = set()
    stack = [j.child for j in robot.joints.values() if j.movable]
    while stack:
        link = stack.pop()
        if link not in moving:
            moving.add(link)
            stack += children.get(link, [])
    base: set[str] = set()
    for joint in robot.joints.values():
        if joint.movable and joint.parent not in moving:
            link = joint.parent
            base.add(link)
            while (
                link in parent_joint
                and parent_joint[link].type == "fixed"
                and parent_joint[link].parent in parent_joint
            ):
                link = parent_joint[link].parent  # up the fixed chain, stopping below the root
                base.add(link)
    return moving | base
