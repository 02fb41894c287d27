"""The parts of a URDF the importer reads, as plain dataclasses that remember their lines.

Read here: links (inertial, meshes), joints (type, ``<limit>``, ``<safety_controller>``, ``<mimic>``,
``<dynamics>``), ``<ros2_control>`` blocks (hardware plugin and params, joints with command/state interfaces and
their params, sensors, GPIOs, transmissions inside the block), top-level ``<transmission>`` in the ROS 1 form
(``<type>``, ``<hardwareInterface>``, ``<mechanicalReduction>``) and the ROS 2 form (``<plugin>``,
``<mechanical_reduction>``, ``<offset>``), and ``<gazebo>`` elements. Nothing is interpreted yet: that is
``mapping.py``'s job.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

from hild.importers.ros2_control.report import SourceRef
from hild.importers.ros2_control.xmltree import XmlElement

SourceRefFn = Callable[[XmlElement], SourceRef]

MOVABLE_TYPES = ("revolute", "continuous", "prismatic")
KNOWN_TYPES = (*MOVABLE_TYPES, "fixed", "floating", "planar")


@dataclass(frozen=True)
class Mesh:
    element: XmlElement  # the <mesh> element (its filename is rewritten for the twin)
    filename: str
    collision: bool  # inside <collision>; otherwise <visual>
    where: SourceRef


@dataclass(frozen=True)
class Inertia:
    """An ``<inertia>`` element: the tensor in the link's inertial frame."""

    where: SourceRef
    ixx: float
    ixy: float
    ixz: float
    iyy: float
    iyz: float
    izz: float


@dataclass(frozen=True)
class Link:
    name: str
    where: SourceRef
    mass: float | None  # None: no <inertial>
    meshes: tuple[Mesh, ...]
    collision: bool = False  # has <collision> geometry (what the twin collides)
    inertia: Inertia | None = None


@dataclass(frozen=True)
class Limit:
    where: SourceRef
    lower: float | None
    upper: float | None
    velocity: float | None
    effort: float | None


@dataclass(frozen=True)
class SafetyController:
    where: SourceRef
    soft_lower: float | None
    soft_upper: float | None
    k_position: float | None
    k_velocity: float | None


@dataclass(frozen=True)
class Mimic:
    where: SourceRef
    joint: str
    multiplier: float
    offset: float


@dataclass(frozen=True)
class Joint:
    name: str
    type: str
    parent: str
    child: str
    where: SourceRef
    limit: Limit | None
    safety: SafetyController | None
    mimic: Mimic | None
    dynamics: SourceRef | None  # where <dynamics> is, when present

    @property
    def movable(self) -> bool:
        return self.type in MOVABLE_TYPES


@dataclass(frozen=True)
class Interface:
    name: str
    where: SourceRef
    params: dict[str, str]  # <param name=...> and the min/max/initial_value attributes of older files
    param_where: dict[str, SourceRef]

    def where_of(self, param: str) -> SourceRef:
        return self.param_where.get(param, self.where)


@dataclass(frozen=True)
class HardwareJoint:
    name: str
    where: SourceRef
    command_interfaces: tuple[Interface, ...]
    state_interfaces: tuple[Interface, ...]
    params: dict[str, str]
    mimic: bool  # <joint mimic="true"> inside <ros2_control>
    param_where: dict[str, SourceRef] = field(default_factory=dict)


@dataclass(frozen=True)
class TransmissionEnd:
    """One ``<joint>`` or ``<actuator>`` of a transmission, with what it says about reduction and offset."""

    name: str
    where: SourceRef
    reduction: float | None
    reduction_where: SourceRef | None
    offset: float | None
    hardware_interfaces: tuple[str, ...]


@dataclass(frozen=True)
class Transmission:
    name: str
    where: SourceRef
    kind: str  # the <type> (ROS 1) or <plugin> (ROS 2) text
    form: str  # "ROS 1" or "ROS 2"
    joints: tuple[TransmissionEnd, ...]
    actuators: tuple[TransmissionEnd, ...]


@dataclass(frozen=True)
class HardwareSensor:
    """A ``<sensor>`` of a ``<ros2_control>`` block: state interfaces only (``force.x`` …) and its params."""

    name: str
    where: SourceRef
    state_interfaces: tuple[Interface, ...]
    params: dict[str, tuple[str, SourceRef]]


@dataclass(frozen=True)
class Ros2Control:
    name: str
    type: str
    where: SourceRef
    plugin: str | None
    plugin_where: SourceRef
    params: dict[str, tuple[str, SourceRef]]
    joints: tuple[HardwareJoint, ...]
    others: tuple[tuple[str, str, SourceRef], ...]  # (tag, name, where) of <gpio>, ...
    sensors: tuple[HardwareSensor, ...] = ()


