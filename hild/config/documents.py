"""Plain YAML/JSON documents that are not robot configs (e.g. a trajectory for ``hild ctl trajectory``)."""

from __future__ import annotations

from collections.abc import Hashable, Iterator, Mapping
from pathlib import Path
from typing import Any

import yaml


class DocumentError(ValueError):
    pass


def load_document(path: str | Path, text: str | None = None, *, merge_repeated: bool = False) -> Any:
    """Parse a YAML (or JSON, a subset of YAML) file; errors name the file and line.

    ``text``: the file's content as the caller already has it (e.g. after substitutions), named by ``path``.
    ``merge_repeated``: a key given twice in one mapping is merged with its earlier value (mappings key by key, a
    later value winning), as ROS's parameter parser applies repeated blocks; plain YAML keeps the last one only."""
    path = Path(path)
    if text is None:
        text = read_text(path)
    try:
        return yaml.load(text, Loader=_MergingLoader if merge_repeated else yaml.SafeLoader)  # both safe loaders
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
    path: str | Path, text: str | None = None, *, merge_repeated: bool = False
) -> tuple[Any, dict[KeyPath, int]]:
    """Like :func:`load_document`, plus the 1-based line of every key path (``("a", "b", 0)`` for ``a.b[0]``); a
    key given twice has the line of its last occurrence.

    For tools that read foreign YAML (e.g. a ros2_control controllers.yaml) and must point back at its lines.
    """
    if text is None:
        text = read_text(path)
    data = load_document(path, text, merge_repeated=merge_repeated)  # DocumentError: a syntax error's line
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


class _MergingLoader(yaml.SafeLoader):
    """A SafeLoader for which a key given twice in one mapping is applied block by block: a later value overrides an
    earlier one key by key (mappings merge; anything else replaces)."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        self.flatten_mapping(node)
        mapping: dict[Any, Any] = {}
        for key_node, value_node in node.value:
            key = self.construct_object(key_node, deep=True)
            if not isinstance(key, Hashable):
                raise yaml.constructor.ConstructorError(
                    "while constructing a mapping", node.start_mark, "found an unhashable key", key_node.start_mark
                )
            value = self.construct_object(value_node, deep=True)
            earlier = mapping.get(key)
            mapping[key] = _overlaid(earlier, value) if isinstance(earlier, dict) and isinstance(value, dict) else value
        return mapping


def _overlaid(earlier: dict[Any, Any], later: Mapping[Any, Any]) -> dict[Any, Any]:
    merged = dict(earlier)
    for key, value in later.items():
        before = merged.get(key)
        merged[key] = _overlaid(before, value) if isinstance(before, dict) and isinstance(value, dict) else value
    return merged


def repeated_keys(text: str) -> Iterator[tuple[KeyPath, int, int]]:
    """``(key path, line of its first occurrence, line of this one)`` for every key a mapping gives again."""

    def walk(node: yaml.Node, at: KeyPath) -> Iterator[tuple[KeyPath, int, int]]:
        if isinstance(node, yaml.MappingNode):
            first: dict[str, int] = {}
            for key, value in node.value:
                name, line = str(key.value), key.start_mark.line + 1
                if name in first:
                    yield (*at, name), first[name], line
                first.setdefault(name, line)
                yield from walk(value, (*at, name))
        elif isinstance(node, yaml.SequenceNode):
            for i, item in enumerate(node.value):
                yield from walk(item, (*at, i))

    root = yaml.compose(text, Loader=yaml.SafeLoader)
    return walk(root, ()) if root is not None else iter(())
