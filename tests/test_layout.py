"""The package's layout rules (docs/architecture.md, "Rooms"), checked on the import graph.

- Code that runs in the cycle process never imports client-domain code (``hild.daemon``, ``hild.api``,
  ``hild.main``, the recorder side of ``hild.telemetry``) nor the libraries only the client domain uses: whatever
  the cycle process loads, it loads from ``hild.cycle.process`` down. A lazy import inside a function counts: it
  runs in the cycle process the day that function is called there.
- No import cycles among hild's modules; an import under ``if TYPE_CHECKING:`` is not run and does not count.
- A running cycle process has none of the client domain's shared objects mapped (checked from ``/proc``).
"""

from __future__ import annotations

import ast
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

from tests.conftest import REPO

CYCLE_ENTRY = "hild.cycle.process"
CLIENT_ONLY = (
    "hild.daemon",
    "hild.api",
    "hild.main",
    "hild.telemetry",
    "hild.record",
    "hild.bench",
    "hild.importers",
)
CLIENT_LIBRARIES = ("zenoh", "rerun", "rosbags", "xxhash", "rclpy", "simpleeval", "ruamel", "mcap", "pyarrow")
# Loaded into the cycle process by name (entry points), beside what its entry imports.
PLUGIN_PACKAGES = ("hild.controllers", "drivers")


def module_files() -> dict[str, Path]:
    files = {}
    for path in [*(REPO / "hild").rglob("*.py"), *(REPO / "drivers").rglob("*.py")]:
        parts = path.relative_to(REPO).with_suffix("").parts
        files[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return files


def _type_checking_nodes(tree: ast.AST) -> set[int]:
    nodes: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            nodes |= {id(inner) for inner in ast.walk(node)}
    return nodes


def imported_names(module: str, path: Path) -> Iterator[str]:
    """Every module name ``path`` imports when run (lazy ones included, type-only ones not), made absolute."""
    tree = ast.parse(path.read_text(), str(path))
    skip = _type_checking_nodes(tree)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            yield from (alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join([*anchor, base] if base else anchor)
            # ``from pkg import module`` imports pkg.module; ``from module import Name`` imports module (the caller
            # trims a name to the module that holds it)
            yield from (f"{base}.{alias.name}" for alias in node.names)


def graph() -> dict[str, set[str]]:
    """hild module → the hild modules (and third-party top-level names) it imports."""
    files = module_files()
    edges: dict[str, set[str]] = {}
    for module, path in files.items():
        targets = set()
        for name in imported_names(module, path):
            if name.split(".")[0] not in ("hild", "drivers"):
                targets.add(name.split(".")[0])
                continue
            while name and name not in files:  # ``from hild.x import Name``: the module is hild.x
                name = name.rpartition(".")[0]
            if name and name != module:
                targets.add(name)
        edges[module] = targets
    return edges


def loaded_by(start: str, edges: dict[str, set[str]]) -> set[str]:
    """What importing ``start`` can load: its imports, theirs, and every package ``__init__`` on the way."""
    seen: set[str] = set()
    todo = [start]
    while todo:
        module = todo.pop()
        if module in seen:
            continue
        seen.add(module)
        parts = module.split(".")
        todo += [".".join(parts[:i]) for i in range(1, len(parts)) if ".".join(parts[:i]) in edges]
        todo += edges.get(module, ())
    return seen


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    for root in edges:
        if root in index:
            continue
        work = [(root, iter(sorted(edges[root] & edges.keys())))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(edges[child] & edges.keys()))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return found


def in_room(module: str, rooms: tuple[str, ...]) -> bool:
    return any(module == room or module.startswith(f"{room}.") for room in rooms)


def test_the_cycle_process_never_imports_client_domain_code() -> None:
    edges = graph()
    plugins = [m for m in edges if in_room(m, PLUGIN_PACKAGES) and not in_room(m, ("drivers.can.emulator",))]
    loaded = set().union(*(loaded_by(start, edges) for start in [CYCLE_ENTRY, *plugins]))
    offenders = sorted(m for m in loaded if in_room(m, CLIENT_ONLY))
    libraries = sorted({lib for m in loaded for lib in edges.get(m, ()) if lib in CLIENT_LIBRARIES})
    assert (offenders, libraries) == ([], [])


def test_the_check_sees_a_lazy_import_and_ignores_a_type_only_one(tmp_path: Path) -> None:
    module = tmp_path / "probe.py"
    module.write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import hild.api.server\n"
        "def later():\n    from hild.daemon import daemon\n"
    )
    names = set(imported_names("hild.cycle.probe", module))
    assert "hild.daemon.daemon" in names and "hild.api.server" not in names


def test_no_import_cycles_among_hilds_modules() -> None:
    assert cycles(graph()) == []


def test_the_cycle_finder_finds_a_cycle() -> None:
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_importing_the_cycle_process_loads_no_client_library() -> None:
    """The same rule at run time: what ``python -m hild.cycle.process`` imports before it reads its spec."""
    code = (
        f"import sys, {CYCLE_ENTRY}; "
        f"bad = sorted(m for m in sys.modules if m.split('.')[0] in {CLIENT_LIBRARIES!r} "
        f"or m.startswith({tuple(f'{room}.' for room in CLIENT_ONLY)!r})); print(bad); assert not bad"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=REPO)
    assert result.returncode == 0, result.stdout + result.stderr


PUBLIC = ("hild", "hild.client", "hild.hardware", "hild.controller", "hild.interfaces", "hild.arrays", "hild.modes")
PUBLIC += ("hild.action", "hild.plugins")


def test_the_public_surface_is_explicit_and_every_name_in_it_exists() -> None:
    import importlib

    missing = {}
    for name in PUBLIC:
        module = importlib.import_module(name)
        exported = getattr(module, "__all__", None)
        assert exported, f"{name} has no __all__"
        missing[name] = [attr for attr in exported if not hasattr(module, attr)]
    assert {k: v for k, v in missing.items() if v} == {}


def test_the_top_of_the_package_is_the_contracts_the_cli_and_the_client() -> None:
    """At most 10 modules at hild/'s top level: everything else lives in the room of the process it runs in."""
    top = sorted(p.name for p in (REPO / "hild").glob("*.py"))
    assert len(top) <= 10, top
    assert {f"{m.rpartition('.')[2]}.py" for m in PUBLIC if m != "hild"} <= set(top)
