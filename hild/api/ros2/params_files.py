"""A controller's section of ROS 2 parameter files, read on the robot PC, as the hild ``params`` of a load.

The spawner hands the controller manager absolute paths (``<c>.params_file``); ros2_control's manager reads them on
its own machine, so hild reads them on the robot PC: the same path must exist there. A ROS parameter file holds
``<node>: {ros__parameters: {...}}``; the controller's node is matched as ROS matches it (``<c>``, ``/<c>``,
``<namespace>/<c>``, ``/**/<c>``, and the wildcard ``/**``, least specific first), later files overriding earlier
ones parameter by parameter. Nested mappings and dotted keys are the same parameters (``constraints: {goal_time:
1}`` is ``constraints.goal_time``), as in ROS and in hild's params.

Keys that belong to the manager or to every ROS node, not to the controller, are left out: ``type`` and
``fallback_controllers`` (the spawner sets them on the manager from the same section), ``use_sim_time`` (hild's
controllers run on the cycle's clock, the config's ``clock``). Everything else is the controller's hild params,
checked by hild's load as any other: a ROS-only parameter is refused by name.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hild.config.documents import DocumentError, load_document, read_text

ROS_PARAMETERS = "ros__parameters"
WILDCARD = "/**"
NOT_PARAMS = frozenset({"type", "fallback_controllers", "use_sim_time"})
MAX_FILE_BYTES = 1 << 20  # a controllers.yaml is a few kB
SUFFIXES = (".yaml", ".yml")


def _flatten(params: dict[str, Any], prefix: str, out: dict[str, Any]) -> None:
    for key, value in params.items():
        path = f"{prefix}{key}"
        if isinstance(value, dict) and value:
            _flatten(value, f"{path}.", out)
        else:
            out[path] = value


def _nest(flat: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for path, value in flat.items():
        node = out
        *parents, last = path.split(".")
        for part in parents:
            child = node.setdefault(part, {})
            if not isinstance(child, dict):
                raise ValueError(f"parameter {path!r}: {part!r} is also a value")
            node = child
        node[last] = value
    return out


def _sections(document: dict[str, Any], controller: str, node: str) -> list[Any]:
    """The node sections that apply to ``node`` (``/ns/controller``), least specific first."""
    wildcard = document.get(WILDCARD)
    found = []
    if isinstance(wildcard, dict):
        found.append(wildcard)
        found.append(wildcard.get(controller))
        found.append(wildcard.get(node))
    for key in (f"{WILDCARD}/{controller}", f"{WILDCARD}{node}", controller, f"/{controller}", node):
        found.append(document.get(key))
    unique = []
    for section in found:
        if isinstance(section, dict) and ROS_PARAMETERS in section and all(section is not s for s in unique):
            unique.append(section)
    return unique


def read_document(path: str) -> dict[str, Any]:
    """One parameter file; ValueError naming the file and what is wrong with it."""
    file = Path(path)
    if not file.is_absolute() or file.suffix not in SUFFIXES:
        raise ValueError(f"{path}: a params_file is an absolute path to a .yaml file")
    try:
        size = file.stat().st_size
    except OSError as exc:
        raise ValueError(f"{path}: cannot read it on the robot PC: {exc.strerror or exc}") from None
    if size > MAX_FILE_BYTES:
        raise ValueError(f"{path}: {size} bytes; a params_file has at most {MAX_FILE_BYTES}")
    try:
        document = load_document(file, read_text(file))
    except DocumentError as exc:
        raise ValueError(f"cannot read it on the robot PC: {exc}") from None
    if not isinstance(document, dict):
        raise ValueError(f"{path}: not a ROS parameter file (expected <node>: {{{ROS_PARAMETERS}: ...}})")
    return document


def controller_params(paths: list[str], controller: str, node: str) -> dict[str, Any]:
    """The merged ``ros__parameters`` for ``controller`` (its node ``node``, fully qualified) from ``paths``, as
    hild params; ValueError (the reason, naming the file) when a file cannot be read or none has its section."""
    merged: dict[str, Any] = {}
    matched = False
    for path in paths:
        for section in _sections(read_document(path), controller, node):
            params = section[ROS_PARAMETERS] or {}
            if not isinstance(params, dict):
                raise ValueError(f"{path}: {ROS_PARAMETERS} of {controller} is not a mapping")
            matched = True
            _flatten(params, "", merged)
    if paths and not matched:
        expected = f"{controller}: {{{ROS_PARAMETERS}: ...}}"
        raise ValueError(f"no parameters for {controller} in {', '.join(paths)} (expected {expected})")
    return _nest({path: value for path, value in merged.items() if path.split(".")[0] not in NOT_PARAMS})