@dataclass(frozen=True)
class GazeboElement:
    where: SourceRef
    reference: str | None
    plugin: str | None  # filename or name of a <plugin>
    parameters: str | None  # <parameters> of a ros2_control plugin


@dataclass
class Robot:
    name: str
    where: SourceRef
    links: dict[str, Link] = field(default_factory=dict)
    joints: dict[str, Joint] = field(default_factory=dict)
    ros2_control: list[Ros2Control] = field(default_factory=list)
    transmissions: list[Transmission] = field(default_factory=list)
    gazebo: list[GazeboElement] = field(default_factory=list)


def parse_robot(root: XmlElement, file: str) -> Robot:
    """Read a parsed URDF; a missing required attribute or a bad number raises ImportFailure with its line."""

    def ref(element: XmlElement) -> SourceRef:
        return SourceRef(file, element.line)

    if root.tag != "robot":
        raise ref(root).fail(f"expected a <robot> root element, found <{root.tag}>")
    robot = Robot(name=root.attrib.get("name", ""), where=ref(root))
    for element in root.elements():
        if element.tag == "link":
            link = _link(element, ref)
            if link.name in robot.links:
                raise ref(element).fail(f"link {link.name!r} is defined twice")
            robot.links[link.name] = link
        elif element.tag == "joint":
            joint = _joint(element, ref)
            if joint.name in robot.joints:
                raise ref(element).fail(f"joint {joint.name!r} is defined twice")
            robot.joints[joint.name] = joint
        elif element.tag == "ros2_control":
            robot.ros2_control.append(_ros2_control(element, ref))
            robot.transmissions.extend(_transmission(t, ref) for t in element.elements("transmission"))
        elif element.tag == "transmission":
            robot.transmissions.append(_transmission(element, ref))
        elif element.tag == "gazebo":
            robot.gazebo.append(_gazebo(element, ref))
    return robot


def _required(element: XmlElement, name: str, ref: SourceRefFn) -> str:
    value = element.attrib.get(name)
    if value is None or not value.strip():
        raise ref(element).fail(f"<{element.tag}> needs a {name!r} attribute")
    return value.strip()


def _number(element: XmlElement, name: str, ref: SourceRefFn, text: str | None = None) -> float | None:
    raw = element.attrib.get(name) if text is None else text
    if raw is None or not raw.strip():
        return None
    try:
        value = float(raw)
    except ValueError:
        raise ref(element).fail(f"<{element.tag}> {name}={raw!r} is not a number") from None
    if not math.isfinite(value):
        raise ref(element).fail(f"<{element.tag}> {name}={raw!r} is not a finite number")
    return value


def _link(element: XmlElement, ref: SourceRefFn) -> Link:
    name = _required(element, "name", ref)
    inertial = element.find("inertial")
    mass: float | None = None
    inertia: Inertia | None = None
    if inertial is not None:
        mass_element = inertial.find("mass")
        mass = 0.0 if mass_element is None else (_number(mass_element, "value", ref) or 0.0)
        tensor = inertial.find("inertia")
        if tensor is not None:
            keys = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
            inertia = Inertia(ref(tensor), *(_number(tensor, key, ref) or 0.0 for key in keys))
    meshes = []
    for kind in ("visual", "collision"):
        for geometry_owner in element.elements(kind):
            geometry = geometry_owner.find("geometry")
            mesh = geometry.find("mesh") if geometry is not None else None
            if mesh is not None:
                filename = _required(mesh, "filename", ref)
                meshes.append(Mesh(mesh, filename, kind == "collision", ref(mesh)))
    collision = any(c.find("geometry") is not None for c in element.elements("collision"))
    return Link(name, ref(element), mass, tuple(meshes), collision, inertia)


def _joint(element: XmlElement, ref: SourceRefFn) -> Joint:
    name = _required(element, "name", ref)
    kind = _required(element, "type", ref)
    if kind not in KNOWN_TYPES:
        raise ref(element).fail(f"joint {name!r} has an unknown type {kind!r} (URDF knows {', '.join(KNOWN_TYPES)})")
    parent, child = element.find("parent"), element.find("child")
    if parent is None or child is None:
        raise ref(element).fail(f"joint {name!r} needs <parent link=...> and <child link=...>")
    limit_element = element.find("limit")
    limit = None
    if limit_element is not None:
        limit = Limit(
            ref(limit_element),
            *(_number(limit_element, key, ref) for key in ("lower", "upper", "velocity", "effort")),
        )
    safety_element = element.find("safety_controller")
    safety = None
    if safety_element is not None:
        safety = SafetyController(
            ref(safety_element),
            *(
                _number(safety_element, key, ref)
                for key in ("soft_lower_limit", "soft_upper_limit", "k_position", "k_velocity")
            ),
        )
    mimic_element = element.find("mimic")
    mimic = None
    if mimic_element is not None:
        multiplier = _number(mimic_element, "multiplier", ref)
        offset = _number(mimic_element, "offset", ref)
        mimic = Mimic(
            ref(mimic_element),
            _required(mimic_element, "joint", ref),
            1.0 if multiplier is None else multiplier,
            0.0 if offset is None else offset,
        )
    dynamics = element.find("dynamics")
    return Joint(
        name,
        kind,
        _required(parent, "link", ref),
        _required(child, "link", ref),
        ref(element),
        limit,
        safety,
        mimic,
        ref(dynamics) if dynamics is not None else None,
    )


