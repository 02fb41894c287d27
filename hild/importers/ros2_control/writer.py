"""The hild config as YAML text: the imported data with a comment naming where each part came from.

YAML is emitted here rather than with a YAML library, because the comments are the point: each joint,
controller and hardware entry says which element or key it was made from, and the CAN section is a commented
template. The shapes are small (mappings, lists of scalars, numbers, names), and the result is validated by
``load_config`` before anything is written.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from hild.config.stop_review import SUGGESTED_DESCENT
from hild.importers.ros2_control.can_template import CanFacts, template_lines
from hild.importers.ros2_control.canopen import Cia402Section
from hild.importers.ros2_control.controllers import ControllerPlan, ControllersPlan
from hild.importers.ros2_control.mapping import JointPlan, MimicPlan, SensorPlan

KeyPath = tuple[str, ...]
_PLAIN = re.compile(r"[A-Za-z_][A-Za-z0-9_\-./]*")  # the whole text (fullmatch: not before a final "\n")
_YAML_WORDS = {"true", "false", "yes", "no", "on", "off", "y", "n", "null", "~"}
FLOW_WIDTH = 118


@dataclass
class Document:
    """A config as nested dicts, with comments keyed by the path of the key they follow."""

    data: dict[str, Any]
    comments: dict[KeyPath, str] = field(default_factory=dict)
    header: list[str] = field(default_factory=list)
    footer: list[str] = field(default_factory=list)


def build_document(
    robot_name: str,
    urdf_name: str,
    joints: Sequence[JointPlan],
    controllers: ControllersPlan,
    substeps: int,
    sources: Sequence[str],
    can: Mapping[str, CanFacts],  # what each <ros2_control> block says about its CAN drives
    exclude_contacts: Sequence[tuple[str, str]] = (),
    mimic_joints: Sequence[MimicPlan] = (),
    sensors: Sequence[SensorPlan] = (),
    cia402: Mapping[str, Cia402Section] | None = None,  # per ros2_canopen block: its cia402 section
) -> Document:
    twin_params: dict[str, Any] = {"model": urdf_name, "substeps": substeps}
    initial = {j.name: j.initial_position for j in joints if j.initial_position is not None}
    if initial:
        twin_params["initial_positions"] = initial
    if exclude_contacts:
        twin_params["exclude_contacts"] = [list(pair) for pair in exclude_contacts]
    doc = Document(
        {
            "robot": {"name": robot_name, "model": urdf_name},
            "update_rate": _whole(controllers.update_rate),
            "clock": {"source": "wall"},
            "safety": {"stop_descent": SUGGESTED_DESCENT},
            "hardware": {"twin": _twin(twin_params, joints, sensors)},
            "joints": {j.name: _joint(j) for j in joints},
            **({"mimic_joints": {m.name: _mimic(m) for m in mimic_joints}} if mimic_joints else {}),
            "controllers": {c.name: _controller(c) for c in controllers.controllers},
        }
    )
    c = doc.comments
    c[("robot", "model")] = "the twin's URDF: gravity feed-forward in hold"
    c[("update_rate",)] = f"controller_manager update_rate ({controllers.update_rate_where.short})"
    c[("clock", "source")] = "wall: real-time twin; sim: lockstep (tests)"
    c[("safety", "stop_descent")] = "s: on stop the arm is lowered (damped, gravity fading out), not dropped"
    c[("hardware", "twin")] = "the MuJoCo twin stands in for every <ros2_control> hardware (joint space)"
    c[("hardware", "twin", "params", "substeps")] = "physics step ≤ 1 ms, short enough for the gains' stability"
    c[("hardware", "twin", "params", "exclude_contacts")] = "adjacent links, links overlapping at the start pose"
    for j in joints:
        c[("hardware", "twin", "joints", j.name)] = j.where.short
        c[("joints", j.name, "hold")] = j.gains_from
    for m in mimic_joints:
        c[("mimic_joints", m.name)] = m.where.short
    for s in sensors:
        c[("hardware", "twin", "sensors", s.name)] = f"{s.where.short}; the twin reads MuJoCo's sensors on {s.frame_id}"
    for plan in controllers.controllers:
        c[("controllers", plan.name)] = f"{plan.comment} ({plan.where.short})"
    doc.header = [
        f"{robot_name}: imported from ros2_control by `hild import ros2-control`.",
        *(f"  {s}" for s in sources),
        "Hardware is the MuJoCo twin over the URDF beside this file. Read the import report (approximations) and",
        "check limits and gains before running on hardware; the CAN section at the end is a template to fill in.",
    ]
    cia402 = cia402 or {}
    others = [j for j in joints if j.block not in cia402]
    doc.footer = template_lines(others, can) if others else []
    if cia402:
        doc.footer.extend(
            ["", *cia402_lines(list(cia402.values()))] if doc.footer else cia402_lines(list(cia402.values()))
        )
    return doc


def cia402_lines(sections: Sequence[Cia402Section]) -> list[str]:
    """The ``cia402`` components of every ros2_canopen block under one ``hardware:`` (commented out by ``render``),
    each value with its source; joints left out are ``# TODO`` lines, comments still once uncommented."""
    comments: dict[KeyPath, str] = {}
    for s in sections:
        root: KeyPath = ("hardware", s.name)
        comments.update({(*root, *path): text for path, text in s.comments.items()})
        comments[root] = f"was <ros2_control name={s.block!r}> {s.plugin}"
    lines = [line for s in sections for line in s.heading]
    lines.extend(_block({"hardware": {s.name: s.component for s in sections}}, comments, 0, ()))
    lines.extend(f"  # TODO: {why}" for s in sections for why in s.missing)
    return lines


