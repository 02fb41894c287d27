"""``import_ros2_control``: URDF (or xacro) + controller YAML files → a hild config and the twin's URDF, or nothing.

The steps, each in its own module: expand xacro (xacro_expand) → parse with lines (xmltree, urdf) → choose the
joints (mapping) → read and merge the controller files (ros_params, controllers) → what the hardware params say
about CAN drives (can_template) → the twin's URDF and its inertias (twin, inertia) → limits, gains,
transmissions (mapping), stiffness against friction and goal tolerances (tolerances) → contacts the twin ignores
(contacts) → YAML (writer). Both files are written to a temporary directory beside the output, checked there the
way ``hild check`` checks a config (its warnings go into the report), a full-speed goal of each trajectory
controller is simulated on the twin there (tracking), and only then are both renamed into place: an error at any
step — or a partial import the user did not accept — leaves nothing behind.
"""

from __future__ import annotations

import contextlib
import copy
import os
import re
import shutil
import tempfile
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from hild.config import ConfigError, load_config
from hild.config.stop_review import check_with_model
from hild.dynamics.inspection import finger_spread
from hild.importers.ros2_control import controllers as ctl
from hild.importers.ros2_control import mapping, twin, writer
from hild.importers.ros2_control.can_template import read_can_facts
from hild.importers.ros2_control.canopen import HARDWARE_PARAMS, Cia402Section, commanded_interfaces, plan_canopen
from hild.importers.ros2_control.contacts import excluded_contacts
from hild.importers.ros2_control.gains import GRIPPER_DEFAULT_EFFORT, GainLimits, grasp_gains
from hild.importers.ros2_control.inertia import joint_inertias
from hild.importers.ros2_control.packages import PackageRoots
from hild.importers.ros2_control.report import ImportFailure, Report, SourceRef
from hild.importers.ros2_control.tolerances import fit_friction
from hild.importers.ros2_control.tracking import report_tracking
from hild.importers.ros2_control.urdf import Robot, parse_robot
from hild.importers.ros2_control.xacro_expand import expand_xacro, is_xacro
from hild.importers.ros2_control.xmltree import XmlDocument, XmlSyntaxError, parse_xml


@dataclass(frozen=True)
class ImportRequest:
    urdf: Path
    controllers: Path | Sequence[Path]  # several: merged in order, as ROS applies parameter files
    output: Path  # the hild config (.yaml); the twin's URDF is written beside it with the same stem
    package_roots: Mapping[str, Path] = field(default_factory=dict)
    xacro_args: Mapping[str, str] = field(default_factory=dict)
    args: Mapping[str, str] = field(default_factory=dict)  # launch arguments: xacro args and $(var NAME) in YAML
    robot_name: str | None = None
    namespace: str | None = None  # of several robots' nodes in the controller files, this one's (default: the first)
    force: bool = False
    allow_partial: bool = False  # accept an import that leaves out controllers or joints it cannot map
    keep_self_contacts: bool = False  # let the twin collide robot links that overlap at the start pose
    tracking_check: bool = True  # simulate a full-speed goal of each trajectory controller on the twin (tracking.py)

    @property
    def twin_urdf(self) -> Path:
        return self.output.with_suffix(".urdf")

    @property
    def controller_files(self) -> tuple[Path, ...]:
        return (self.controllers,) if isinstance(self.controllers, Path) else tuple(self.controllers)


@dataclass(frozen=True)
class ImportResult:
    config: Path
    urdf: Path
    report: Report


