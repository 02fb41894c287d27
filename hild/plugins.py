"""Drivers and controllers are plugins, found by name through entry-point groups.

Like python-can's interface registry: the daemon knows names, not modules, so a third-party package adds a
driver by declaring ``[project.entry-points."hild.drivers"] mydrive = "pkg.mod:Class"``.
"""

from __future__ import annotations

from functools import cache
from importlib.metadata import entry_points
from typing import Any

__all__ = [
    "COMMANDS",
    "CONTROLLERS",
    "DRIVERS",
    "PluginError",
    "available",
    "commands",
    "load",
    "sources",
]

DRIVERS = "hild.drivers"
CONTROLLERS = "hild.controllers"
COMMANDS = "hild.commands"  # extra `hild` sub-commands: a function ``register(subparsers)``


class PluginError(LookupError):
    pass


@cache
def available(group: str) -> tuple[str, ...]:
    return tuple(sorted({ep.name for ep in entry_points(group=group)}))


@cache
def load(group: str, name: str) -> Any:
    """The class registered as ``name`` in ``group``; a clear error names the ones that exist."""
    matches = [ep for ep in entry_points(group=group) if ep.name == name]
    if not matches:
        known = ", ".join(available(group)) or "none installed"
        kind = "driver" if group == DRIVERS else "controller type"
        raise PluginError(f"unknown {kind} {name!r} (known: {known})")
    return matches[0].load()


def sources(group: str) -> list[tuple[str, str]]:
    """Each plugin of ``group`` and where it comes from (``module:Class``), without importing any."""
    return sorted({(ep.name, ep.value) for ep in entry_points(group=group)})


def commands() -> list[Any]:
    """``register(subparsers)`` functions of installed command plugins (e.g. ``hild emulate`` from drivers/can)."""
    return [ep.load() for ep in sorted(entry_points(group=COMMANDS), key=lambda ep: ep.name)]
