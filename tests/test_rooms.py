"""The measuring room's exemption stays bounded: ``hild/bench`` may import drivers and any library, like the tests,
because ``hild bench`` measures the product as shipped; nothing else in ``hild`` imports ``drivers`` (drivers depend
on hild, never the reverse), and no product code imports the measuring room. Outside it, each third-party library
is imported only in its room (docs/architecture.md, "Rules")."""

from __future__ import annotations

import ast
import functools
from pathlib import Path

from tests.conftest import REPO

MEASURING_ROOM = REPO / "hild" / "bench"
# top-level module → where product code may import it (a folder, or one file)
LIBRARY_ROOMS = {
    "yaml": ("hild/config",),
    "pydantic": ("hild/config",),
    "zenoh": ("hild/api",),
    "rosbags": ("hild/api/ros2",),
    "xxhash": ("hild/api/ros2",),
    "mujoco": ("drivers/mujoco", "hild/dynamics"),
    "can": ("drivers/can",),
    "canopen": ("drivers/can",),
    "ruckig": ("hild/motion",),
    "rerun": ("hild/telemetry",),
    "simpleeval": ("hild/api/expressions.py",),
    "ruamel": ("hild/config/tuned.py",),
    "mcap": ("hild/record",),
    "pyarrow": ("hild/record",),
}


@functools.cache  # each module is parsed once, whatever the number of libraries asked about
def imports(path: Path) -> frozenset[str]:
    """Fully qualified modules ``path`` imports (absolute imports only: relative ones stay in their package)."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
    return frozenset(names)


def product_modules() -> list[Path]:
    return [p for root in ("hild", "drivers") for p in (REPO / root).rglob("*.py") if MEASURING_ROOM not in p.parents]


def test_hild_outside_the_measuring_room_never_imports_drivers() -> None:
    offenders = {
        str(p.relative_to(REPO)): sorted(m for m in imports(p) if m.split(".")[0] == "drivers")
        for p in product_modules()
        if p.is_relative_to(REPO / "hild")
    }
    assert {k: v for k, v in offenders.items() if v} == {}


def test_no_product_module_imports_the_measuring_room() -> None:
    offenders = {
        str(p.relative_to(REPO)): sorted(m for m in imports(p) if m == "hild.bench" or m.startswith("hild.bench."))
        for p in product_modules()
    }
    assert {k: v for k, v in offenders.items() if v} == {}


def test_each_library_is_imported_only_in_its_room() -> None:
    offenders = {}
    for path in product_modules():
        where = path.relative_to(REPO)
        for library, rooms in LIBRARY_ROOMS.items():
            if any(m.split(".")[0] == library for m in imports(path)) and not any(
                where == Path(room) or Path(room) in where.parents for room in rooms
            ):
                offenders.setdefault(str(where), []).append(library)
    assert offenders == {}