def render(doc: Document) -> str:
    lines = [f"# {h}".rstrip() for h in doc.header]
    lines.extend(_block(doc.data, doc.comments, 0, ()))
    if doc.footer:
        lines.append("")
        lines.extend(f"# {f}".rstrip() for f in doc.footer)
    return "\n".join(lines) + "\n"


# ---- content ----------------------------------------------------------------------------------------------------


def _whole(value: float) -> float | int:
    return int(value) if float(value).is_integer() else value


def _twin(params: dict[str, Any], joints: Sequence[JointPlan], sensors: Sequence[SensorPlan]) -> dict[str, Any]:
    twin: dict[str, Any] = {"driver": "mujoco", "params": params, "joints": {j.name: {} for j in joints}}
    if sensors:
        twin["sensors"] = {s.name: {"type": s.type, "frame_id": s.frame_id} for s in sensors}
    return twin


def _joint(j: JointPlan) -> dict[str, Any]:
    limits: dict[str, Any] = {"position": {"lower": j.lower, "upper": j.upper}}
    if j.soft_margin:
        limits["soft_margin"] = j.soft_margin
    limits.update(velocity=j.velocity, effort=j.effort, acceleration=j.acceleration, jerk=j.jerk)
    return {"limits": limits, "hold": {"kp": j.kp, "kd": j.kd}}


def _mimic(m: MimicPlan) -> dict[str, Any]:
    return {"joint": m.joint, "multiplier": _whole(m.multiplier), "offset": _whole(m.offset)}


def _controller(plan: ControllerPlan) -> dict[str, Any]:
    out: dict[str, Any] = {"type": plan.type, "params": plan.params}
    if plan.autostart:
        out["autostart"] = True
    return out


# ---- YAML ------------------------------------------------------------------------------------------------------


def _scalar(value: Any) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return _number(value)
    text = str(value)
    if _PLAIN.fullmatch(text) and text.lower() not in _YAML_WORDS:
        return text
    return json.dumps(text, ensure_ascii=False)


def _number(value: float) -> str:
    if math.isnan(value):
        return ".nan"
    if math.isinf(value):
        return ".inf" if value > 0 else "-.inf"
    text = repr(value)
    mantissa, e, exponent = text.partition("e")
    if e and "." not in mantissa:  # YAML 1.1 reads 1e-05 as a string
        text = f"{mantissa}.0e{exponent}"
    return text.removesuffix(".0") if not e else text


def _flow(value: Any) -> str | None:
    """One-line form of a value, or None if it holds something that must be a block."""
    if isinstance(value, dict):
        parts = []
        for k, v in value.items():
            inner = _flow(v)
            if inner is None:
                return None
            parts.append(f"{_scalar(k)}: {inner}")
        return "{" + ", ".join(parts) + "}"
    if isinstance(value, list | tuple):
        items = [_flow(v) for v in value]
        if any(i is None for i in items):
            return None
        return "[" + ", ".join(i for i in items if i is not None) + "]"
    return _scalar(value)


def _block(data: dict[str, Any], comments: dict[KeyPath, str], depth: int, path: KeyPath) -> list[str]:
    lines = []
    indent = "  " * depth
    for key, value in data.items():
        here = (*path, str(key))
        comment = comments.get(here)
        head = f"{indent}{_scalar(key)}:"
        nested_comments = any(p[: len(here)] == here and p != here for p in comments)
        flow = _flow(value) if not nested_comments else None
        width = len(head) + 1 + len(flow or "") + (len(comment) + 4 if comment else 0)
        if isinstance(value, dict) and value and (flow is None or width > FLOW_WIDTH):
            lines.append(_commented(head, comment))
            lines.extend(_block(value, comments, depth + 1, here))
        else:
            lines.append(_commented(f"{head} {flow if flow is not None else _scalar(value)}", comment))
    return lines


def _commented(line: str, comment: str | None) -> str:
    return f"{line}  # {comment}" if comment else line
