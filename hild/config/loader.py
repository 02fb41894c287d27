"""Load and check a robot config: YAML → schema → plugin parameters → cross-references.

Every problem is collected (not just the first) and reported as ``file:line: key.path: what was expected, what
was found``, so one ``hild check`` run shows all that is wrong with a file.

Whatever the file holds, loading ends in a config or a ConfigError, quickly: bytes that are not UTF-8, nesting
deeper than ``MAX_DEPTH`` (checked on the parser's flat event stream, before the recursive composer sees it),
aliases that expand past ``MAX_NODES`` values (a "billion laughs"), integers too long to read, and keys that are
not scalars are all reported with their line.
"""

from __future__ import annotations

import types
import typing
from collections.abc import Callable, Collection
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ValidationError

from hild import plugins
from hild.config.model import ControllerSection, RobotConfig
from hild.config.params import Params
from hild.config.safety import review_safety
from hild.crossing.cyclelog import MAX_BYTES as CYCLE_LOG_MAX_BYTES
from hild.crossing.cyclelog import capacity_of, cycle_log_bytes
from hild.hardware import BusUsage
from hild.interfaces import FIELDS, ClaimError, SensorLayout, interface_name, parse_interface

Loc = tuple[str | int, ...]
Report = Callable[[Loc, str], None]  # (where in the file, what is wrong)
_UNION_TYPES = (typing.Union, types.UnionType)
MAX_DEPTH = 64  # nested mappings/sequences; a robot config needs about 8
MAX_NODES = 100_000  # values after alias expansion; a robot config has about a thousand


@dataclass(frozen=True)
class ConfigIssue:
    file: str
    line: int | None
    path: str
    message: str

    def __str__(self) -> str:
        where = f"{self.file}:{self.line}" if self.line else self.file
        return f"{where}: {self.path or '<top>'}: {self.message}"


class ConfigError(ValueError):
    def __init__(self, issues: list[ConfigIssue]) -> None:
        self.issues = issues
        super().__init__("\n".join(str(i) for i in issues))


@dataclass
class LoadedConfig:
    """A validated config plus the plugin classes and parameter objects it names."""

    path: Path
    config: RobotConfig
    driver_classes: dict[str, type] = field(default_factory=dict)
    driver_params: dict[str, Params] = field(default_factory=dict)
    controller_classes: dict[str, type] = field(default_factory=dict)
    controller_params: dict[str, Params] = field(default_factory=dict)
    sensor_params: dict[str, dict[str, Params]] = field(default_factory=dict)  # component → sensor → its params
    notes: list[str] = field(default_factory=list)  # warnings and figures for `hild check` (e.g. bus load)
    # The file as it was named and where each key sits in it, kept so checks that run after loading (``hild
    # check``'s model review) name file:line as the loader's own findings do.
    file: str = ""
    lines: dict[Loc, int] = field(default_factory=dict, repr=False)

    def issue(self, loc: Loc, message: str) -> ConfigIssue:
        """A finding at config key ``loc``, located like the loader's own."""
        return ConfigIssue(self.file or str(self.path), _line(self.lines, loc), _fmt(loc), message)

    @property
    def directory(self) -> Path:
        return self.path.parent

    def in_lockstep(self) -> LoadedConfig:
        """This config on the sim clock at no real-time pacing: the cycle steps as fast as it computes, the twin
        inside each cycle, deterministic (tests, benches, offline replays). Changes it in place; returns it."""
        clock = self.config.clock.model_copy(update={"source": "sim", "real_time_factor": 0.0})
        self.config = self.config.model_copy(update={"clock": clock})
        return self

    @property
    def recording_dir(self) -> Path:
        """``recording.dir``, absolute (a relative one is beside the config file)."""
        return (self.directory / Path(self.config.recording.dir).expanduser()).resolve()

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(self.config.joints)

    def summary(self) -> str:
        c = self.config
        lines = [
            f"{self.path}: robot {c.robot.name!r} at {c.update_rate:g} Hz, {c.clock.source} clock",
            f"  joints ({len(c.joints)}): {', '.join(c.joints)}",
        ]
        for name, hw in c.hardware.items():
            lines.append(f"  hardware {name}: driver {hw.driver}, joints {', '.join(hw.joints)}")
            for sensor, spec in hw.sensors.items():
                ranges = ", ".join(f"{k} {v:g}" for k, v in spec.limits.ranges(spec.type).items())
                lines.append(f"    sensor {sensor}: {spec.type} in {spec.frame_id} ({ranges})")
        for name, ctl in c.controllers.items():
            auto = " (autostart)" if ctl.autostart else ""
            chain = f", chained to {ctl.chain_to}" if ctl.chain_to else ""
            lines.append(f"  controller {name}: {ctl.type}{chain}{auto}")
        lines.append(f"  zenoh: {c.zenoh.mode}, listen {c.zenoh.listen or '[]'}, connect {c.zenoh.connect or '[]'}")
        lines.extend(f"  {note}" for note in self.notes)
        return "\n".join(lines)


