"""URDF joints, limits, ``<ros2_control>`` and transmissions → hild joints, the twin's params and the CAN template.

The defaults below are the documented answers (docs/import.md) to what a ros2_control robot does not say but a
hild config needs: acceleration and jerk for planning, finite limits for continuous joints, the twin's physics
step. Hold gains are ``gains``' job, the twin's start pose ``start_pose``'s.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from hild.importers.ros2_control.canopen import CANOPEN_SYSTEM, DRIVE_PLUGINS
from hild.importers.ros2_control.controllers import JointCatalog, Pid
from hild.importers.ros2_control.gains import GainLimits, hold_gains, round4
from hild.importers.ros2_control.inertia import JointInertia
from hild.importers.ros2_control.report import Report, SourceRef
from hild.importers.ros2_control.start_pose import initial_position
from hild.importers.ros2_control.urdf import HardwareJoint, Joint, Robot, Ros2Control
from hild.interfaces import SENSOR_INTERFACES

# Planning limits a URDF does not carry: reach full speed in 0.5 s, but never ask for more than half the effort
# limit to accelerate the joint's own inertia (the other half is left for gravity and the rest of the arm).
ACCELERATION_PER_VELOCITY = 2.0  # 1/s
ACCELERATION_EFFORT_SHARE = 0.5
JERK_PER_ACCELERATION = 10.0  # 1/s: full acceleration in 0.1 s
# The twin runs the drive law once per physics step: in the joint's lightest pose, kd·h/M and √(kp/M)·h stay
# below STEP_MARGIN, which sets the number of substeps (at most MAX_SUBSTEPS; beyond that the gains are lowered).
STEP_MARGIN = 0.5
MAX_SUBSTEPS = 100
CONTINUOUS_RANGE = round(2.0 * math.pi, 4)  # a continuous joint gets ±one turn
PHYSICS_STEP = 0.001  # s: the twin's substeps keep MuJoCo's step at or below this (or smaller, see above)

SIMULATORS = {
    "gazebo_ros2_control/GazeboSystem": "Gazebo Classic",
    "gz_ros2_control/GazeboSimSystem": "Gazebo (gz)",
    "ign_ros2_control/IgnitionSystem": "Ignition Gazebo",
    "mujoco_ros2_control/MujocoSystem": "MuJoCo",
    "mujoco_ros2_control/MujocoSystemInterface": "MuJoCo",
}
MOCKS = ("mock_components/GenericSystem", "fake_components/GenericSystem")
HILD_INTERFACES = ("position", "velocity", "effort")  # and kp/kd: what the hild servo command carries


@dataclass(frozen=True)
class Selected:
    """A joint hild commands, with where ros2_control declares it."""

    joint: Joint
    hardware: HardwareJoint | None
    block: Ros2Control | None


@dataclass
class JointPlan:
    name: str
    where: SourceRef
    lower: float
    upper: float
    soft_margin: float
    velocity: float
    effort: float
    acceleration: float
    jerk: float
    kp: float
    kd: float
    gains_from: str
    initial_position: float | None
    transmission: dict[str, float] | None  # reduction/direction/offset for the CAN template
    transmission_from: SourceRef | None
    block: str
    inertia: JointInertia
    gains_pid: tuple[str, SourceRef] | None = None  # (controller, where) of the user's PID the hold gains come from


@dataclass(frozen=True)
class MimicPlan:
    """A mimic joint of the config (``mimic_joints``): it follows ``joint``, a commanded joint, through any chain."""

    name: str
    joint: str
    multiplier: float
    offset: float
    where: SourceRef  # its <mimic> element


@dataclass(frozen=True)
class SensorPlan:
    """A ``<sensor>`` of ``<ros2_control>`` as a sensor of the twin (``hardware.twin.sensors``)."""

    name: str
    type: str  # force_torque | imu
    frame_id: str
    where: SourceRef


def plan_sensors(robot: Robot, report: Report) -> list[SensorPlan]:
    """Each ``<sensor>`` whose state interfaces are a force/torque sensor's or an IMU's, on the link its
    ``frame_id`` param names (the twin reads it there from MuJoCo's own sensors); others are not supported."""
    plans: list[SensorPlan] = []
    for block in robot.ros2_control:
        for sensor in block.sensors:
            names = {i.name for i in sensor.state_interfaces}
            kind = next((k for k, known in SENSOR_INTERFACES.items() if names and names <= set(known)), None)
            if kind is None:
                report.dropped(
                    sensor.where,
                    f"<sensor> {sensor.name!r}: state interfaces {sorted(names)} are neither a force/torque sensor's "
                    "nor an IMU's (hild reads those two kinds)",
                )
                continue
            frame, frame_where = sensor.params.get("frame_id", (None, sensor.where))
            if frame is None:
                if sensor.name not in robot.links:
                    raise sensor.where.fail(
                        f'<sensor> {sensor.name!r} has no <param name="frame_id">: the twin needs the link it sits on'
                    )
                frame = sensor.name
            if frame not in robot.links:
                raise frame_where.fail(f"<sensor> {sensor.name!r}: frame_id {frame!r} is not a link of the URDF")
            missing = [i for i in SENSOR_INTERFACES[kind] if i not in names]
            text = f"<sensor> {sensor.name!r} → a {kind} sensor of the twin on {frame} (MuJoCo's own sensors there)"
            if missing:
                text += f"; it also offers {', '.join(missing)}"
            report.mapped(sensor.where, text)
            for key, (_, where) in sensor.params.items():
                if key != "frame_id":
                    report.unsupported(where, f"<sensor> {sensor.name!r}: param {key!r} is not used by hild")
            plans.append(SensorPlan(sensor.name, kind, frame, sensor.where))
    return plans


def select_joints(robot: Robot, report: Report) -> list[Selected]:
    """The joints hild will command: those of the ``<ros2_control>`` blocks, in their order."""
    selected: list[Selected] = []
    seen: dict[str, SourceRef] = {}
    for block in robot.ros2_control:
        for tag, name, where in block.others:
            report.unsupported(where, f"<{tag}> {name!r} in <ros2_control> {block.name!r} (hild has joints only)")
        for hw in block.joints:
            joint = robot.joints.get(hw.name)
            if joint is None:
                known = ", ".join(j.name for j in robot.joints.values() if j.movable)
                raise hw.where.fail(f"<ros2_control> joint {hw.name!r} is not a joint of the URDF (joints: {known})")
            if hw.name in seen:
                raise hw.where.fail(f"joint {hw.name!r} is already in <ros2_control> at {seen[hw.name]}")
            seen[hw.name] = hw.where
            if hw.mimic or joint.mimic is not None:
                if joint.mimic is None:  # ros2_control refuses this too: the URDF says whom it follows
                    report.unsupported(
                        hw.where, f'joint {hw.name!r} is mimic="true" but the URDF gives it no <mimic>: not commanded'
                    )
                elif hw.command_interfaces:
                    report.unsupported(
                        hw.command_interfaces[0].where,
                        f"mimic joint {hw.name!r}: command interfaces (ros2_control refuses them on a mimic joint)",
                    )
                continue
            for spec in hw.command_interfaces:
                if spec.name not in HILD_INTERFACES:
                    report.unsupported(
                        spec.where,
                        f"{hw.name}: command interface {spec.name!r} (hild has {', '.join(HILD_INTERFACES)})",
                    )
            if not joint.movable:
                report.dropped(hw.where, f"joint {hw.name!r} is {joint.type}: not a commandable joint")
                continue
            selected.append(Selected(joint, hw, block))
    if robot.ros2_control:
        return selected
    transmitted = {end.name for t in robot.transmissions for end in t.joints}
    candidates = [j for j in robot.joints.values() if j.movable and j.mimic is None]
    chosen = [j for j in candidates if j.name in transmitted] or candidates
    why = "the joints of its <transmission>s" if transmitted else "every movable joint"
    report.approximated(robot.where, f"no <ros2_control> in the URDF: hild commands {why}")
    return [Selected(j, None, None) for j in chosen]


def catalog(robot: Robot, selected: list[Selected], sensors: list[SensorPlan]) -> JointCatalog:
    interfaces = {
        s.joint.name: frozenset(i.name for i in s.hardware.command_interfaces)
        for s in selected
        if s.hardware is not None
    }
    mimic = {j.name: j.mimic.joint for j in robot.joints.values() if j.mimic is not None}
    for block in robot.ros2_control:
        for hw in block.joints:
            if hw.mimic and hw.name not in mimic:
                mimic[hw.name] = "(mimic in <ros2_control>)"
    kinds = {s.name: s.type for s in sensors}
    return JointCatalog(tuple(s.joint.name for s in selected), frozenset(robot.joints), mimic, interfaces, kinds)


def report_hardware(robot: Robot, read: Mapping[str, set[str]], report: Report) -> None:
    """What becomes of each hardware plugin, its params (``read``: those the CAN template took, per block), the
    gazebo plugins and mimic joints."""
    for block in robot.ros2_control:
        plugin = block.plugin
        if plugin in SIMULATORS:
            report.mapped(block.plugin_where, f"{plugin} ({SIMULATORS[plugin]}) → the MuJoCo twin over the same URDF")
        elif plugin in MOCKS:
            report.approximated(
                block.plugin_where,
                f"{plugin} → the MuJoCo twin: it has physics (gravity, inertia), the mock mirrors commands",
            )
        elif plugin is None:
            report.unsupported(
                block.where, f"<ros2_control> {block.name!r} names no hardware plugin; the twin stands in"
            )
        elif plugin in DRIVE_PLUGINS:
            report.mapped(
                block.plugin_where,
                f"{plugin} (ros2_canopen, CiA 402) → the commented cia402 section at the end, from its bus.yml; "
                "the MuJoCo twin stands in until it replaces the twin",
            )
        elif plugin == CANOPEN_SYSTEM:
            report.unsupported(
                block.plugin_where,
                f"{plugin}: ros2_canopen's CiA 301 system (raw PDO/NMT interfaces, no drive profile) has no hild "
                "driver (hild's CANopen driver is cia402): the MuJoCo twin stands in",
            )
        else:
            report.unsupported(
                block.plugin_where,
                f"hardware plugin {plugin} has no hild driver: the MuJoCo twin stands in; fill in the CAN template",
            )
        for name, (value, where) in block.params.items():
            if name not in read.get(block.name, set()):
                report.unsupported(where, f"hardware param {name}={value!r} of {plugin} is not used by the twin")
    for element in robot.gazebo:
        if element.plugin and "ros2_control" in element.plugin:
            extra = (
                f"; its parameters file {element.parameters} is the --controllers input" if element.parameters else ""
            )
            report.mapped(element.where, f"<gazebo> plugin {element.plugin} → the twin runs the controllers{extra}")
        elif element.reference:
            report.unsupported(element.where, f"<gazebo reference={element.reference!r}>: Gazebo-only properties")
        else:
            report.unsupported(element.where, f"<gazebo> {element.plugin or 'element'}: not used by the twin")
    for joint in robot.joints.values():
        if joint.mimic is None and joint.type in ("floating", "planar"):
            report.unsupported(joint.where, f"{joint.type} joint {joint.name!r}: hild drives 1-DoF joints only")


def plan_mimic_joints(robot: Robot, selected: list[Selected], report: Report) -> list[MimicPlan]:
    """URDF ``<mimic>`` joints → the config's ``mimic_joints``: each follows a commanded joint, a chain of mimic
    joints composed into one multiplier and offset. The twin keeps every one coupled (MuJoCo makes a joint
    equality of ``<mimic>``); those that follow a joint hild does not command are left out of joint_states."""
    commanded = {s.joint.name for s in selected}
    plans = []
    for joint in robot.joints.values():
        m = joint.mimic
        if m is None:
            continue
        leader, multiplier, offset, seen = m.joint, m.multiplier, m.offset, {joint.name}
        while leader in robot.joints and robot.joints[leader].mimic is not None and leader not in seen:
            seen.add(leader)
            first = robot.joints[leader].mimic
            assert first is not None
            leader, multiplier, offset = first.joint, multiplier * first.multiplier, multiplier * first.offset + offset
        follows = f"follows {m.joint!r} × {m.multiplier:g} + {m.offset:g}"
        if leader not in commanded:
            report.unsupported(
                m.where,
                f"mimic joint {joint.name!r} ({follows}): {leader!r} is not commanded, so joint_states leaves it "
                "out; the twin keeps it coupled (MuJoCo joint equality)",
            )
            continue
        chain = f", i.e. {leader!r} × {multiplier:g} + {offset:g}" if leader != m.joint else ""
        report.mapped(
            m.where,
            f"mimic joint {joint.name!r} ({follows}{chain}) → mimic_joints: joint_states reports it, the twin "
            "keeps it coupled (MuJoCo joint equality) and starts it where its joint puts it",
        )
        plans.append(MimicPlan(joint.name, leader, multiplier, offset, m.where))
    return plans


def plan_joints(
    robot: Robot,
    selected: list[Selected],
    inertias: Mapping[str, JointInertia],
    effort_pid: Mapping[str, tuple[str, Pid]],
    update_rate: float,
    report: Report,
) -> list[JointPlan]:
    transmissions = _transmissions(robot, {s.joint.name for s in selected}, report)
    plans = []
    for s in selected:
        joint, hw = s.joint, s.hardware
        lower, upper, velocity, effort = _limits(joint, hw, report)
        margin = _soft_margin(joint, lower, upper, report)
        acceleration, jerk = _planning_limits(joint, velocity, effort, inertias[joint.name], report)
        pid = effort_pid.get(joint.name)
        declared = hw.where if hw is not None else joint.where
        limits = GainLimits(velocity, effort, margin, 1.0 / update_rate)
        kp, kd, gains_from = hold_gains(joint.name, joint.where, limits, inertias[joint.name], pid, report)
        reduction = transmissions.get(joint.name)
        plans.append(
            JointPlan(
                name=joint.name,
                where=declared,
                lower=lower,
                upper=upper,
                soft_margin=margin,
                velocity=velocity,
                effort=effort,
                acceleration=acceleration,
                jerk=jerk,
                kp=kp,
                kd=kd,
                gains_from=gains_from,
                initial_position=initial_position(joint.name, declared, hw, lower, upper, report),
                transmission=reduction[0] if reduction else None,
                transmission_from=reduction[1] if reduction else None,
                block=s.block.name if s.block is not None else "",
                inertia=inertias[joint.name],
                gains_pid=(pid[0], pid[1].where) if pid is not None else None,
            )
        )
    return plans


def check_limits(selected: list[Selected]) -> None:
    """Raise on a joint whose limits hild cannot use, before the twin's model is built from them."""
    for s in selected:
        _limits(s.joint, s.hardware, Report())


def position_ranges(robot: Robot, selected: list[Selected]) -> dict[str, tuple[float, float]]:
    """Where each joint can go (for sampling poses): its URDF limits, ±1 turn for a continuous joint."""
    out = {}
    for s in selected:
        limit = s.joint.limit
        if s.joint.type == "continuous" or limit is None or limit.lower is None or limit.upper is None:
            out[s.joint.name] = (-math.pi, math.pi)
        else:
            out[s.joint.name] = (limit.lower, limit.upper)
    return out


def choose_substeps(plans: list[JointPlan], update_rate: float, report: Report) -> int:
    """Physics steps per cycle: a step of at most PHYSICS_STEP that keeps every joint's drive law stable.

    A joint whose gains would need more than MAX_SUBSTEPS gets its gains lowered to what that step allows.
    """
    period = 1.0 / update_rate
    needed = [_stable_step(p) for p in plans]
    step = min([PHYSICS_STEP, *needed])
    count = min(MAX_SUBSTEPS, max(1, math.ceil(period / step - 1e-9)))
    h = period / count
    for plan, limit in zip(plans, needed, strict=True):
        if limit < h * (1 - 1e-9):
            light = plan.inertia.lightest
            kp, kd = plan.kp, plan.kd
            plan.kd = round4(min(kd, STEP_MARGIN * light / h))
            plan.kp = round4(min(kp, light * (STEP_MARGIN / h) ** 2))
            report.approximated(
                plan.where,
                f"{plan.name}: gains kp {kp:g}, kd {kd:g} need a physics step below {limit * 1e6:.0f} µs in its "
                f"lightest pose (inertia {light:.4g}); lowered to kp {plan.kp:g}, kd {plan.kd:g} at "
                f"{count} substeps",
            )
    return count


def _stable_step(plan: JointPlan) -> float:
    light = plan.inertia.lightest
    if light <= 0:
        return PHYSICS_STEP
    by_damping = STEP_MARGIN * light / plan.kd if plan.kd > 0 else math.inf
    by_stiffness = STEP_MARGIN * math.sqrt(light / plan.kp) if plan.kp > 0 else math.inf
    return min(by_damping, by_stiffness)


# ---- pieces ---------------------------------------------------------------------------------------------------


def _interface_bound(hw: HardwareJoint | None, interface: str, joint: str) -> tuple[float | None, ...]:
    """``(min, max)`` params of a command interface, when given (ros2_control joint limits from the tag)."""
    if hw is None:
        return None, None
    for spec in hw.command_interfaces:
        if spec.name == interface:
            out = []
            for key in ("min", "max"):
                raw = spec.params.get(key)
                try:
                    out.append(float(raw) if raw not in (None, "") else None)
                except ValueError:
                    raise spec.where_of(key).fail(
                        f"joint {joint!r}: {interface} {key}={raw!r} is not a number"
                    ) from None
            return tuple(out)
    return None, None


def _limits(joint: Joint, hw: HardwareJoint | None, report: Report) -> tuple[float, float, float, float]:
    limit = joint.limit
    where = limit.where if limit is not None else joint.where
    if joint.type == "continuous":
        lower, upper = -CONTINUOUS_RANGE, CONTINUOUS_RANGE
        report.approximated(
            where, f"{joint.name}: continuous joint → position limits ±{CONTINUOUS_RANGE:.4f} (±1 turn)"
        )
    else:
        if limit is None or limit.lower is None or limit.upper is None:
            raise where.fail(f"{joint.type} joint {joint.name!r} needs <limit lower=... upper=...>")
        lower, upper = limit.lower, limit.upper
        if not lower < upper:
            raise where.fail(f"joint {joint.name!r}: <limit> lower {lower:g} must be below upper {upper:g}")
    velocity = limit.velocity if limit is not None else None
    effort = limit.effort if limit is not None else None
    lo, hi = _interface_bound(hw, "position", joint.name)
    if (lo is not None and lo > lower) or (hi is not None and hi < upper):
        lower, upper = max(lower, lo if lo is not None else lower), min(upper, hi if hi is not None else upper)
        report.mapped(hw.where if hw else where, f"{joint.name}: position min/max of <command_interface> → tighter")
    for name, current in (("velocity", velocity), ("effort", effort)):
        lo, hi = _interface_bound(hw, name, joint.name)
        bounds = [abs(b) for b in (lo, hi) if b is not None]
        if bounds and (current is None or min(bounds) < current):
            if len(set(bounds)) > 1:
                report.approximated(
                    hw.where if hw else where, f"{joint.name}: asymmetric {name} min/max → ±{min(bounds):g}"
                )
            if name == "velocity":
                velocity = min(bounds)
            else:
                effort = min(bounds)
    for name, value in (("velocity", velocity), ("effort", effort)):
        if value is None or value <= 0:
            found = "missing" if value is None else f"{value:g}"
            raise where.fail(
                f"joint {joint.name!r}: <limit {name}=...> is {found}; hild needs a positive {name} limit "
                f"({'the twin saturates its torque to it' if name == 'effort' else 'it bounds commands and planning'})"
            )
    assert velocity is not None and effort is not None
    report.mapped(
        where, f"{joint.name}: limits position [{lower:g}, {upper:g}], velocity {velocity:g}, effort {effort:g}"
    )
    return lower, upper, velocity, effort


def _soft_margin(joint: Joint, lower: float, upper: float, report: Report) -> float:
    safety = joint.safety
    if safety is None:
        return 0.0
    margins = []
    if safety.soft_lower is not None:
        margins.append(safety.soft_lower - lower)
    if safety.soft_upper is not None:
        margins.append(upper - safety.soft_upper)
    margins = [max(0.0, m) for m in margins]
    margin = round4(max(margins, default=0.0))
    if 2 * margin >= upper - lower:
        raise safety.where.fail(f"joint {joint.name!r}: soft limits leave no room inside [{lower:g}, {upper:g}]")
    text = f"{joint.name}: <safety_controller> soft limits → soft_margin {margin:g}"
    if len(set(margins)) > 1 or len(margins) == 1:
        report.approximated(safety.where, f"{text} (hild's margin is symmetric: the tighter side is taken)")
    else:
        report.mapped(safety.where, text)
    if safety.k_position is not None or safety.k_velocity is not None:
        report.unsupported(
            safety.where, f"{joint.name}: k_position/k_velocity (hild clamps the command at the soft limit)"
        )
    return margin


def _planning_limits(
    joint: Joint, velocity: float, effort: float, inertia: JointInertia, report: Report
) -> tuple[float, float]:
    heaviest = inertia.heaviest
    by_speed = ACCELERATION_PER_VELOCITY * velocity
    by_effort = ACCELERATION_EFFORT_SHARE * effort / heaviest if heaviest > 0 else math.inf
    acceleration = round4(min(by_speed, by_effort))
    jerk = round4(JERK_PER_ACCELERATION * acceleration)
    rule = f"{ACCELERATION_PER_VELOCITY:g} × velocity" if by_speed <= by_effort else "½ effort / inertia"
    report.approximated(
        joint.limit.where if joint.limit else joint.where,
        f"{joint.name}: URDF has no acceleration/jerk → acceleration {acceleration:g} ({rule}; heaviest inertia "
        f"{heaviest:.4g}), jerk {jerk:g} ({JERK_PER_ACCELERATION:g} × acceleration)",
    )
    return acceleration, jerk


def _transmissions(robot: Robot, commanded: set[str], report: Report) -> dict[str, tuple[dict[str, float], SourceRef]]:
    out: dict[str, tuple[dict[str, float], SourceRef]] = {}
    for t in robot.transmissions:
        if "SimpleTransmission" not in t.kind:
            report.unsupported(t.where, f"transmission {t.name!r}: {t.kind or 'no type'} (hild has simple ones)")
            continue
        if len(t.joints) != 1:
            raise t.where.fail(f"transmission {t.name!r}: a SimpleTransmission has exactly one <joint>")
        end = t.joints[0]
        if end.name not in robot.joints:
            raise end.where.fail(f"transmission {t.name!r} names joint {end.name!r}, which the URDF does not have")
        if end.name not in commanded:
            report.unsupported(t.where, f"transmission {t.name!r}: joint {end.name!r} is not commanded")
            continue
        actuator = t.actuators[0] if t.actuators else None
        reduction = end.reduction if end.reduction is not None else (actuator.reduction if actuator else None)
        where = end.reduction_where or (actuator.reduction_where if actuator else None) or t.where
        reduction = 1.0 if reduction is None else reduction
        if reduction == 0:
            raise where.fail(f"transmission {t.name!r}: mechanical reduction 0")
        offset = end.offset if end.offset is not None else ((actuator.offset if actuator else None) or 0.0)
        spec: dict[str, float] = {}
        if abs(reduction) != 1.0:
            spec["reduction"] = abs(reduction)
        if reduction < 0:
            spec["direction"] = -1
        if offset:
            spec["offset"] = offset
        out[end.name] = (spec, where)
        interfaces = sorted({i for e in (*t.joints, *t.actuators) for i in e.hardware_interfaces})
        iface_text = f", {', '.join(interfaces)}" if interfaces else ""
        report.mapped(
            where,
            f"transmission {t.name!r} ({t.form}{iface_text}): {end.name} reduction {abs(reduction):g}, "
            f"direction {-1 if reduction < 0 else 1}, offset {offset:g} → CAN template (the twin is joint space)",
        )
    return out