def _params(element: XmlElement, ref: SourceRefFn) -> dict[str, tuple[str, SourceRef]]:
    return {_required(p, "name", ref): (p.text, ref(p)) for p in element.elements("param")}


def _interface(element: XmlElement, ref: SourceRefFn) -> Interface:
    found = _params(element, ref)
    params = {name: value for name, (value, _) in found.items()}
    for key in ("min", "max", "initial_value"):  # older files give these as attributes
        if key in element.attrib:
            params.setdefault(key, element.attrib[key])
    where = {name: line for name, (_, line) in found.items()}
    return Interface(_required(element, "name", ref), ref(element), params, where)


def _ros2_control(element: XmlElement, ref: SourceRefFn) -> Ros2Control:
    hardware = element.find("hardware")
    plugin_element = hardware.find("plugin") if hardware is not None else None
    if plugin_element is None:  # Foxy-era files: <hardware><classType>
        plugin_element = hardware.find("classType") if hardware is not None else None
    joints = []
    others = []
    sensors: list[HardwareSensor] = []
    for child in element.elements():
        if child.tag == "joint":
            params = _params(child, ref)
            joints.append(
                HardwareJoint(
                    _required(child, "name", ref),
                    ref(child),
                    tuple(_interface(i, ref) for i in child.elements("command_interface")),
                    tuple(_interface(i, ref) for i in child.elements("state_interface")),
                    {name: value for name, (value, _) in params.items()},
                    child.attrib.get("mimic", "false").strip().lower() == "true",
                    {name: where for name, (_, where) in params.items()},
                )
            )
        elif child.tag == "sensor":
            sensors.append(
                HardwareSensor(
                    _required(child, "name", ref),
                    ref(child),
                    tuple(_interface(i, ref) for i in child.elements("state_interface")),
                    _params(child, ref),
                )
            )
        elif child.tag not in ("hardware", "transmission"):
            others.append((child.tag, child.attrib.get("name", ""), ref(child)))
    return Ros2Control(
        name=element.attrib.get("name", ""),
        type=element.attrib.get("type", "system"),
        where=ref(element),
        plugin=plugin_element.text if plugin_element is not None and plugin_element.text else None,
        plugin_where=ref(plugin_element if plugin_element is not None else (hardware or element)),
        params=_params(hardware, ref) if hardware is not None else {},
        joints=tuple(joints),
        others=tuple(others),
        sensors=tuple(sensors),
    )


def _transmission_end(element: XmlElement, ref: SourceRefFn) -> TransmissionEnd:
    reduction = offset = None
    reduction_where = None
    for tag in ("mechanical_reduction", "mechanicalReduction"):
        found = element.find(tag)
        if found is not None:
            reduction, reduction_where = _number(found, "value", ref, found.text), ref(found)
    for tag in ("offset", "jointOffset"):
        found = element.find(tag)
        if found is not None:
            offset = _number(found, "value", ref, found.text)
    interfaces = tuple(h.text for h in element.elements("hardwareInterface") if h.text)
    return TransmissionEnd(
        _required(element, "name", ref), ref(element), reduction, reduction_where, offset, interfaces
    )


def _transmission(element: XmlElement, ref: SourceRefFn) -> Transmission:
    plugin = element.find("plugin")
    named_by = plugin if plugin is not None else element.find("type")
    form = "ROS 2" if plugin is not None else "ROS 1"
    text = named_by.text if named_by is not None else ""
    return Transmission(
        name=element.attrib.get("name", ""),
        where=ref(element),
        kind=text,
        form=form,
        joints=tuple(_transmission_end(j, ref) for j in element.elements("joint")),
        actuators=tuple(_transmission_end(a, ref) for a in element.elements("actuator")),
    )


def _gazebo(element: XmlElement, ref: SourceRefFn) -> GazeboElement:
    plugin = element.find("plugin")
    parameters = plugin.find("parameters") if plugin is not None else None
    return GazeboElement(
        ref(element),
        element.attrib.get("reference"),
        (plugin.attrib.get("filename") or plugin.attrib.get("name")) if plugin is not None else None,
        parameters.text if parameters is not None else None,
    )