# ---- YAML with line numbers ---------------------------------------------------------------------------------


class _Loader(yaml.SafeLoader):
    """SafeLoader whose integers too long for ``int()`` (over 4300 digits) are a YAML error with a line."""

    def construct_yaml_int(self, node: yaml.ScalarNode) -> int:
        try:
            return super().construct_yaml_int(node)  # type: ignore[no-any-return]
        except ValueError as exc:
            message = f"cannot read the integer: {exc}"
            raise yaml.constructor.ConstructorError(None, None, message, node.start_mark) from None


_Loader.add_constructor("tag:yaml.org,2002:int", _Loader.construct_yaml_int)


def _parse(text: str, file: str, issues: list[ConfigIssue]) -> tuple[Any, dict[Loc, int]]:
    """Check the depth on the parser's flat event stream (PyYAML's composer recurses, and a deep document would
    exhaust the stack), compose once, map the lines (refusing bombs and complex keys), build the data from the same
    nodes. YAMLError for what PyYAML refuses; ConfigError for the rest."""
    _check_depth(text, file)
    loader = _Loader(text)
    try:
        root = loader.get_single_node()
        lines = _line_map(root, file, issues)
        if issues:  # keys that are not plain values: the constructor would only say "unhashable"
            raise ConfigError(issues)
        return (None if root is None else loader.construct_document(root)), lines
    finally:
        loader.dispose()


def _check_depth(text: str, file: str) -> None:
    depth = 0
    for event in yaml.parse(text, Loader=yaml.SafeLoader):
        if isinstance(event, yaml.MappingStartEvent | yaml.SequenceStartEvent):
            depth += 1
            if depth > MAX_DEPTH:
                raise ConfigError(
                    [ConfigIssue(file, event.start_mark.line + 1, "", f"nested deeper than {MAX_DEPTH} levels")]
                )
        elif isinstance(event, yaml.MappingEndEvent | yaml.SequenceEndEvent):
            depth -= 1


_BOMB = f"the document expands to more than {MAX_NODES} values (aliases of aliases: a YAML bomb?)"


def _line_map(root: yaml.Node | None, file: str, issues: list[ConfigIssue]) -> dict[Loc, int]:
    """Map every key path to its 1-based line; report duplicate keys (PyYAML would silently keep the last).

    Aliases are followed, so this walk is also where an alias bomb is caught: it stops at MAX_NODES values."""
    lines: dict[Loc, int] = {}
    visited = 0

    def walk(node: yaml.Node, loc: Loc) -> None:
        nonlocal visited
        visited += 1
        if visited > MAX_NODES:
            raise ConfigError([ConfigIssue(file, node.start_mark.line + 1, _fmt(loc), _BOMB)])
        lines[loc] = node.start_mark.line + 1
        if isinstance(node, yaml.MappingNode):
            seen: set[str] = set()
            for key, value in node.value:
                if not isinstance(key, yaml.ScalarNode):
                    issues.append(ConfigIssue(file, key.start_mark.line + 1, _fmt(loc), "a key must be a plain value"))
                    continue
                name = key.value
                if name in seen:
                    issues.append(ConfigIssue(file, key.start_mark.line + 1, _fmt((*loc, name)), "duplicate key"))
                seen.add(name)
                lines[(*loc, name)] = key.start_mark.line + 1
                walk(value, (*loc, name))
                lines[(*loc, name)] = key.start_mark.line + 1
        elif isinstance(node, yaml.SequenceNode):
            for i, item in enumerate(node.value):
                walk(item, (*loc, i))

    if root is not None:
        walk(root, ())
    return lines


