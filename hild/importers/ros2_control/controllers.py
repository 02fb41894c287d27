"""controller_manager YAML → hild controllers, with every key accounted for in the report.

The files are read and merged by ``ros_params`` (launch substitutions, several files in order, lines). Every
layout ROS has used is read:

* ROS 2 with the types in controller_manager: ``controller_manager: ros__parameters: {update_rate, <name>:
  {type}}`` plus a ``<name>: ros__parameters:`` block per controller (namespaces and ``/**`` allowed);
* ROS 2 since Jazzy: each controller's ``type`` in its own ``ros__parameters`` block (a controller_manager block
  may then hold only ``update_rate``, or be in another file, or be absent);
* ROS 1 (``gazebo_ros_control``): controllers are mappings with a ``type``, their params beside it.

Which controllers a launch file spawned is not in the YAML, so broadcasters autostart and every other controller
starts inactive. Joint names are checked against the URDF here; a controller naming a joint that is not there
stops the import with the controller, the joint and the line. A controller hild has no counterpart for is
``Report.dropped``: the import is then partial, which the user must accept.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hild.config.documents import KeyPath
from hild.importers.ros2_control.report import ImportFailure, Report, SourceRef
from hild.importers.ros2_control.ros_params import WILDCARD, ParamTree, read_param_files

DEFAULT_UPDATE_RATE = 100.0  # Hz: controller_manager's own default
DEFAULT_PUBLISH_RATE = 100.0  # Hz: ROS 2's broadcaster publishes every update; hild publishes at a rate

BROADCASTERS = ("joint_state_broadcaster/JointStateBroadcaster", "joint_state_controller/JointStateController")
TRAJECTORY = "joint_trajectory_controller/JointTrajectoryController"
FORCE_TORQUE_BROADCASTER = "force_torque_sensor_broadcaster/ForceTorqueSensorBroadcaster"
FORWARD = "forward_command_controller/ForwardCommandController"
# Group controllers (removed from ros2_controllers in 2026) and ROS 1 single-joint forwarders: one interface each.
FORWARD_GROUPS = {
    "position_controllers/JointGroupPositionController": "position",
    "velocity_controllers/JointGroupVelocityController": "velocity",
    "effort_controllers/JointGroupEffortController": "effort",
    "position_controllers/JointPositionController": "position",
    "velocity_controllers/JointVelocityController": "velocity",
    "effort_controllers/JointEffortController": "effort",
}
CANOPEN_DRIVE_CONTROLLERS = (
    "canopen_ros2_controllers/Cia402RobotController",
    "canopen_ros2_controllers/Cia402DeviceController",
)
EFFORT_POSITION_PID = "effort_controllers/JointPositionController"
# Gripper action controllers → parallel_gripper, serving the ROS action the original served.
GRIPPERS = {
    "parallel_gripper_action_controller/GripperActionController": "parallel_gripper_command",
    "position_controllers/GripperActionController": "gripper_command",
    "effort_controllers/GripperActionController": "gripper_command",
}
GRIPPER_NUMBERS = (
    "goal_tolerance",
    "stall_velocity_threshold",
    "stall_timeout",
    "max_effort",
    "max_velocity",
    "action_monitor_rate",
)
GRIPPER_IGNORED = {
    "state_interfaces": "hild reads the joint's position, velocity and effort",
    "max_effort_interface": "hild bounds the grasp force itself, through the drive's spring",
    "max_velocity_interface": "hild limits the finger's speed itself",
    "gains": "hild's drive closes the position loop; the force is bounded by max_effort",
}

# JTC command interface sets → hild's (which has [position], [position, velocity] and [effort]).
JTC_INTERFACES: dict[tuple[str, ...], tuple[list[str], str | None]] = {
    ("position",): (["position"], None),
    ("position", "velocity"): (["position", "velocity"], None),
    ("effort",): (["effort"], None),
    ("velocity",): (
        ["position", "velocity"],
        "velocity-only (a PID on the velocity interface) → [position, velocity]: the drive tracks both",
    ),
    ("position", "velocity", "acceleration"): (
        ["position", "velocity"],
        "the acceleration command is dropped: the drive takes position and velocity",
    ),
    ("position", "effort"): (["position"], "the trajectory's effort is not fed forward"),
}
JTC_IGNORED = {
    "state_interfaces": "hild reads position and velocity of every joint",
    "open_loop_control": "hild always starts a goal from the desired state",
    "interpolate_from_desired_state": "hild always starts a goal from the desired state",
    "interpolation_method": "hild plans with ruckig (jerk-limited) and splines by the fields a goal gives",
    "allow_nonzero_velocity_at_trajectory_end": "hild appends a stop to a trajectory that ends moving",
    "set_last_command_interface_value_as_state_on_activation": "hild starts from the measured state (bumpless)",
}
PID_KEYS = ("p", "i", "d", "i_clamp", "i_clamp_max", "i_clamp_min", "ff_velocity_scale")


@dataclass(frozen=True)
class JointCatalog:
    """What the URDF says about joints, for checking the names controllers use."""

    commanded: tuple[str, ...]  # the hild joints (from <ros2_control>)
    urdf: frozenset[str]
    mimic: Mapping[str, str]  # mimic joint → the joint it follows
    interfaces: Mapping[str, frozenset[str]]  # command interfaces <ros2_control> exports per joint
    sensors: Mapping[str, str] = field(default_factory=dict)  # <sensor> name → hild sensor type (force_torque, imu)

    def check(self, controller: str, joint: Any, where: SourceRef) -> str:
        if not isinstance(joint, str):
            raise where.fail(f"controller {controller!r}: a joint name must be a string, found {joint!r}")
        if joint in self.commanded:
            return joint
        if joint in self.mimic:
            reason = f"is a mimic joint of {self.mimic[joint]!r} and cannot be commanded"
        elif joint in self.urdf:
            reason = "is in the URDF but in no <ros2_control> block, so it has no command interfaces"
        else:
            known = ", ".join(self.commanded) or "none"
            reason = f"does not exist in the URDF (commandable joints: {known})"
        raise where.fail(f"controller {controller!r} names joint {joint!r}, which {reason}")


@dataclass
class Pid:
    p: float
    i: float
    d: float
    i_clamp: float | None  # None: ROS's integral is unbounded; the pipeline bounds it by the effort limit
    ff_velocity_scale: float
    where: SourceRef

    def params(self) -> dict[str, float]:
        out = {"p": self.p, "i": self.i, "d": self.d}
        if self.i_clamp is not None:
            out["i_clamp"] = self.i_clamp
        if self.ff_velocity_scale:
            out["ff_velocity_scale"] = self.ff_velocity_scale
        return out


@dataclass
class ControllerPlan:
    name: str
    type: str  # hild controller type
    params: dict[str, Any]
    autostart: bool
    where: SourceRef
    comment: str
    pid: dict[str, Pid] = field(default_factory=dict)  # effort PID per joint (joint_trajectory on [effort])


@dataclass
class ControllersPlan:
    update_rate: float
    update_rate_where: SourceRef
    controllers: list[ControllerPlan]

    def effort_pid(self) -> dict[str, tuple[str, Pid]]:
        """Per joint, the first effort PID found (its p and d are the joint's natural hold gains)."""
        found: dict[str, tuple[str, Pid]] = {}
        for plan in self.controllers:
            for joint, pid in plan.pid.items():
                found.setdefault(joint, (plan.name, pid))
        return found


@dataclass
class _Controller:
    name: str
    ros_type: str
    type_where: SourceRef
    params: dict[str, Any]
    params_path: KeyPath  # key path of the params mapping, for lines


def read_controllers(
    paths: Path | Sequence[Path],
    catalog: JointCatalog,
    report: Report,
    variables: Mapping[str, str] | None = None,
    namespace: str | None = None,
) -> ControllersPlan:
    """Read the controller files (merged in order, ``$(var NAME)`` from ``variables``; of several robots' nodes,
    those under ``namespace``) into hild controllers."""
    files = [paths] if isinstance(paths, Path) else list(paths)
    tree = read_param_files(files, variables or {}, report, namespace)
    reader = _Reader(tree, catalog, report)
    if tree.document is not None:
        rate, rate_where, found = reader.ros1_layout(tree.document)
    else:
        rate, rate_where, found = reader.ros2_layout(tree.nodes)
    plans = [plan for c in found if (plan := reader.controller(c)) is not None]
    if found:
        report.approximated(
            rate_where,
            "which controllers ROS spawned is in the launch file, not here: broadcasters autostart, every other "
            "controller starts inactive (activate with `hild ctl switch`)",
        )
    return ControllersPlan(rate, rate_where, plans)


class _Reader:
    def __init__(self, tree: ParamTree, catalog: JointCatalog, report: Report) -> None:
        self.tree, self.catalog, self.report = tree, catalog, report

    def ref(self, path: KeyPath) -> SourceRef:
        return self.tree.ref(path)

    # ---- layouts --------------------------------------------------------------------------------------------
    def ros2_layout(self, nodes: dict[str, dict[str, Any]]) -> tuple[float, SourceRef, list[_Controller]]:
        """Controllers named in controller_manager (with their type) and nodes whose own params carry a type."""
        cm_path: KeyPath = ("controller_manager",)
        cm = nodes.get("controller_manager")
        declared: dict[str, tuple[str, SourceRef]] = {}
        if cm is None:
            rate, rate_where = self.update_rate(None, (), ())
        else:
            rate, rate_where = self.update_rate(cm.get("update_rate"), (*cm_path, "update_rate"), cm_path)
            for key, value in cm.items():
                here = (*cm_path, str(key))
                if isinstance(value, dict) and "type" in value:
                    for extra in sorted(set(value) - {"type"}):
                        self.report.unsupported(
                            self.ref((*here, extra)),
                            f"controller {key!r}: {extra} is not read (put params in the controller's own block)",
                        )
                    declared[str(key)] = (str(value["type"]), self.ref((*here, "type")))
                elif key != "update_rate":
                    self.report.unsupported(self.ref(here), f"controller_manager parameter {key!r} is not used by hild")
        typed = [n for n, p in nodes.items() if n not in declared and n != "controller_manager" and "type" in p]
        found: list[_Controller] = []
        for name in [*declared, *typed]:
            params = dict(nodes.get(name, {}))
            own = params.pop("type", None)
            if name in declared:
                kind, where = declared[name]
                if own is not None and str(own) != kind:
                    raise self.ref((name, "type")).fail(
                        f"controller {name!r} has two types: {own} here and {kind} at {where}"
                    )
            else:
                kind, where = str(own), self.ref((name, "type"))
            found.append(_Controller(name, kind, where, params, (name,)))
        for name, params in nodes.items():
            if name == WILDCARD:
                for key in params:
                    self.report.unsupported(self.ref((name, key)), f"wildcard parameter {key!r} is not used")
            elif name != "controller_manager" and name not in declared and name not in typed:
                self.report.unsupported(
                    self.ref((name,)),
                    f"parameters for {name!r}, which is not a controller: no type here or in controller_manager",
                )
        if not found:
            raise self.no_controllers()
        return rate, rate_where, found

    def no_controllers(self) -> ImportFailure:
        """A controllers file with nothing to import stops the import: a config without its controllers is not
        what was asked for (``--allow-partial`` leaves out controllers hild cannot map, never all of them)."""
        return SourceRef(str(self.tree.files[0]), 1).fail(
            "no controllers found: expected controller_manager: ros__parameters: with <name>: {type: ...}, "
            "<name>: ros__parameters: {type: ...} (ROS 2), or mappings with a type (ROS 1)"
        )

    def ros1_layout(self, data: dict[str, Any]) -> tuple[float, SourceRef, list[_Controller]]:
        found: list[_Controller] = []

        def walk(node: dict[str, Any], path: KeyPath) -> None:
            for key, value in node.items():
                here = (*path, str(key))
                if not isinstance(value, dict):
                    continue
                kind = value.get("type")
                if isinstance(kind, str) and "/" in kind:
                    params = {k: v for k, v in value.items() if k != "type"}
                    found.append(_Controller(str(key), kind, self.ref((*here, "type")), params, here))
                elif len(path) < 3:
                    walk(value, here)

        walk(data, ())
        if not found:
            raise self.no_controllers()
        rate, where = self.update_rate(None, (), ())
        self.report.approximated(where, "ROS 1 layout (gazebo_ros_control): controllers read from their type keys")
        return rate, where, found

    def update_rate(self, value: Any, path: KeyPath, owner: KeyPath) -> tuple[float, SourceRef]:
        if value is None:
            where = self.ref(owner) if owner else SourceRef(str(self.tree.files[0]), 1)
            self.report.approximated(
                where,
                f"no update_rate in {'controller_manager' if owner else 'any file'}: controller_manager's default "
                f"{DEFAULT_UPDATE_RATE:g} Hz",
            )
            return DEFAULT_UPDATE_RATE, where
        where = self.ref(path)
        if isinstance(value, bool) or not isinstance(value, int | float) or not 1.0 <= value <= 10000.0:
            raise where.fail(f"update_rate must be a number of Hz between 1 and 10000, found {value!r}")
        self.report.mapped(where, f"update_rate {value:g} Hz")
        return float(value), where

    # ---- one controller ----------------------------------------------------------------------------------------
    def controller(self, c: _Controller) -> ControllerPlan | None:
        if not isinstance(c.params, dict):
            raise self.ref(c.params_path).fail(f"parameters of controller {c.name!r} must be a mapping")
        if c.ros_type in BROADCASTERS:
            return self.broadcaster(c)
        if c.ros_type == TRAJECTORY:
            return self.trajectory(c)
        if c.ros_type == FORWARD:
            interface = c.params.get("interface_name")
            return self.forward(c, interface, self.ref((*c.params_path, "interface_name")), {"interface_name"})
        if c.ros_type == EFFORT_POSITION_PID:
            return self.effort_position(c)
        if c.ros_type in FORWARD_GROUPS:
            return self.forward(c, FORWARD_GROUPS[c.ros_type], c.type_where, set())
        if c.ros_type in GRIPPERS:
            return self.gripper(c)
        if c.ros_type == FORCE_TORQUE_BROADCASTER:
            return self.wrench_broadcaster(c)
        if c.ros_type in CANOPEN_DRIVE_CONTROLLERS:
            self.report.approximated(
                c.type_where,
                f"controller {c.name!r} ({c.ros_type}): not needed: its services (init, halt, recover, mode "
                "switches) are what hild's cia402 component does on activate, stop and reset, in one cyclic mode "
                "per drive; its params are not read",
            )
            return None
        self.report.dropped(c.type_where, f"controller {c.name!r}: type {c.ros_type} has no hild counterpart")
        return None

    def leftovers(self, c: _Controller, used: set[str], why: Mapping[str, str] | None = None) -> None:
        for key in c.params:
            if key in used:
                continue
            where = self.ref((*c.params_path, key))
            if why and key in why:
                self.report.approximated(where, f"controller {c.name!r}: {key} not needed: {why[key]}")
            else:
                self.report.unsupported(where, f"controller {c.name!r}: parameter {key!r} is not used by hild")

    def joints(self, c: _Controller, key: str = "joints") -> list[str]:
        raw = c.params.get(key)
        path = (*c.params_path, key)
        if key == "joint" and isinstance(raw, str):
            return [self.catalog.check(c.name, raw, self.ref(path))]
        if not isinstance(raw, list) or not raw:
            raise self.ref(path if raw is not None else c.params_path).fail(
                f"controller {c.name!r} ({c.ros_type}) needs a non-empty list {key!r}"
            )
        joints = [self.catalog.check(c.name, j, self.ref((*path, i))) for i, j in enumerate(raw)]
        if len(set(joints)) != len(joints):
            raise self.ref(path).fail(f"controller {c.name!r} lists a joint twice: {joints}")
        return joints

    def check_claims(self, c: _Controller, joints: Sequence[str], interfaces: Sequence[str]) -> None:
        """Claims ROS would refuse because <ros2_control> does not export them (the twin offers every one)."""
        missing = [
            f"{joint}/{i}"
            for joint in joints
            if joint in self.catalog.interfaces
            for i in interfaces
            if i not in self.catalog.interfaces[joint]
        ]
        if missing:
            self.report.approximated(
                c.type_where,
                f"controller {c.name!r} claims {', '.join(missing)}, which <ros2_control> does not export "
                "(ROS would refuse it; the twin offers every interface)",
            )

    def broadcaster(self, c: _Controller) -> ControllerPlan:
        rate = c.params.get("publish_rate", c.params.get("state_publish_rate"))
        if isinstance(rate, int | float) and not isinstance(rate, bool) and rate > 0:
            key = "publish_rate" if "publish_rate" in c.params else "state_publish_rate"
            self.report.mapped(self.ref((*c.params_path, key)), f"{c.name}: publish_rate {rate:g} Hz")
        else:
            rate = DEFAULT_PUBLISH_RATE
            self.report.approximated(
                c.type_where, f"{c.name} → joint_state_broadcaster at {rate:g} Hz (ROS publishes every update)"
            )
        self.leftovers(
            c, {"publish_rate", "state_publish_rate"}, {k: "hild publishes every joint's state" for k in c.params}
        )
        return ControllerPlan(
            c.name, "joint_state_broadcaster", {"publish_rate": rate}, True, c.type_where, f"from {c.ros_type}"
        )

    def forward(self, c: _Controller, interface: Any, where: SourceRef, used: set[str]) -> ControllerPlan | None:
        joints = self.joints(c, "joint" if "joint" in c.params and "joints" not in c.params else "joints")
        if interface not in ("position", "velocity", "effort"):
            self.report.dropped(
                where, f"controller {c.name!r}: interface {interface!r} (hild forwards position, velocity or effort)"
            )
            return None
        self.check_claims(c, joints, [interface])
        self.report.approximated(
            c.type_where,
            f"{c.name}: {c.ros_type} → forward_command on {interface}; hild returns the joints to hold after "
            "0.5 s without commands (ROS keeps the last one)",
        )
        self.leftovers(c, used | {"joints", "joint"})
        return ControllerPlan(
            c.name,
            "forward_command",
            {"joints": joints, "interface": interface},
            False,
            c.type_where,
            f"from {c.ros_type}",
        )

    def trajectory(self, c: _Controller) -> ControllerPlan:
        joints = self.joints(c)
        p = c.params
        used = {"joints", "command_interfaces", "constraints", "gains", "allow_partial_joints_goal"}
        raw_ifaces = p.get("command_interfaces", ["position"])
        where_ifaces = self.ref((*c.params_path, "command_interfaces"))
        if not isinstance(raw_ifaces, list) or tuple(raw_ifaces) not in JTC_INTERFACES:
            raise where_ifaces.fail(
                f"controller {c.name!r}: command_interfaces {raw_ifaces!r} is not a set the JTC accepts "
                f"({', '.join(str(list(k)) for k in JTC_INTERFACES)})"
            )
        interfaces, note = JTC_INTERFACES[tuple(raw_ifaces)]
        self.check_claims(c, joints, raw_ifaces)
        if note:
            self.report.approximated(where_ifaces, f"{c.name}: {note}")
        params: dict[str, Any] = {"joints": joints, "command_interfaces": interfaces}
        if "allow_partial_joints_goal" in p:
            params["allow_partial_joints_goal"] = bool(p["allow_partial_joints_goal"])
        if "action_monitor_rate" in p:
            used.add("action_monitor_rate")
            params["feedback_rate"] = self.number(p["action_monitor_rate"], (*c.params_path, "action_monitor_rate"))
        params["constraints"] = self.constraints(c, joints)
        plan = ControllerPlan(c.name, "joint_trajectory", params, False, c.type_where, f"from {c.ros_type}")
        gains = p.get("gains")
        if gains is not None:
            where = self.ref((*c.params_path, "gains"))
            if interfaces != ["effort"]:
                self.report.approximated(where, f"{c.name}: gains unused: hild's drive closes the position loop")
            elif not isinstance(gains, dict):
                raise where.fail(f"controller {c.name!r}: gains must map joints to {{p, i, d}}")
            else:
                for joint, raw in gains.items():
                    here = (*c.params_path, "gains", str(joint))
                    if joint not in joints:
                        self.report.unsupported(self.ref(here), f"{c.name}: gains for {joint!r}, not in its joints")
                        continue
                    plan.pid[joint] = self.pid(c, raw, here)
        text = f"{c.name} → joint_trajectory on [{', '.join(interfaces)}] over {', '.join(joints)}"
        self.report.mapped(c.type_where, text)
        self.leftovers(c, used, JTC_IGNORED)
        return plan

    def constraints(self, c: _Controller, joints: list[str]) -> dict[str, Any]:
        base = (*c.params_path, "constraints")
        raw = c.params.get("constraints") or {}
        if not isinstance(raw, dict):
            raise self.ref(base).fail(f"controller {c.name!r}: constraints must be a mapping")
        out: dict[str, Any] = {}
        goal_time = raw.get("goal_time", 0.0)
        if self.number(goal_time, (*base, "goal_time")) > 0:
            out["goal_time"] = float(goal_time)
            self.report.mapped(self.ref((*base, "goal_time")), f"{c.name}: constraints.goal_time {goal_time:g} s")
        else:
            out["goal_time"] = 1.0
            self.report.approximated(
                self.ref((*base, "goal_time") if "goal_time" in raw else c.params_path),
                f"{c.name}: goal_time 0 (ROS: wait forever) → 1 s after the trajectory's end",
            )
        out["stopped_velocity_tolerance"] = self.number(
            raw.get("stopped_velocity_tolerance", 0.01), (*base, "stopped_velocity_tolerance")
        )
        per_joint: dict[str, dict[str, float]] = {}
        for key, value in raw.items():
            here = (*base, str(key))
            if key in ("goal_time", "stopped_velocity_tolerance"):
                continue
            if key not in joints or not isinstance(value, dict):
                self.report.unsupported(self.ref(here), f"{c.name}: constraints.{key} is not used by hild")
                continue
            entry = {}
            for tol, tol_value in value.items():
                if tol in ("trajectory", "goal"):
                    entry[tol] = self.number(tol_value, (*here, tol))
                else:
                    self.report.unsupported(self.ref((*here, tol)), f"{c.name}: constraints.{key}.{tol} not used")
            per_joint[key] = entry
        if per_joint:
            out["joints"] = per_joint
            self.report.mapped(self.ref(base), f"{c.name}: per-joint trajectory/goal tolerances")
        return out

    def gripper(self, c: _Controller) -> ControllerPlan:
        """A gripper action controller → parallel_gripper on its joint, with the same action on ROS 2."""
        joints = self.joints(c, "joint")
        if len(joints) != 1:
            raise self.ref(c.params_path).fail(f"controller {c.name!r} ({c.ros_type}) drives exactly one joint")
        joint = joints[0]
        self.check_claims(c, [joint], ["position"])
        params: dict[str, Any] = {"joint": joint, "ros_action": GRIPPERS[c.ros_type]}
        for key in GRIPPER_NUMBERS:
            if key not in c.params:
                continue
            value = self.number(c.params[key], (*c.params_path, key))
            if key in ("max_effort", "max_velocity") and value == 0.0:  # ROS: no limit given; hild's default
                self.report.approximated(
                    self.ref((*c.params_path, key)), f"{c.name}: {key} 0 → parallel_gripper's default"
                )
                continue
            params[key] = value
        if "allow_stalling" in c.params:
            params["allow_stalling"] = bool(c.params["allow_stalling"])
        action = "ParallelGripperCommand" if GRIPPERS[c.ros_type] == "parallel_gripper_command" else "GripperCommand"
        self.report.mapped(
            c.type_where,
            f"{c.name} → parallel_gripper on {joint}: goals to a position with a bounded force, stall detection; "
            f"ROS 2 action {c.name}/gripper_cmd ({action})",
        )
        self.leftovers(c, {"joint", "allow_stalling", *GRIPPER_NUMBERS}, GRIPPER_IGNORED)
        return ControllerPlan(c.name, "parallel_gripper", params, False, c.type_where, f"from {c.ros_type}")

    def wrench_broadcaster(self, c: _Controller) -> ControllerPlan:
        """force_torque_sensor_broadcaster → hild's, on the same sensor (or interfaces) and frame."""
        p = c.params
        params: dict[str, Any] = {}
        sensor = p.get("sensor_name")
        if sensor:
            if self.catalog.sensors.get(str(sensor)) != "force_torque":
                known = ", ".join(n for n, k in self.catalog.sensors.items() if k == "force_torque") or "none"
                raise self.ref((*c.params_path, "sensor_name")).fail(
                    f"controller {c.name!r}: sensor_name {sensor!r} is no force/torque <sensor> of <ros2_control> "
                    f"(force/torque sensors: {known})"
                )
            params["sensor_name"] = str(sensor)
        names = p.get("interface_names")
        if isinstance(names, dict) and not sensor:
            params["interface_names"] = {
                part: {axis: str(value) for axis, value in (names.get(part) or {}).items() if value}
                for part in ("force", "torque")
            }
        if "frame_id" in p:
            params["frame_id"] = str(p["frame_id"])
        self.report.mapped(c.type_where, f"{c.name} → force_torque_sensor_broadcaster: {c.name}/wrench (JSON, ROS 2)")
        self.report.approximated(
            c.type_where, f"{c.name}: published at {DEFAULT_PUBLISH_RATE:g} Hz (ROS publishes every update)"
        )
        why = {"sensor_filter_chain": "hild offers a first-order low_pass_cutoff instead (off)"}
        self.leftovers(c, {"sensor_name", "interface_names", "frame_id"}, why)
        return ControllerPlan(
            c.name,
            "force_torque_sensor_broadcaster",
            {**params, "publish_rate": DEFAULT_PUBLISH_RATE},
            True,
            c.type_where,
            f"from {c.ros_type}",
        )

    def effort_position(self, c: _Controller) -> ControllerPlan:
        joints = self.joints(c, "joint" if "joint" in c.params else "joints")
        if len(joints) != 1:
            raise self.ref(c.params_path).fail(f"controller {c.name!r} ({c.ros_type}) drives exactly one joint")
        joint = joints[0]
        self.check_claims(c, joints, ["effort"])
        if "pid" in c.params:
            pid, used = self.pid(c, c.params["pid"], (*c.params_path, "pid")), "pid"
        elif isinstance(c.params.get("gains"), dict) and joint in c.params["gains"]:
            pid, used = self.pid(c, c.params["gains"][joint], (*c.params_path, "gains", joint)), "gains"
        else:
            raise self.ref(c.params_path).fail(f"controller {c.name!r} ({c.ros_type}) needs pid: {{p, i, d}}")
        plan = ControllerPlan(
            c.name,
            "joint_trajectory",
            {"joints": joints, "command_interfaces": ["effort"], "constraints": {"goal_time": 1.0}},
            False,
            c.type_where,
            f"from {c.ros_type} (set-point topic → trajectory and move_to goals)",
            {joint: pid},
        )
        self.report.approximated(
            c.type_where,
            f"{c.name}: {c.ros_type} → joint_trajectory on [effort] with the same PID: it takes trajectory and "
            "move_to goals instead of a set-point topic",
        )
        self.leftovers(c, {"joint", "joints", used})
        return plan

    def pid(self, c: _Controller, raw: Any, path: KeyPath) -> Pid:
        where = self.ref(path)
        if not isinstance(raw, dict) or "p" not in raw:
            raise where.fail(f"controller {c.name!r}: PID gains must be a mapping with at least p, found {raw!r}")
        values = {k: self.number(v, (*path, k), minimum=None) for k, v in raw.items() if k in PID_KEYS}
        for key in raw:
            if key not in PID_KEYS:
                self.report.unsupported(self.ref((*path, key)), f"{c.name}: PID option {key!r} is not used by hild")
        for key in ("p", "i", "d"):
            if values.get(key, 0.0) < 0:
                raise self.ref((*path, key)).fail(f"controller {c.name!r}: hild needs PID gains ≥ 0")
        clamp = values.get("i_clamp")
        bounds = [abs(values[k]) for k in ("i_clamp_max", "i_clamp_min") if k in values]
        if clamp is None and bounds:
            clamp = min(bounds)
            if len(set(bounds)) > 1:
                self.report.approximated(where, f"{c.name}: asymmetric integral clamp → ±{clamp:g}")
        gains = ", ".join(f"{k} {values.get(k, 0.0):g}" for k in ("p", "i", "d"))
        self.report.mapped(where, f"{c.name}: PID {gains}")
        return Pid(
            values["p"],
            values.get("i", 0.0),
            values.get("d", 0.0),
            abs(clamp) if clamp is not None else None,
            values.get("ff_velocity_scale", 0.0),
            where,
        )

    def number(self, value: Any, path: KeyPath, minimum: float | None = 0.0) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise self.ref(path).fail(f"{'.'.join(map(str, path[-2:]))} must be a number, found {value!r}")
        if minimum is not None and value < minimum:
            raise self.ref(path).fail(f"{'.'.join(map(str, path[-2:]))} must be ≥ {minimum:g}, found {value!r}")
        return float(value)
