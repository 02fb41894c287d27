"""ROS parameter files as a launch file hands them to ROS: substitutions first, then every file merged in order.

* **Substitutions.** A launch file may pass a parameter file with substitutions allowed; ``$(var NAME)`` then takes
  the launch argument's value (``--arg NAME=VALUE``). The text is substituted before it is parsed, as ROS does, and
  within its line, so every line number still points into the file as written. A ``$(var NAME)`` without a value
  stops the import with its line; other substitutions (``$(find-pkg-share ...)``, ``$(env ...)``) are left as
  they are and reported, since no hild parameter needs them.
* **Merging.** ROS applies parameter files in the order given: for the same node a later file overrides an earlier
  one parameter by parameter (nested mappings are parameter namespaces; a list is one value). Nodes are named by
  their base name (``/robot1/controller_manager`` and ``controller_manager`` are one node); ``/**`` is kept as
  the wildcard node ``**``.
* **Repeated keys.** A file may give the same node twice (``/**:`` three times at its top): ROS's parameter parser
  applies the blocks in order, as it would separate files, so they are merged the same way and the report says so.
  (``yaml.safe_load`` keeps the last block only: every controller of the others was lost.)
* **Lines.** Every value remembers the file and line that set it last (:meth:`ParamTree.ref`).

A file with no ``ros__parameters`` anywhere is the ROS 1 layout (``gazebo_ros_control``): such files are merged
as whole documents instead, and the two layouts never mix.
"""

from __future__ import annotations

import re
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hild.config.documents import DocumentError, KeyPath, load_document_lines, read_text, repeated_keys
from hild.importers.ros2_control.report import ImportFailure, Report, SourceRef

WILDCARD = "**"


_SUBSTITUTION = re.compile(r"\$\(\s*([A-Za-z][\w-]*)\s*([^()]*?)\s*\)")


@dataclass
class ParamTree:
    """The merged parameters: ``nodes`` for ROS 2 files, ``document`` for ROS 1 files, and where each value was set."""

    files: tuple[Path, ...]
    nodes: dict[str, dict[str, Any]] = field(default_factory=dict)  # node base name → its merged parameters
    document: dict[str, Any] | None = None  # ROS 1: the merged documents
    lines: dict[KeyPath, SourceRef] = field(default_factory=dict)  # (node, *keys) or the ROS 1 key path

    def ref(self, path: KeyPath) -> SourceRef:
        """Where the value at ``path`` was set; the nearest enclosing key that was, or the first file."""
        while path and path not in self.lines:
            path = path[:-1]
        return self.lines.get(path, SourceRef(str(self.files[0]), 1))


def read_param_files(
    paths: Sequence[Path], variables: Mapping[str, str], report: Report, namespace: str | None = None
) -> ParamTree:
    """Read, substitute and merge ``paths`` in order; raises ImportFailure (with file:line) on bad input.

    ``namespace``: the robot whose nodes to read when the files give several robots' (``/leader/…``,
    ``/follower/…``); by default the first one given, said in the report. Nodes at the root and under ``/**`` apply
    to every robot."""
    if not paths:
        raise ImportFailure("no controllers file given")
    tree = ParamTree(tuple(paths))
    loaded = [_load(path, variables, report) for path in paths]
    chosen = _robot_namespace(loaded, namespace, report)
    layouts = [(path, _has_ros2_nodes(data)) for path, data, _ in loaded]
    for (_, data, where), (_, ros2) in zip(loaded, layouts, strict=True):
        if ros2:
            for (node, node_path), params in _ros2_nodes(data, ()):
                if _namespace(node_path) not in ("", WILDCARD, chosen):
                    report.unsupported(
                        where[node_path[:-1]],
                        f"{node!r} under /{_namespace(node_path)}: another robot's namespace, left out "
                        f"(the import reads /{chosen})",
                    )
                    continue
                target = tree.nodes.setdefault(node, {})
                tree.lines[(node,)] = where[node_path[:-1]]
                if not isinstance(params, dict):
                    raise where[node_path].fail(f"ros__parameters of {node!r} must be a mapping")
                _merge(target, params, (node,), node_path, where, tree.lines)
        else:
            tree.document = tree.document if tree.document is not None else {}
            _merge(tree.document, data, (), (), where, tree.lines)
    _check_one_layout(layouts)
    return tree


Loaded = tuple[Path, dict[str, Any], dict[KeyPath, SourceRef]]


def _load(path: Path, variables: Mapping[str, str], report: Report) -> Loaded:
    """One file, substituted and parsed, with where each key is."""
    text = _substitute(path, read_file(path), variables, report)
    try:
        data, lines = load_document_lines(path, text, merge_repeated=True)  # as ROS's parameter parser reads it
    except DocumentError as exc:
        raise ImportFailure(str(exc)) from None
    for key_path, first, line in repeated_keys(text):
        report.mapped(
            SourceRef(str(path), line),
            f"{'.'.join(map(str, key_path))!r} repeated (first at line {first}): merged with it block by block, "
            "as ROS applies it",
        )
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise SourceRef(str(path), 1).fail("expected a mapping of ROS nodes (controller_manager: ros__parameters:)")
    return path, data, {key: SourceRef(str(path), line) for key, line in lines.items()}


