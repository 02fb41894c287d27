"""A ros2_canopen ``bus.yml`` as ros2_canopen reads it: the master, and each device with its keys and their lines.

Two layouts exist. The flat one (lely's ``dcfgen`` input) has ``options``, ``master`` and one top-level key per
device. The ``cogen`` one has ``defaults`` and ``nodes``; ros2_canopen's build (``cogen_dcf``) flattens it first,
copying every ``defaults`` key into each node — over the node's own value, as cogen.py does — so the same is
done here and a node value that loses to a default is reported. ``dcf`` names the device's EDS/DCF relative to the
bus.yml's directory (dcfgen runs there); ``options.dcf_path`` is where the generated ``.bin`` files go at run time,
which hild does not need.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hild.config.documents import DocumentError, KeyPath, load_document_lines
from hild.importers.ros2_control.report import ImportFailure, Report, SourceRef

SECTIONS = ("options", "master", "defaults", "nodes")


@dataclass
class BusNode:
    """One section of the bus: the master or a device, its keys (after defaults) and where each was set."""

    name: str
    where: SourceRef
    values: dict[str, Any]
    lines: dict[str, SourceRef] = field(default_factory=dict)
    paths: dict[str, KeyPath] = field(default_factory=dict)  # key → its path in the file (defaults' keys there)
    file_lines: dict[KeyPath, int] = field(default_factory=dict)

    def ref(self, key: str, *inner: str | int) -> SourceRef:
        """Where ``key`` (or an item inside it, e.g. ``ref("sdo", 2)``) is set."""
        if inner and key in self.paths and (*self.paths[key], *inner) in self.file_lines:
            return SourceRef(self.where.file, self.file_lines[(*self.paths[key], *inner)])
        return self.lines.get(key, self.where)


@dataclass
class Bus:
    path: Path
    master: BusNode | None
    devices: dict[str, BusNode]
    options: dict[str, Any]

    def by_node_id(self, node_id: int) -> BusNode | None:
        for device in self.devices.values():
            if as_int(device.values.get("node_id")) == node_id:
                return device
        return None


def read_bus(path: Path, report: Report) -> Bus:
    """The bus.yml at ``path``; a missing file or one that is no bus is an ImportFailure naming it."""
    try:
        data, lines = load_document_lines(path)
    except DocumentError as exc:
        raise ImportFailure(f"ros2_canopen bus_config: {exc}") from None
    label = str(path)

    def ref(key_path: KeyPath) -> SourceRef:
        return SourceRef(label, lines.get(key_path))

    if not isinstance(data, dict):
        raise SourceRef(label, 1).fail("a ros2_canopen bus.yml must be a mapping (options, master, devices)")
    options = data.get("options") if isinstance(data.get("options"), dict) else {}
    master = _node("master", data.get("master"), ("master",), ref, lines)
    devices: dict[str, BusNode] = {}
    if "nodes" in data:
        nodes, defaults = data.get("nodes"), data.get("defaults") or {}
        if not isinstance(nodes, dict) or not isinstance(defaults, dict):
            raise ref(("nodes",)).fail("nodes and defaults must be mappings of device name → keys")
        for name, values in nodes.items():
            device = _node(str(name), values, ("nodes", str(name)), ref, lines)
            assert device is not None
            for key, value in defaults.items():
                if key in device.values and device.values[key] != value:
                    report.approximated(
                        device.ref(key),
                        f"bus.yml node {name!r}: {key} {device.values[key]!r} is overridden by defaults' "
                        f"{value!r} (ros2_canopen's cogen copies defaults over each node's own keys)",
                    )
                device.values[key] = value
                device.lines[key] = ref(("defaults", str(key)))
                device.paths[key] = ("defaults", str(key))
            devices[str(name)] = device
        extra = [k for k in data if k not in SECTIONS]
        for key in extra:
            report.unsupported(ref((str(key),)), f"bus.yml {key!r} beside nodes: ros2_canopen's cogen ignores it")
    else:
        if "defaults" in data:
            report.unsupported(ref(("defaults",)), "bus.yml defaults without nodes: ros2_canopen ignores them")
        for name, values in data.items():
            if name in SECTIONS:
                continue
            device = _node(str(name), values, (str(name),), ref, lines)
            if device is not None:
                devices[str(name)] = device
    if master is None:
        raise SourceRef(label, 1).fail("the bus.yml has no master section (ros2_canopen needs one)")
    return Bus(path, master, devices, options)


def _node(name: str, values: Any, key_path: KeyPath, ref: Any, file_lines: dict[KeyPath, int]) -> BusNode | None:
    if values is None:
        return None
    if not isinstance(values, dict):
        raise ref(key_path).fail(f"bus.yml {name!r} must be a mapping of configuration items")
    keys = [str(k) for k in values]
    lines = {k: ref((*key_path, k)) for k in keys}
    paths: dict[str, KeyPath] = {k: (*key_path, k) for k in keys}
    return BusNode(name, ref(key_path), {str(k): v for k, v in values.items()}, lines, paths, file_lines)


def as_int(value: Any) -> int | None:
    """An integer key as YAML (or a quoted hex string) gives it; None when it is not one."""
    if isinstance(value, bool):
        return None
    if isinstance(value, int):
        return value
    if isinstance(value, str):
        try:
            return int(value.strip(), 0)
        except ValueError:
            return None
    return None


def as_float(value: Any) -> float | None:
    """A number key; None when it is not one (a bool is not a number)."""
    if isinstance(value, bool):
        return None
    if isinstance(value, int | float):
        return float(value)
    if isinstance(value, str):
        try:
            return float(int(value.strip(), 0)) if value.strip().lower().startswith("0x") else float(value)
        except ValueError:
            return None
    return None
