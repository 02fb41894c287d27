"""Plain YAML/JSON documents that are not robot configs (e.g. a trajectory for ``hild ctl trajectory``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml


class DocumentError(ValueError):
    pass


def load_document(path: str | Path, text: str | None = None, loader: type[yaml.SafeLoader] = yaml.SafeLoader) -> Any:
    """Parse a YAML (or JSON, a subset of YAML) file; errors name the file and line.

    ``text``: the file's content as the caller already has it (e.g. after substitutions), named by ``path``.
    ``loader``: a SafeLoader that reads a foreign format's conventions (e.g. ROS parameter files')."""
    path = Path(path)
    if text is None:
        text = read_text(path)
    try:
        return yaml.load(text, Loader=loader)  # a SafeLoader or a subclass: never arbitrary objects
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"{path}:{mark.line + 1}" if mark else str(path)
        raise DocumentError(f"{where}: not valid YAML: {getattr(exc, 'problem', None) or exc}") from None


def read_text(path: str | Path) -> str:
    """The file's text; an unreadable file is a DocumentError naming it."""
    try:
        return Path(path).read_text()
    except OSError as exc:
        raise DocumentError(f"{path}: cannot read the file: {exc.strerror or exc}") from None


KeyPath = tuple[str | int, ...]


def load_document_lines(
    path: str | Path, text: str | None = None, loader: type[yaml.SafeLoader] = yaml.SafeLoader
) -> tuple[Any, dict[KeyPath, int]]:
    """Like :func:`load_document`, plus the 1-based line of every key path (``("a", "b", 0)`` for ``a.b[0]``); a
    key given twice has the line of its last occurrence.

    For tools that read foreign YAML (e.g. a ros2_control controllers.yaml) and must point back at its lines.
    """
    if text is None:
        text = read_text(path)
    data = load_document(path, text, loader)  # raises DocumentError with the line of a syntax error
    root = yaml.compose(text, Loader=yaml.SafeLoader)
    lines: dict[KeyPath, int] = {}

    def walk(node: yaml.Node, loc: KeyPath) -> None:
        lines.setdefault(loc, node.start_mark.line + 1)
        if isinstance(node, yaml.MappingNode):
            for key, value in node.value:
                here = (*loc, str(key.value))
                lines[here] = key.start_mark.line + 1
                walk(value, here)
        elif isinstance(node, yaml.SequenceNode):
            for i, item in enumerate(node.value):
                walk(item, (*loc, i))

    if root is not None:
        walk(root, ())
    return data, lines
