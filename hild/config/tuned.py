"""A copy of the config file with what was tuned while the robot ran, so a tuning session is not lost.

ruamel.yaml's round trip keeps the file's comments, key order and layout; only the values that differ from what
the file says now are written (a parameter the file leaves at its default is added where it belongs), and a
controller loaded while the robot ran is added with its type and the params that differ from its defaults. The
copy is text for the caller to write: the daemon never writes a file for a client (``hild ctl params save``).
"""

from __future__ import annotations

import io
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ruamel.yaml import YAML
from ruamel.yaml.comments import CommentedMap

from hild.config.loader import load_config
from hild.config.params import Params, flatten
from hild.config.tuning import ManagerParams


def tuned_copy(
    path: Path, controllers: Mapping[str, tuple[str, Params]], tuning: ManagerParams
) -> tuple[str, list[str]]:
    """The config file at ``path`` with ``controllers`` (name → type, current params) and the daemon's own
    ``tuning`` (each joint's hold gains and soft margin; the velocity scale has no place in a config and is left
    out) as they are now: its text, and the dotted keys that changed. ConfigError if the file on disk does not load
    (there is nothing sound to copy)."""
    on_disk = load_config(path)
    yaml = YAML()  # round trip: comments and order survive
    yaml.width = 120
    document = yaml.load(path.read_text(encoding="utf-8"))
    changed: list[str] = []
    sections = document.setdefault("controllers", CommentedMap())
    for name, (type_name, params) in controllers.items():
        spec = on_disk.config.controllers.get(name)
        if spec is None or spec.type != type_name:
            sections[name] = CommentedMap(type=type_name, params=params.model_dump(mode="json", exclude_defaults=True))
            changed.append(f"controllers.{name}")
            continue
        before = flatten(on_disk.controller_params[name])
        for key, value in flatten(params).items():
            if before.get(key) != value:
                _set(sections[name].setdefault("params", CommentedMap()), key.split("."), value)
                changed.append(f"controllers.{name}.params.{key}")
    for joint, now in tuning.joints.items():
        was = on_disk.config.joints[joint]
        for keys, value, before in (
            (("hold", "kp"), now.hold.kp, was.hold.kp),
            (("hold", "kd"), now.hold.kd, was.hold.kd),
            (("limits", "soft_margin"), now.soft_margin, was.limits.soft_margin),
        ):
            if value != before:
                _set(document["joints"][joint], list(keys), value)
                changed.append(f"joints.{joint}.{'.'.join(keys)}")
    out = io.StringIO()
    yaml.dump(document, out)
    return out.getvalue(), changed


def _set(node: Any, parts: list[str], value: Any) -> None:
    for part in parts[:-1]:
        node = node.setdefault(part, CommentedMap())
    node[parts[-1]] = value


def friction_copy(path: Path, frictions: Mapping[str, Mapping[str, float]]) -> tuple[str, list[str]]:
    """The config file at ``path`` with ``joints.<j>.friction`` set to ``frictions`` (joint → viscous, coulomb,
    offset, band; ``hild identify``'s fit), everything else as the file has it: its text, and the dotted keys that
    changed. ConfigError if the file on disk does not load; ValueError for a joint it does not have."""
    on_disk = load_config(path)
    unknown = [j for j in frictions if j not in on_disk.config.joints]
    if unknown:
        raise ValueError(f"{path} has no joints {unknown}")
    yaml = YAML()
    yaml.width = 120
    document = yaml.load(path.read_text(encoding="utf-8"))
    changed: list[str] = []
    for joint, values in frictions.items():
        node = document["joints"][joint]
        section = node.get("friction")
        if section is None:
            node["friction"] = section = CommentedMap()
        for key, value in values.items():
            if section.get(key) != value:
                section[key] = value
                changed.append(f"joints.{joint}.friction.{key}")
    out = io.StringIO()
    yaml.dump(document, out)
    return out.getvalue(), changed