def import_ros2_control(request: ImportRequest) -> ImportResult:
    """Run the import; raises :class:`ImportFailure` (with file:line) and then has written nothing."""
    config_path, urdf_path = request.output.resolve(), request.twin_urdf.resolve()
    _check_destination(request, config_path, urdf_path)
    report = Report()
    packages = PackageRoots(request.package_roots, request.urdf.resolve().parent)
    document, label = _read_urdf(request, packages, urdf_path, report)
    robot = parse_robot(document.root, label)

    selected = mapping.select_joints(robot, report)
    if not selected:
        raise robot.where.fail("no joint to command: <ros2_control> lists no movable, non-mimic joint")
    sensors = mapping.plan_sensors(robot, report)
    files = request.controller_files
    catalog = mapping.catalog(robot, selected, sensors)
    plan = ctl.read_controllers(files, catalog, report, request.args, request.namespace)
    can = read_can_facts(robot, report)
    cia402 = plan_canopen(
        robot,
        _joints_by_block(selected),
        commanded_interfaces(plan),
        packages,
        config_path.parent,
        plan.update_rate,
        report,
    )
    used = {name: facts.used for name, facts in can.items()} | {name: set(HARDWARE_PARAMS) for name in cia402}
    mapping.report_hardware(robot, used, report)
    mimics = mapping.plan_mimic_joints(robot, selected, report)
    mapping.check_limits(selected)
    twin.check_inertias(robot)
    urdf_text = twin.build_twin_urdf(document, robot, request.urdf.resolve().parent, packages, report)

    with _staging(config_path) as staging:
        staged_urdf, staged_config = staging / urdf_path.name, staging / config_path.name
        staged_urdf.write_text(urdf_text)
        with _mujoco_refusal(robot, label, staging):
            ranges = mapping.position_ranges(robot, selected)
            inertias = joint_inertias(staged_urdf, [s.joint.name for s in selected], ranges)
        joints = mapping.plan_joints(robot, selected, inertias, plan.effort_pid(), plan.update_rate, report)
        fit_friction(joints, plan, plan.update_rate, report)
        start = {j.name: j.initial_position for j in joints if j.initial_position is not None}
        with _mujoco_refusal(robot, label, staging):
            exclusions = excluded_contacts(robot, staged_urdf, start, request.keep_self_contacts, report)
        with _mujoco_refusal(robot, label, staging):
            _complete_grippers(plan, joints, staged_urdf, report)
        substeps = mapping.choose_substeps(joints, plan.update_rate, report)
        _complete_effort_gains(plan, joints, report)
        doc = writer.build_document(
            _robot_name(request.robot_name or robot.name or config_path.stem),
            urdf_path.name,
            joints,
            plan,
            substeps,
            [f"URDF: {request.urdf.resolve()}", *(f"controllers: {f.resolve()}" for f in files)],
            can,
            exclusions,
            mimics,
            sensors,
            cia402,
        )
        staged_config.write_text(writer.render(doc))
        _relay_check_warnings(_hild_check(staged_config, config_path), joints, robot, report)
        _check_cia402(doc, cia402, robot, staging, config_path.parent, report)
        if report.partial and not request.allow_partial:  # last: every real error in the input comes first
            raise report.partial_failure()
        if request.tracking_check:
            report_tracking(staged_config, {c.name: c.where for c in plan.controllers}, report, robot.where)
        else:
            report.tracking(robot.where, "not simulated (--no-tracking-check)")
        os.replace(staged_urdf, urdf_path)
        os.replace(staged_config, config_path)
    report.notes.insert(0, f"wrote {config_path} and {urdf_path} (the twin's model)")
    if report.partial:
        report.notes.insert(1, f"partial import (--allow-partial): {len(report.partial)} left out, see Not supported")
    return ImportResult(config_path, urdf_path, report)


def _joints_by_block(selected: Sequence[mapping.Selected]) -> dict[str, list[str]]:
    """The joints hild commands, per <ros2_control> block name."""
    out: dict[str, list[str]] = {}
    for s in selected:
        if s.block is not None:
            out.setdefault(s.block.name, []).append(s.joint.name)
    return out


def _read_urdf(
    request: ImportRequest, packages: PackageRoots, urdf_path: Path, report: Report
) -> tuple[XmlDocument, str]:
    """The URDF as a document with lines, and the file name its lines refer to (the expansion, for xacro)."""
    source = request.urdf
    try:
        text = source.read_text()
    except OSError as exc:
        raise ImportFailure(f"{source}: cannot read the URDF: {exc.strerror or exc}") from None
    label = str(source)
    if is_xacro(source, text):
        text, warnings = expand_xacro(source, {**request.args, **request.xacro_args}, packages)
        label = str(urdf_path)
        report.notes.append(f"xacro: {source} expanded; URDF lines below refer to the expansion, {urdf_path}")
        for warning in warnings:
            report.approximated(SourceRef(str(source)), f"xacro said: {warning}")
    try:
        return parse_xml(text), label
    except XmlSyntaxError as exc:
        raise SourceRef(label, exc.line).fail(str(exc)) from None


@contextlib.contextmanager
def _staging(config_path: Path) -> Iterator[Path]:
    """A temporary directory beside the output; on failure it, and any directory made for it, is gone."""
    created = [d for d in (config_path.parent, *config_path.parent.parents) if not d.exists()]
    config_path.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=".hild-import-", dir=config_path.parent))
    try:
        yield staging
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        for directory in created:  # innermost first: only the directories this import made
            directory.rmdir()
        raise
    shutil.rmtree(staging, ignore_errors=True)


def _check_destination(request: ImportRequest, config_path: Path, urdf_path: Path) -> None:
    if config_path.suffix not in (".yaml", ".yml"):
        raise ImportFailure(f"{request.output}: the output is a hild config and must end in .yaml")
    for given in (request.urdf, *request.controller_files):
        if given.resolve() in (config_path, urdf_path):
            raise ImportFailure(f"{given}: the output would overwrite this input; choose another -o")
    if not request.force:
        for path in (config_path, urdf_path):
            if path.exists():
                raise ImportFailure(f"{path} exists: pass --force to overwrite it")


