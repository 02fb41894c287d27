"""The URDF the MuJoCo twin loads: the (expanded) source with mesh paths made absolute and a ``<mujoco>`` element.

MuJoCo reads URDF itself and keeps joint names, ``<limit>`` (range; ``effort`` becomes the torque limit the twin
saturates to), ``<dynamics>`` (damping, friction) and ``<mimic>`` (a joint equality). It ignores
``<ros2_control>``, ``<transmission>`` and ``<gazebo>``, so those stay in the copy and its lines match the
source. What it cannot do is resolve ``package://``; and it needs mass on every moving body. Both are handled
here, before MuJoCo sees the file.
"""

from __future__ import annotations

from pathlib import Path

from hild.importers.ros2_control.packages import PackageRoots
from hild.importers.ros2_control.report import Report, SourceRef
from hild.importers.ros2_control.urdf import Robot
from hild.importers.ros2_control.xmltree import XmlDocument, XmlElement, serialize

MESH_FORMATS = (".stl", ".obj", ".msh")  # what MuJoCo's mesh loader reads
# strippath: keep the directories of mesh paths. fusestatic: keep every link a body (names stay; the viewer
# shows each link). discardvisual: collision geometry only, as ROS simulators do (unless the URDF says otherwise).
COMPILER_DEFAULTS = {"strippath": "false", "fusestatic": "false", "discardvisual": "true"}


def check_inertias(robot: Robot) -> None:
    """Every link a movable joint carries (with what is welded to it) needs mass, or MuJoCo refuses the model.

    Chosen over a default mass: a guessed inertia makes the twin and its gravity feed-forward quietly wrong.
    """
    welded: dict[str, list[str]] = {}
    for joint in robot.joints.values():
        if joint.type == "fixed":
            welded.setdefault(joint.parent, []).append(joint.child)

    def mass(link: str) -> float:
        own = robot.links[link].mass if link in robot.links else None
        return (own or 0.0) + sum(mass(child) for child in welded.get(link, []))

    for joint in robot.joints.values():
        if not joint.movable:
            continue
        if joint.child not in robot.links:
            raise joint.where.fail(f"joint {joint.name!r} names a child link {joint.child!r} that is not defined")
        if mass(joint.child) <= 0.0:
            link = robot.links[joint.child]
            missing = "no <inertial>" if link.mass is None else "zero mass"
            raise link.where.fail(
                f"link {link.name!r} has {missing} but moves with joint {joint.name!r}: the twin (MuJoCo) needs "
                "mass and inertia on every moving link; add <inertial> with <mass> and <inertia>"
            )


def build_twin_urdf(
    document: XmlDocument, robot: Robot, source_dir: Path, packages: PackageRoots, report: Report
) -> str:
    """The twin's URDF text (``document`` is changed in place): mesh paths absolute, MuJoCo compiler options set."""
    compiler = _compiler(document.root, robot.where, report)
    keep_visuals = compiler.attrib.get("discardvisual", "true").strip().lower() == "false"
    resolved: dict[str, tuple[SourceRef, int]] = {}
    for link in robot.links.values():
        for mesh in link.meshes:
            path, problem = packages.resolve_uri(mesh.filename, source_dir)
            if problem is None and path is not None and not path.is_file():
                problem = f"mesh file not found: {path}"
            needed = mesh.collision or keep_visuals
            if problem is not None:
                if needed:
                    raise mesh.where.fail(f"link {link.name!r}: {problem}")
                report.unsupported(
                    mesh.where, f"visual mesh of link {link.name!r} not found ({problem}); the twin discards visuals"
                )
                continue
            assert path is not None
            if needed and path.suffix.lower() not in MESH_FORMATS:
                raise mesh.where.fail(
                    f"link {link.name!r}: MuJoCo reads {', '.join(MESH_FORMATS)} meshes, not {path.suffix!r}: "
                    f"convert {path.name} (e.g. to STL) or give the link primitive collision geometry"
                )
            mesh.element.attrib["filename"] = str(path)
            first, count = resolved.get(str(path.parent), (mesh.where, 0))
            resolved[str(path.parent)] = (first, count + 1)
    for directory, (where, count) in resolved.items():
        report.mapped(where, f"{count} mesh path(s) resolved to {directory} for the twin")
    for package, root in packages.inferred.items():
        report.approximated(robot.where, f"ROS package {package!r} taken to be {root} (no --package-root given)")
    return serialize(document)


def _compiler(root: XmlElement, where: SourceRef, report: Report) -> XmlElement:
    """The ``<mujoco><compiler>`` element, created on the ``<robot>`` line (no line moves) or completed."""
    mujoco = root.find("mujoco")
    if mujoco is None:
        mujoco = XmlElement("mujoco", {}, root.line)
        root.children.insert(0, mujoco)
    compiler = mujoco.find("compiler")
    if compiler is None:
        compiler = XmlElement("compiler", {}, mujoco.line)
        mujoco.children.insert(0, compiler)
    added = {k: v for k, v in COMPILER_DEFAULTS.items() if k not in compiler.attrib}
    compiler.attrib.update(added)
    if added:
        options = " ".join(f'{k}="{v}"' for k, v in added.items())
        report.mapped(where, f"twin URDF: <mujoco><compiler {options}/> added (MuJoCo's URDF extension)")
    return compiler
