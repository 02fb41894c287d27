"""The URDF the MuJoCo twin loads: the (expanded) source with mesh paths made absolute and a ``<mujoco>`` element.

MuJoCo reads URDF itself and keeps joint names, ``<limit>`` (range; ``effort`` becomes the torque limit the twin
saturates to), ``<dynamics>`` (damping, friction) and ``<mimic>`` (a joint equality). It ignores
``<ros2_control>``, ``<transmission>`` and ``<gazebo>``, so those stay in the copy and its lines match the
source. What it cannot do is resolve ``package://``; it needs mass on every moving body; and it refuses a body
whose principal moments of inertia break the triangle inequality A + B ≥ C (no rigid body has them; a typo or a
tensor exported in the wrong frame does). All three are handled here, before MuJoCo sees the file: the last by
MuJoCo's own ``balanceinertia`` (each moment of such a body becomes their mean), reported per link — or, when the
URDF itself forbids balancing, refused at the ``<inertia>`` line.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hild.importers.ros2_control.packages import PackageRoots
from hild.importers.ros2_control.report import Report, SourceRef
from hild.importers.ros2_control.urdf import Inertia, Robot
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
    _balance_inertias(robot, compiler, report)
    keep_visuals = compiler.attrib.get("discardvisual", "true").strip().lower() == "false"
    _unique_geom_names(document.root, robot.where.file, keep_visuals, report)
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


def _unique_geom_names(root: XmlElement, label: str, keep_visuals: bool, report: Report) -> None:
    """Geom names MuJoCo would see twice, made unique in the twin's copy. Its URDF loader names MuJoCo geoms after
    ``<collision>`` (and kept ``<visual>``) elements, prints "WARNING: Geom with duplicate name … creating an
    unnamed geom" to stderr for each repeat — on every load, during the import and at each start of the twin — and
    leaves the repeat unnamed. hild uses no geom names: the first keeps its name, a repeat becomes
    ``<link>_<name>``, and the report says so once per name."""
    tags = ("collision", "visual") if keep_visuals else ("collision",)
    named = [
        (link.attrib.get("name", ""), element)
        for link in root.elements("link")
        for element in link.elements()
        if element.tag in tags and element.attrib.get("name", "")
    ]
    taken = {element.attrib["name"] for _, element in named}
    first: set[str] = set()
    renamed: dict[str, list[tuple[XmlElement, str]]] = {}
    for link, element in named:
        name = element.attrib["name"]
        if name not in first:
            first.add(name)
            continue
        new, k = f"{link}_{name}", 2
        while new in taken:
            new, k = f"{link}_{name}_{k}", k + 1
        taken.add(new)
        element.attrib["name"] = new
        renamed.setdefault(name, []).append((element, new))
    for name, repeats in renamed.items():
        element = repeats[0][0]
        report.approximated(
            SourceRef(label, element.line),
            f"geom name {name!r} is given to {len(repeats) + 1} <{'/'.join(tags)}> elements: MuJoCo's URDF loader "
            f'would print "WARNING: Geom with duplicate name {name!r} encountered in URDF, creating an unnamed '
            f"geom\" for each repeat; the twin's URDF names the repeats {', '.join(new for _, new in repeats)} "
            "instead (nothing in hild uses geom names)",
        )


def principal_moments(inertia: Inertia) -> tuple[float, float, float]:
    """The tensor's eigenvalues, ascending: what MuJoCo checks (it diagonalizes a URDF's full inertia)."""
    i = inertia
    tensor = np.array([[i.ixx, i.ixy, i.ixz], [i.ixy, i.iyy, i.iyz], [i.ixz, i.iyz, i.izz]])
    a, b, c = np.linalg.eigvalsh(tensor)
    return float(a), float(b), float(c)


def _balance_inertias(robot: Robot, compiler: XmlElement, report: Report) -> None:
    """Links whose inertia MuJoCo refuses: balanced by MuJoCo (one finding each), or refused if the URDF says so."""
    allowed = compiler.attrib.get("balanceinertia", "").strip().lower() != "false"
    balanced = False
    for link in robot.links.values():
        if link.inertia is None or not link.mass:
            continue
        a, b, c = principal_moments(link.inertia)
        if a < 0.0:
            raise link.inertia.where.fail(
                f"link {link.name!r}: principal moments of inertia {a:.4g}, {b:.4g}, {c:.4g}: a negative one is no "
                "rigid body's; fix the <inertia>"
            )
        if a + b >= c:
            continue
        moments = f"principal moments of inertia {a:.4g}, {b:.4g}, {c:.4g} break A + B ≥ C, which MuJoCo refuses"
        if not allowed:
            raise link.inertia.where.fail(
                f'link {link.name!r}: {moments} (this URDF sets <compiler balanceinertia="false">): fix the <inertia>'
            )
        report.approximated(
            link.inertia.where,
            f"link {link.name!r}: {moments}: the twin balances them (each becomes their mean, {(a + b + c) / 3:.4g})",
        )
        balanced = True
    if balanced and "balanceinertia" not in compiler.attrib:
        compiler.attrib["balanceinertia"] = "true"


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