def _fmt(loc: Loc) -> str:
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out


def _line(lines: dict[Loc, int], loc: Loc) -> int | None:
    while loc not in lines and loc:
        loc = loc[:-1]
    return lines.get(loc)


def _found(value: Any) -> str:
    text = repr(value)
    if len(text) > 60:
        text = text[:57] + "..."
    return f"{text} ({type(value).__name__})"


def _allowed_keys(model: type[BaseModel], loc: Loc) -> list[str] | None:
    """Walk the schema along ``loc`` (a path to an unknown key) and list the keys its parent allows."""
    current: Any = model
    for part in loc[:-1]:
        if isinstance(current, type) and issubclass(current, BaseModel):
            info = current.model_fields.get(str(part))
            if info is None:
                return None
            current = info.annotation
        else:  # dict[str, X], list[X] or X | None: step into the value type
            args = [a for a in typing.get_args(current) if a is not type(None)]
            if not args:
                return None
            current = args[-1]
        while typing.get_origin(current) in _UNION_TYPES:
            current = next(a for a in typing.get_args(current) if a is not type(None))
    if isinstance(current, type) and issubclass(current, BaseModel):
        return list(current.model_fields)
    return None


def _pydantic_issues(
    exc: ValidationError, model: type[BaseModel], prefix: Loc, file: str, lines: dict[Loc, int]
) -> list[ConfigIssue]:
    issues = []
    for err in exc.errors():
        loc = prefix + tuple(err["loc"])
        kind = err["type"]
        if kind == "missing":
            message = "missing required key"
        elif kind == "extra_forbidden":
            allowed = _allowed_keys(model, tuple(err["loc"]))
            message = "unknown key" + (f" (allowed: {', '.join(allowed)})" if allowed else "")
        else:
            msg = err["msg"].removeprefix("Value error, ")
            message = f"expected: {msg[0].lower() + msg[1:]}; found {_found(err['input'])}"
        issues.append(ConfigIssue(file, _line(lines, loc), _fmt(loc), message))
    return issues


# ---- the loader ---------------------------------------------------------------------------------------------