def _namespace(node_path: KeyPath) -> str:
    """The namespace of the node whose ``ros__parameters`` are at ``node_path`` (``leader`` for
    ``/leader/controller_manager`` or ``/leader: controller_manager:``); ``**`` under a wildcard; ``""`` at the root."""
    parts = [p for key in node_path[:-1] for p in str(key).strip("/").split("/") if p]
    return WILDCARD if WILDCARD in parts[:-1] else "/".join(parts[:-1])


def _robot_namespace(loaded: Sequence[Loaded], asked: str | None, report: Report) -> str:
    """The namespace whose nodes are read: ``asked``, or the first of several, said in the report."""
    first_seen: dict[str, SourceRef] = {}
    for _, data, where in loaded:
        for (_, node_path), _ in _ros2_nodes(data, ()):
            ns = _namespace(node_path)
            if ns not in ("", WILDCARD):
                first_seen.setdefault(ns, where[node_path[:-1]])
    if asked is not None:
        asked = asked.strip("/")
        if asked not in first_seen:
            given = ", ".join(f"/{ns}" for ns in first_seen) or "none"
            raise ImportFailure(f"--namespace /{asked}: no node of the controller files is under it (given: {given})")
        return asked
    if not first_seen:
        return ""
    chosen, where = next(iter(first_seen.items()))
    if len(first_seen) > 1:
        report.approximated(
            where,
            f"the controller files give {len(first_seen)} robots' namespaces "
            f"({', '.join(f'/{ns}' for ns in first_seen)}): the import reads /{chosen}, the first "
            "(--namespace NAME chooses)",
        )
    return chosen


def read_file(path: Path) -> str:
    try:
        return read_text(path)
    except DocumentError as exc:
        raise ImportFailure(str(exc)) from None


def _check_one_layout(layouts: list[tuple[Path, bool]]) -> None:
    ros2 = [p for p, is_ros2 in layouts if is_ros2]
    ros1 = [p for p, is_ros2 in layouts if not is_ros2]
    if ros1 and ros2:
        raise ImportFailure(
            f"{ros1[0]}: a ROS 1 controller file (no ros__parameters) cannot be merged with the ROS 2 parameter "
            f"file {ros2[0]}: give the files of one robot description"
        )


def _substitute(path: Path, text: str, variables: Mapping[str, str], report: Report) -> str:
    """``$(var NAME)`` → its value, line by line; other substitutions stay and are reported."""
    out = []
    for number, line in enumerate(text.splitlines(keepends=True), start=1):
        out.append(_substitute_line(SourceRef(str(path), number), line, variables, report))
    return "".join(out)


def _substitute_line(where: SourceRef, line: str, variables: Mapping[str, str], report: Report) -> str:
    def value(match: re.Match[str]) -> str:
        kind, argument = match.group(1), match.group(2)
        if kind != "var":
            report.unsupported(where, f"launch substitution {match.group(0)} is left as it is (hild reads $(var ...))")
            return match.group(0)
        if argument not in variables:
            raise where.fail(
                f"$(var {argument}) has no value: pass --arg {argument}=VALUE (the launch file's argument)"
            )
        return variables[argument]

    return _SUBSTITUTION.sub(value, line) if "$(" in line else line


def _has_ros2_nodes(data: Mapping[str, Any]) -> bool:
    return any(True for _ in _ros2_nodes(data, ()))


def _ros2_nodes(data: Mapping[str, Any], path: KeyPath) -> Iterator[tuple[tuple[str, KeyPath], Any]]:
    """``((node base name, key path of its ros__parameters), params)`` for every node, however namespaced."""
    for key, value in data.items():
        if not isinstance(value, dict):
            continue
        here = (*path, str(key))
        if "ros__parameters" in value:
            base = str(key).strip("/").split("/")[-1]
            yield (base or WILDCARD, (*here, "ros__parameters")), value["ros__parameters"] or {}
        else:
            yield from _ros2_nodes(value, here)


def _merge(
    target: dict[str, Any],
    source: Mapping[str, Any],
    at: KeyPath,
    source_at: KeyPath,
    where: Mapping[KeyPath, SourceRef],
    lines: dict[KeyPath, SourceRef],
) -> None:
    """Deep-merge ``source`` into ``target`` (a later value wins; mappings merge key by key), recording lines."""
    for key, value in source.items():
        here, there = (*at, str(key)), (*source_at, str(key))
        if isinstance(value, dict) and isinstance(target.get(key), dict):
            lines[here] = where[there]
            _merge(target[key], value, here, there, where, lines)
            continue
        for stale in [k for k in lines if k[: len(here)] == here]:  # an overridden value's lines go with it
            del lines[stale]
        target[key] = _copy(value)
        for key_path, ref in where.items():
            if key_path[: len(there)] == there:
                lines[(*here, *key_path[len(there) :])] = ref


def _copy(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _copy(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_copy(v) for v in value]
    return value
