"""xacro without ROS: the PyPI ``xacro`` package (the same code ROS ships), with ``$(find pkg)`` answered by us.

xacro resolves ``$(find pkg)`` through ament_index_python, which only exists in a ROS install. Its lookup is one
module-level function (``xacro.substitution_args._eval_find``, also exposed to ``$(eval find(...))``); it is
swapped for :class:`PackageRoots` for the duration of one expansion. xacro keeps module-level state (the file
stack, the argument context), so expansions are serialized by a lock.
"""

from __future__ import annotations

import contextlib
import io
import threading
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any
from xml.parsers import expat

from hild.importers.ros2_control.packages import PackageRoots
from hild.importers.ros2_control.report import ImportFailure

_LOCK = threading.Lock()


class _UnknownPackage(LookupError):
    pass


def is_xacro(path: Path, text: str) -> bool:
    """A ``.xacro`` file, or any file that declares the xacro namespace."""
    return path.suffix == ".xacro" or "http://www.ros.org/wiki/xacro" in text or "http://ros.org/wiki/xacro" in text


@contextlib.contextmanager
def _find_hook(packages: PackageRoots, missing: list[str]) -> Iterator[None]:
    from xacro import substitution_args

    def find(package: str) -> str:
        root = packages.find(package)
        if root is None:
            missing.append(package)
            raise _UnknownPackage(package)
        return str(root)

    saved = substitution_args._eval_find, substitution_args._eval_dict["find"]
    substitution_args._eval_find = find
    substitution_args._eval_dict["find"] = find
    try:
        yield
    finally:
        substitution_args._eval_find, substitution_args._eval_dict["find"] = saved


def expand_xacro(path: Path, args: Mapping[str, str], packages: PackageRoots) -> tuple[str, list[str]]:
    """Expand ``path`` with xacro ``args`` (``name:=value``); returns (URDF text, xacro's own warnings)."""
    import xacro

    missing: list[str] = []
    messages = io.StringIO()
    with _LOCK, _find_hook(packages, missing), contextlib.redirect_stderr(messages):
        xacro.all_includes = []
        try:
            document: Any = xacro.process_file(str(path.resolve()), mappings=dict(args))
            text = document.toprettyxml(indent="  ")
        except Exception as exc:
            where = _current_file(xacro, path)
            if missing:
                raise ImportFailure(
                    f"{where}: xacro: unknown ROS package {missing[0]!r} in $(find {missing[0]}): "
                    f"pass --package-root {missing[0]}=DIR"
                ) from None
            if isinstance(exc, expat.ExpatError):
                raise ImportFailure(
                    f"{where}:{exc.lineno}: not well-formed XML: {expat.errors.messages[exc.code]}"
                ) from None
            detail = " ".join(str(exc).split())
            if "Undefined substitution argument" in detail:
                detail += " (pass it with --arg NAME=VALUE)"
            raise ImportFailure(f"{where}: xacro could not expand it: {detail}") from None
        finally:
            xacro.filestack = None  # forget this file: a later expansion starts clean
    return text, _warnings(messages.getvalue())


_LOCATION_PREFIXES = (
    "when processing file:",
    "in file:",
    "included from:",
    "when instantiating macro:",
    "instantiated",
)


def _warnings(printed: str) -> list[str]:
    """xacro's printed warnings, one per entry, with its location lines folded into the warning."""
    out: list[str] = []
    for line in (raw.strip() for raw in printed.splitlines()):
        if not line:
            continue
        if out and line.startswith(_LOCATION_PREFIXES):
            out[-1] += f" ({line})"
        else:
            out.append(line)
    return out


def _current_file(xacro: Any, path: Path) -> str:
    """The file xacro was reading when it failed (an included file, or the top one)."""
    stack = getattr(xacro, "filestack", None) or []
    current = next((f for f in reversed(stack) if f), None)
    return str(current) if current else str(path)