def load_config(path: str | Path) -> LoadedConfig:
    """Load, validate and cross-check a robot config; raises ConfigError listing every problem."""
    path = Path(path)
    file = str(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ConfigError([ConfigIssue(file, None, "", f"cannot read the file: {exc.strerror or exc}")]) from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise ConfigError([ConfigIssue(file, line, "", f"not UTF-8 text: {exc.reason} at byte {exc.start}")]) from None
    issues: list[ConfigIssue] = []
    try:
        data, lines = _parse(text, file, issues)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = mark.line + 1 if mark else None
        if isinstance(exc, yaml.reader.ReaderError):  # a character YAML does not allow: it has a position only
            line = text.count("\n", 0, exc.position) + 1
        raise ConfigError([ConfigIssue(file, line, "", f"not valid YAML: {exc}")]) from None
    if not isinstance(data, dict):
        raise ConfigError([ConfigIssue(file, 1, "", f"expected: a mapping at the top; found {_found(data)}")])
    try:
        config = RobotConfig.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(issues + _pydantic_issues(exc, RobotConfig, (), file, lines)) from None

    loaded = LoadedConfig(path=path.resolve(), config=config, file=file, lines=lines)
    for check in (_load_plugins, _cross_check, _review_hardware, _review_safety):
        check(loaded, issues)
    if issues:
        raise ConfigError(issues)
    return loaded


def _load_plugins(loaded: LoadedConfig, issues: list[ConfigIssue]) -> None:
    c = loaded.config
    groups = (
        (
            "hardware",
            plugins.DRIVERS,
            {n: (h.driver, h.params) for n, h in c.hardware.items()},
            "driver",
            loaded.driver_classes,
            loaded.driver_params,
        ),
        (
            "controllers",
            plugins.CONTROLLERS,
            {n: (s.type, s.params) for n, s in c.controllers.items()},
            "type",
            loaded.controller_classes,
            loaded.controller_params,
        ),
    )
    for section, group, entries, key, classes, params in groups:
        for name, (plugin_name, raw) in entries.items():
            try:
                cls = plugins.load(group, plugin_name)
            except plugins.PluginError as exc:
                issues.append(loaded.issue((section, name, key), str(exc)))
                continue
            classes[name] = cls
            try:
                params[name] = cls.Params.model_validate(raw)
            except ValidationError as exc:
                issues.extend(_pydantic_issues(exc, cls.Params, (section, name, "params"), loaded.file, loaded.lines))
    for name, hw in c.hardware.items():
        if name in loaded.driver_classes:
            _load_sensor_params(loaded, name, hw, issues)


def _load_sensor_params(loaded: LoadedConfig, name: str, hw: Any, issues: list[ConfigIssue]) -> None:
    """Each sensor of component ``name``: a type its driver reads, and params its driver's SensorParams take."""
    cls = loaded.driver_classes[name]
    types_ = frozenset(getattr(cls, "SENSOR_TYPES", frozenset()))
    sensor_params = loaded.sensor_params.setdefault(name, {})
    for sensor, spec in hw.sensors.items():
        loc = ("hardware", name, "sensors", sensor)
        if spec.type not in types_:
            reads = f"it reads {', '.join(sorted(types_))} sensors only" if types_ else "it reads no sensors"
            issues.append(
                loaded.issue((*loc, "type"), f"driver {hw.driver!r} cannot read a {spec.type} sensor: {reads}")
            )
            continue
        try:
            sensor_params[sensor] = cls.SensorParams.model_validate(spec.params)
        except ValidationError as exc:
            issues.extend(_pydantic_issues(exc, cls.SensorParams, (*loc, "params"), loaded.file, loaded.lines))


def _cross_check(loaded: LoadedConfig, issues: list[ConfigIssue]) -> None:
    """What no single section can check alone: joints against hardware, files, controllers against drivers."""

    def report(loc: Loc, message: str) -> None:
        issues.append(loaded.issue(loc, message))

    owner = _joint_owners(loaded.config, report)
    _check_mimic_joints(loaded.config, report)
    _check_sensor_names(loaded.config, report)
    _check_files(loaded, report)
    _check_controllers(loaded, owner, report)
    _check_contact(loaded.config, report)
    _check_recording(loaded, report)


def _check_recording(loaded: LoadedConfig, report: Report) -> None:
    """The cycle log fits the shared region, and recording.dir is a directory if it exists."""
    c = loaded.config
    if not c.recording.enabled:
        return
    capacity = capacity_of(c)
    nbytes = cycle_log_bytes(len(c.joints), capacity)
    if nbytes > CYCLE_LOG_MAX_BYTES:
        report(
            ("recording", "blackbox_seconds"),
            f"the cycle log would take {nbytes / 2**20:.0f} MiB ({capacity} cycles of {len(c.joints)} joints at "
            f"{c.update_rate:g} Hz); at most {CYCLE_LOG_MAX_BYTES / 2**20:.0f} MiB: keep fewer seconds",
        )
    where = loaded.recording_dir
    if where.exists() and not where.is_dir():
        report(("recording", "dir"), f"not a directory: {where}")


def _check_contact(c: RobotConfig, report: Report) -> None:
    """safety.contact names robot joints, needs a model, and its observer must be stable at the update rate."""
    contact = c.safety.contact
    for joint in contact.joints:
        if joint not in c.joints:
            report(("safety", "contact", "joints", joint), f"joint {joint!r} is not defined under joints")
    if not contact.enabled:
        return
    if not c.robot.model:
        report(("safety", "contact", "enabled"), "the contact observer needs robot.model (the arm's dynamics)")
    if contact.observer_gain / c.update_rate >= 1.0:
        report(
            ("safety", "contact", "observer_gain"),
            f"{contact.observer_gain:g}/s at {c.update_rate:g} Hz: gain × period must stay below 1 "
            f"(use a gain below {c.update_rate:g}/s)",
        )


def _joint_owners(c: RobotConfig, report: Report) -> dict[str, str]:
    """Each joint's hardware component; a joint with none, two, or no definition is reported."""
    owner: dict[str, str] = {}
    for hw_name, hw in c.hardware.items():
        for joint in hw.joints:
            loc = ("hardware", hw_name, "joints", joint)
            if joint not in c.joints:
                report(loc, f"joint {joint!r} is not defined under joints (defined: {', '.join(c.joints)})")
            elif joint in owner:
                report(loc, f"joint {joint!r} already belongs to hardware {owner[joint]!r}; each joint has one")
            else:
                owner[joint] = hw_name
    for joint in c.joints:
        if joint not in owner:
            report(("joints", joint), f"joint {joint!r} belongs to no hardware component")
    return owner


def _check_mimic_joints(c: RobotConfig, report: Report) -> None:
    """Each mimic joint follows a robot joint (not another mimic joint: give the composed multiplier and offset)
    and is not itself a robot joint."""
    for name, mimic in c.mimic_joints.items():
        if name in c.joints:
            report(("mimic_joints", name), f"{name!r} is also a joint under joints: a mimic joint is not commanded")
        followed = mimic.joint
        if followed in c.joints:
            continue
        loc = ("mimic_joints", name, "joint")
        if followed in c.mimic_joints:
            hint = ""
            first = c.mimic_joints[followed]
            if first.joint in c.joints:
                multiplier = mimic.multiplier * first.multiplier
                offset = mimic.multiplier * first.offset + mimic.offset
                hint = f": follow {first.joint!r} with multiplier {multiplier:g} and offset {offset:g}"
            report(loc, f"{followed!r} is a mimic joint itself; a mimic joint follows a robot joint{hint}")
        else:
            report(loc, f"joint {followed!r} is not defined under joints (defined: {', '.join(c.joints)})")


def _check_sensor_names(c: RobotConfig, report: Report) -> None:
    """A sensor's name is unique across the robot and never a joint's: its interfaces share their namespace."""
    seen: dict[str, str] = {}
    for hw_name, hw in c.hardware.items():
        for sensor in hw.sensors:
            loc = ("hardware", hw_name, "sensors", sensor)
            if sensor in c.joints:
                report(loc, f"sensor {sensor!r} has a joint's name; sensors and joints need names of their own")
            elif sensor in seen:
                report(loc, f"sensor {sensor!r} is already declared under hardware {seen[sensor]!r}; names are unique")
            seen.setdefault(sensor, hw_name)


def _check_files(loaded: LoadedConfig, report: Report) -> None:
    """The robot model, the URDF ROS 2 is given, and every file a driver names exist (relative to the config)."""
    c = loaded.config
    named = {("robot", "model"): c.robot.model, ("ros2", "robot_description"): c.ros2 and c.ros2.robot_description}
    for loc, relative in named.items():
        if relative and not (loaded.directory / relative).is_file():
            report(loc, f"file not found: {loaded.directory / relative}")
    for hw_name in c.hardware:
        cls, params = loaded.driver_classes.get(hw_name), loaded.driver_params.get(hw_name)
        if cls is None or params is None:
            continue
        for param, relative in cls.files(params).items():
            if not (loaded.directory / relative).is_file():
                report(("hardware", hw_name, "params", param), f"file not found: {loaded.directory / relative}")


def _check_controllers(loaded: LoadedConfig, owner: dict[str, str], report: Report) -> None:
    """Controllers name known joints, claim what their joints' drivers offer, and never two autostart one claim."""
    c = loaded.config
    available = _available_claims(loaded, owner)
    autostart_claims: dict[str, str] = {}
    for name, spec in c.controllers.items():
        cls, params = loaded.controller_classes.get(name), loaded.controller_params.get(name)
        if cls is None or params is None:
            continue
        claims = _check_controller(loaded, name, cls, params, available, report, chained=spec.chain_to is not None)
        if spec.chain_to is not None:
            claims = _check_chain(loaded, name, spec.chain_to, claims, report)
        if spec.autostart:
            for claim in claims:
                other = autostart_claims.setdefault(claim, name)
                if other != name:
                    report(("controllers", name, "autostart"), f"claims {claim!r} like {other!r}; both autostart")
        _check_fallbacks(name, spec.fallback_controllers, set(c.controllers), report)


def _available_claims(loaded: LoadedConfig, owner: dict[str, str]) -> set[str]:
    """Every command interface the joints' drivers offer."""
    available = set()
    for joint, hw_name in owner.items():
        fields = _joint_fields(loaded, hw_name, joint)
        available.update(interface_name(joint, f) for f in FIELDS if f in fields)
    return available


def _joint_fields(loaded: LoadedConfig, hw_name: str, joint: str) -> Collection[str]:
    """The command fields `joint`'s driver applies: per joint when its params decide (``command_fields``, e.g. a
    CiA 402 drive's mode), else the class's ``COMMAND_FIELDS``."""
    cls, params = loaded.driver_classes.get(hw_name), loaded.driver_params.get(hw_name)
    if cls is None:
        return FIELDS
    if params is not None and hasattr(cls, "command_fields"):
        per_joint = cls.command_fields(params, [joint])
        if joint in per_joint:
            return per_joint[joint]
    return getattr(cls, "COMMAND_FIELDS", FIELDS)


def _check_controller(
    loaded: LoadedConfig,
    name: str,
    cls: Any,
    params: Params,
    available: set[str],
    report: Report,
    *,
    chained: bool = False,
) -> list[str]:
    """One controller's joints, limits and claims against the robot; its claims that parse."""
    c = loaded.config
    limits = {joint: section.limits for joint, section in c.joints.items()}
    owner = {joint: hw for hw, section in c.hardware.items() for joint in section.joints}
    for i, joint in enumerate(cls.joints_for(params)):
        if joint in c.joints:
            continue
        if joint in c.mimic_joints:
            followed = c.mimic_joints[joint].joint
            report(
                ("controllers", name, "params", "joints", i),
                f"{joint!r} is a mimic joint of {followed!r}: it follows that joint and cannot be commanded",
            )
        else:
            report(("controllers", name, "params", "joints", i), f"unknown joint {joint!r}")
    for problem in cls.robot_problems(params, limits):
        report(("controllers", name, "params"), problem)
    sensor_interfaces = set(SensorLayout.of(c).interfaces())
    for read in cls.sensor_interfaces_for(params):
        if read not in sensor_interfaces:
            known = ", ".join(sorted(sensor_interfaces)) or "none: declare sensors under hardware.<component>.sensors"
            report(("controllers", name, "params"), f"reads {read!r}, which no sensor provides (sensor interfaces: "
                   f"{known})")  # fmt: skip
    claims = []
    for claim in cls.claims_for(params):
        try:
            joint, _ = parse_interface(claim)
        except ClaimError as exc:
            report(("controllers", name, "params"), str(exc))
            continue
        claims.append(claim)
        if joint in c.joints and claim not in available and not chained:  # a chained one claims references
            driver = c.hardware[owner[joint]].driver if joint in owner else "?"
            offered = sorted(_joint_fields(loaded, owner[joint], joint)) if joint in owner else []
            report(
                ("controllers", name, "params"),
                f"claims {claim!r}, which driver {driver!r} does not offer (it applies {', '.join(offered)} "
                f"for {joint})",
            )
    return claims


def _check_chain(loaded: LoadedConfig, name: str, following: str, claims: list[str], report: Report) -> list[str]:
    """``controllers.<name>.chain_to``: a chainable controller of this config, no loop, and every claim of ``name``
    one of its reference interfaces. Returns the claims as the manager names them (``<following>/<joint>/<field>``)."""
    c, loc = loaded.config, ("controllers", name, "chain_to")
    redirected = [f"{following}/{claim}" for claim in claims]
    if following == name:
        report(loc, "a controller cannot chain to itself")
        return redirected
    if following not in c.controllers:
        report(loc, f"unknown controller {following!r}")
        return redirected
    seen, hop = {name}, following
    while (hop := c.controllers[hop].chain_to) is not None and hop in c.controllers:
        if hop in seen:
            report(loc, f"the chain from {name} through {following} comes back to {hop}: a chain cannot loop")
            return redirected
        seen.add(hop)
    cls, params = loaded.controller_classes.get(following), loaded.controller_params.get(following)
    if cls is None or params is None:
        return redirected
    exported = set(cls.reference_interfaces_for(params))
    if not exported:
        report(
            loc, f"{following} ({c.controllers[following].type}) exports no reference interfaces: it is not chainable"
        )
        return redirected
    if missing := [claim for claim in claims if claim not in exported]:
        report(loc, f"{following} exports no reference interfaces {missing} (it exports {sorted(exported)})")
    return redirected


def _check_fallbacks(name: str, fallbacks: list[str], known: set[str], report: Report) -> None:
    for i, fallback in enumerate(fallbacks):
        loc = ("controllers", name, "fallback_controllers", i)
        if fallback not in known:
            report(loc, f"unknown controller {fallback!r}")
        elif fallback == name:
            report(loc, "a controller cannot be its own fallback")


@dataclass(frozen=True)
class CheckedController:
    """A controller to load while the robot runs, checked as the config's are."""

    name: str
    type: str
    params: Params
    fallbacks: tuple[str, ...]
    chain_to: str = ""  # the controller whose reference interfaces it claims (``chain_to``), or none


def check_controller(
    loaded: LoadedConfig, name: str, section: Any, loaded_controllers: set[str], source: str
) -> CheckedController:
    """``section`` (a controller's config section: ``type``, ``params``, ``fallback_controllers``) checked against
    this robot the way ``hild check`` checks the config's controllers: its keys, its type, its params, its joints,
    limits and claims, and fallbacks among ``loaded_controllers``. Raises :class:`ConfigError` listing every
    problem, located as ``source: controllers.<name>…``."""
    issues: list[ConfigIssue] = []

    def report(loc: Loc, message: str) -> None:
        issues.append(ConfigIssue(source, None, _fmt(loc), message))

    if isinstance(section, dict) and "autostart" in section:
        report(("controllers", name, "autostart"), "applies when the daemon starts; switch the controller instead")
        section = {k: v for k, v in section.items() if k != "autostart"}
    try:
        spec = ControllerSection.model_validate(section)
    except ValidationError as exc:
        raise ConfigError(
            issues + _pydantic_issues(exc, ControllerSection, ("controllers", name), source, {})
        ) from None
    try:
        cls = plugins.load(plugins.CONTROLLERS, spec.type)
    except plugins.PluginError as exc:
        raise ConfigError([*issues, ConfigIssue(source, None, _fmt(("controllers", name, "type")), str(exc))]) from None
    try:
        params = cls.Params.model_validate(spec.params)
    except ValidationError as exc:
        raise ConfigError(
            issues + _pydantic_issues(exc, cls.Params, ("controllers", name, "params"), source, {})
        ) from None
    owner = {joint: hw for hw, section_ in loaded.config.hardware.items() for joint in section_.joints}
    chained = spec.chain_to is not None
    _check_controller(loaded, name, cls, params, _available_claims(loaded, owner), report, chained=chained)
    _check_fallbacks(name, spec.fallback_controllers, loaded_controllers, report)
    if spec.chain_to == name:
        report(("controllers", name, "chain_to"), "a controller cannot chain to itself")
    elif chained and spec.chain_to not in loaded_controllers:
        report(("controllers", name, "chain_to"), f"unknown controller {spec.chain_to!r}")
    if issues:
        raise ConfigError(issues)
    return CheckedController(name, spec.type, params, tuple(spec.fallback_controllers), spec.chain_to or "")


BUS_LOAD_WARNING = 0.70
BUS_LOAD_LIMIT = 1.00


def _review_hardware(loaded: LoadedConfig, issues: list[ConfigIssue]) -> None:
    """Each driver's own findings, then shared media summed over components: load and identifier overlaps."""
    c = loaded.config
    buses: dict[str, list[tuple[str, BusUsage]]] = {}
    for name, hw in c.hardware.items():
        cls, params = loaded.driver_classes.get(name), loaded.driver_params.get(name)
        if cls is None or params is None:
            continue
        loc = ("hardware", name, "params")
        joints = list(hw.joints)
        findings = cls.review(params, joints, c.update_rate)
        findings += cls.review_files(params, joints, c.update_rate, loaded.directory)
        for finding in findings:
            if finding.level == "error":
                issues.append(loaded.issue(loc, finding.message))
            else:
                loaded.notes.append(f"{finding.level}: hardware {name}: {finding.message}")
        for usage in cls.bus_usage(params, joints, c.update_rate):
            buses.setdefault(usage.bus, []).append((name, usage))
    for bus, users in buses.items():
        seen: dict[int, str] = {}
        for name, usage in users:
            for ident in sorted(usage.ids):
                if ident in seen and seen[ident] != name:
                    message = f"id {ident:#x} on {bus} is also used by hardware {seen[ident]!r}"
                    issues.append(loaded.issue(("hardware", name, "params"), message))
                seen.setdefault(ident, name)
        load = sum(u.bits_per_second for _, u in users) / min(u.capacity for _, u in users)
        text = f"bus {bus}: worst-case load {load:.0%} at {c.update_rate:g} Hz ({', '.join(n for n, _ in users)})"
        if load > BUS_LOAD_LIMIT:
            message = f"{text}: over 100 %, frames would be late every cycle; lower update_rate or split the motors"
            issues.append(loaded.issue(("hardware", users[0][0], "params"), message + " over more buses"))
        elif load > BUS_LOAD_WARNING:
            loaded.notes.append(f"warning: {text}: above {BUS_LOAD_WARNING:.0%}, little headroom for retries")
        else:
            loaded.notes.append(text)


def _review_safety(loaded: LoadedConfig, issues: list[ConfigIssue]) -> None:
    """Unsafe combinations refuse the config; suspicious ones become warnings (hild/config/safety.py)."""
    for finding in review_safety(loaded.config, loaded.driver_classes, loaded.driver_params):
        issue = loaded.issue(finding.loc, finding.message)
        if finding.level == "error":
            issues.append(issue)
        else:
            loaded.notes.append(f"warning: {issue}")


def json_schema() -> dict[str, Any]:
    """JSON Schema of the config file, with each known driver's and controller's params filled in."""
    schema = RobotConfig.model_json_schema()
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["title"] = "hild robot config"
    defs = schema.setdefault("$defs", {})
    for section, group, key in (
        ("HardwareSection", plugins.DRIVERS, "driver"),
        ("ControllerSection", plugins.CONTROLLERS, "type"),
    ):
        variants = []
        for name in plugins.available(group):
            params_schema = plugins.load(group, name).Params.model_json_schema(ref_template="#/$defs/{model}")
            defs.update(params_schema.pop("$defs", {}))
            variants.append(
                {
                    "if": {"properties": {key: {"const": name}}, "required": [key]},
                    "then": {"properties": {"params": params_schema}},
                }
            )
        defs[section]["allOf"] = variants
    return schema