GRAVITY_ON_EFFORT = (
    "gravity_compensation: true — on the twin hild adds the model's gravity torque to the PID's effort, as a real "
    "arm's driver does (without it the arm stops short by gravity / p); on real drives the same must come from hild "
    "with robot.model, or from the drive itself with gravity_compensation: false, never both"
)

_WARNING = re.compile(r"^warning: .*?:\d+: (?P<key>\S+): (?P<message>.*)$", re.S)


def _relay_check_warnings(notes: list[str], joints: list[mapping.JointPlan], robot: Robot, report: Report) -> None:
    """`hild check`'s warnings on the written config, at the source of the values they are about. The importer's own
    defaults draw none (mapping keeps them within what check demands): what is left is about the user's numbers."""
    by_name = {j.name: j for j in joints}
    for note in notes:
        found = _WARNING.match(note)
        if found is None:
            continue
        key, message = found.group("key"), found.group("message")
        parts = key.split(".")
        joint = by_name.get(parts[1]) if len(parts) > 2 and parts[0] == "joints" else None
        where, origin = robot.where, ""
        if joint is not None:
            where = joint.where
            if parts[2] in ("hold", "position_gains") and joint.gains_pid is not None:
                controller, where = joint.gains_pid
                origin = f" (from your PID gains of {controller})"
        report.approximated(where, f"hild check warns: {key}: {message}{origin}")


def _hild_check(staged_config: Path, config_path: Path) -> list[str]:
    """Check the written config exactly as `hild check` does; its notes (warnings), or the failure under the
    name the user asked for."""
    try:
        loaded = load_config(staged_config)
        check_with_model(loaded)
    except ConfigError as exc:
        detail = str(exc).replace(str(staged_config), str(config_path))
        raise ImportFailure(f"the imported config does not pass `hild check` (please report):\n{detail}") from None
    return loaded.notes


def _check_cia402(
    doc: writer.Document,
    sections: Mapping[str, Cia402Section],
    robot: Robot,
    staging: Path,
    config_dir: Path,
    report: Report,
) -> None:
    """The config with the cia402 sections in place of the twin, checked as `hild check` checks it (the driver's
    params, its review of node ids, EDS and scaling, the bus load): what it refuses or warns about is reported at
    the <ros2_control> block, so the commented section is known to work before anyone uncomments it."""
    if not sections:
        return
    blocks = {b.name: b for b in robot.ros2_control}
    where = blocks[next(iter(sections))].where
    covered = {j for s in sections.values() for j in s.component["joints"]}
    if covered != set(doc.data["joints"]):
        report.approximated(where, "cia402 section not checked: it drives only some of the joints (mixed hardware)")
        return
    hardware = {}
    for s in sections.values():
        component = copy.deepcopy(s.component)
        params = component["params"]
        for holder in (params, *params["drives"].values()):
            if "eds" in holder:
                holder["eds"] = str((config_dir / holder["eds"]).resolve())
        hardware[s.name] = component
    check = staging / "cia402_check.yaml"
    check.write_text(writer.render(writer.Document({**doc.data, "hardware": hardware})))
    try:
        loaded = load_config(check)
        check_with_model(loaded)
    except ConfigError as exc:
        detail = str(exc)
        if "unknown driver 'cia402'" in detail:
            report.approximated(where, "cia402 section not checked: no cia402 driver is installed")
            return
        for line in detail.splitlines():
            line = re.sub(rf"^\s*{re.escape(str(check))}(:\d+)?:\s*", "", line).strip()  # lines of the check file
            if line:
                report.unsupported(where, f"cia402 section: hild check refuses it: {line}")
        return
    for note in loaded.notes:
        if note.startswith("warning"):
            text = re.sub(rf"^{re.escape(str(check))}(:\d+)?:\s*", "", note.removeprefix("warning:").strip())
            report.approximated(where, f"cia402 section: hild check warns: {text}")
    report.mapped(where, "cia402 section: passes `hild check` in place of the twin")


@contextlib.contextmanager
def _mujoco_refusal(robot: Robot, label: str, staging: Path) -> Iterator[None]:
    """MuJoCo's ValueError on the staged twin becomes an ImportFailure at the source line it is about."""
    try:
        yield
    except ValueError as exc:
        raise _refused(exc, robot, label, staging) from None


def _refused(exc: ValueError, robot: Robot, label: str, staging: Path) -> ImportFailure:
    """MuJoCo's refusal of the twin's URDF, at the line of the element it names — never the staging file, which
    is gone by the time anyone reads the message."""
    detail = str(exc).split("MuJoCo could not load it: ", 1)[-1].removeprefix("Error: ")
    detail = detail.replace(f"{staging}/", "")
    found = re.search(r"\nElement name '([^']*)'", detail)
    detail = " ".join(detail.split("\nElement name")[0].split())
    where, element = SourceRef(label), ""
    if found is not None:
        name = found.group(1)
        meshes = {Path(m.filename).stem: m.where for link in robot.links.values() for m in link.meshes}
        if "mesh" in detail.lower() or "stl" in detail.lower() or "obj" in detail.lower():
            candidates = [("mesh", meshes), ("link", {n: k.where for n, k in robot.links.items()})]
        else:
            candidates = [("link", {n: k.where for n, k in robot.links.items()}), ("mesh", meshes)]
        candidates.append(("joint", {n: j.where for n, j in robot.joints.items()}))
        for kind, table in candidates:
            if name in table:
                where, element = table[name], f" ({kind} {name!r})"
                break
    return where.fail(f"the twin cannot use this URDF{element}: MuJoCo refuses it: {detail}")


def _robot_name(name: str) -> str:
    """hild robot names are Zenoh key parts: letters, digits, _ and -."""
    return re.sub(r"[^A-Za-z0-9_\-]+", "_", name).strip("_") or "robot"


def _complete_grippers(
    plan: ctl.ControllersPlan, joints: list[mapping.JointPlan], twin_urdf: Path, report: Report
) -> None:
    """A gripper's open and closed ends (from the twin: where its fingers come together), its max_effort within its
    joint's effort limit, and its joint stiff enough to press with it."""
    by_name = {j.name: j for j in joints}
    for controller in plan.controllers:
        if controller.type != "parallel_gripper":
            continue
        params = controller.params
        j = by_name[params["joint"]]
        effort = params.get("max_effort", GRIPPER_DEFAULT_EFFORT)
        if effort > j.effort:
            effort = params["max_effort"] = j.effort
            report.approximated(
                controller.where,
                f"{controller.name}: max_effort (given or parallel_gripper's default {GRIPPER_DEFAULT_EFFORT:g}) "
                f"above {j.name}'s effort limit → {effort:g}",
            )
        if params.get("max_velocity", 0.1) > j.velocity:
            params["max_velocity"] = j.velocity
            report.approximated(controller.where, f"{controller.name}: max_velocity → {j.name}'s limit {j.velocity:g}")
        lower, upper = j.lower + j.soft_margin, j.upper - j.soft_margin
        at_lower, at_upper = finger_spread(twin_urdf, j.name, [lower, upper])
        closed, opened = (upper, lower) if at_upper < at_lower else (lower, upper)
        params["closed_position"], params["open_position"] = closed, opened
        end = "upper" if closed == upper else "lower"
        report.approximated(
            controller.where,
            f"{controller.name}: closes toward {j.name}'s {end} limit (on the twin its fingers come together there: "
            f"{min(at_lower, at_upper) * 1000:.3g} mm apart against {max(at_lower, at_upper) * 1000:.3g}): "
            f"closed_position {closed:g}, open_position {opened:g}",
        )
        limits = GainLimits(j.velocity, j.effort, j.soft_margin, 1.0 / plan.update_rate)
        stiffer = grasp_gains(
            j.name, j.kp, j.lower, j.upper, limits, j.inertia, effort, j.where, controller.name, report
        )
        if stiffer is not None:
            j.kp, j.kd = stiffer
            j.gains_from = f"stiff enough for {controller.name}'s max_effort"


def _complete_effort_gains(plan: ctl.ControllersPlan, joints: list[mapping.JointPlan], report: Report) -> None:
    """An effort trajectory controller needs a PID per joint and a bounded integral, and gravity on top of its
    effort: a ROS effort PID relies on the robot's driver (or a simulator's) to carry the arm's weight."""
    by_name = {j.name: j for j in joints}
    for controller in plan.controllers:
        params = controller.params
        if params.get("command_interfaces") != ["effort"]:
            continue
        params["gravity_compensation"] = True
        report.approximated(controller.where, f"{controller.name}: {GRAVITY_ON_EFFORT}")
        gains = {}
        for joint in params["joints"]:
            pid = controller.pid.get(joint)
            j = by_name[joint]
            if pid is None:
                gains[joint] = {"p": j.kp, "d": j.kd}
                report.approximated(
                    controller.where,
                    f"{controller.name}: no gains for {joint} (ROS: p = 0) → the hold gains p {j.kp:g}, d {j.kd:g}",
                )
                continue
            if pid.i > 0 and pid.i_clamp is None:
                pid.i_clamp = j.effort
                report.approximated(pid.where, f"{controller.name}: {joint} integral bounded to ±{j.effort:g} N·m")
            gains[joint] = pid.params()
        params["gains"] = gains
