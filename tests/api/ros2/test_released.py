"""hild's vendored definitions (hild/api/ros2/definitions.py) against the released files they copy
(``released/``, see its README): the same fields, in the same order, for every type definitions.py holds.

Only what reaches CDR and the RIHS01 hash is compared — each field's type and name (and a default value, had one
any) — so comments, constants and blank lines may differ; a package's own types are written unqualified in its
files and qualified in definitions.py, so both sides are qualified before comparing.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from hild.api.ros2.definitions import ACTIONS, MESSAGES, SERVICES
from tests.api.ros2.conftest import released_files

INTEGERS = (f"{sign}int{bits}" for sign in ("", "u") for bits in (8, 16, 32, 64))
PRIMITIVES = frozenset(("bool", "byte", "char", "float32", "float64", "string", "wstring", *INTEGERS))
SEPARATOR = re.compile(r"^---[ \t]*$", re.MULTILINE)


def qualified(type_name: str, package: str) -> str:
    """``ChainConnection[]`` of controller_manager_msgs → ``controller_manager_msgs/ChainConnection[]``."""
    base = re.split(r"[\[<]", type_name, maxsplit=1)[0]
    return type_name if "/" in base or base in PRIMITIVES else f"{package}/{type_name}"


def fields(text: str, package: str) -> list[str]:
    """The field lines of one .msg section: ``type name [default]``, comments and constants left out."""
    out = []
    for line in text.splitlines():
        line = line.split("#", 1)[0].strip()
        if not line or "=" in line:  # blank, or a constant (``int32 STRICT=2``, ``int32 SUCCESSFUL = 0``)
            continue
        type_name, *rest = line.split()
        out.append(" ".join([qualified(type_name, package), *rest]))
    return out


def vendored(name: str) -> list[str]:
    """definitions.py's sections of ``name``: one for a message, request/response, goal/result/feedback."""
    if name in MESSAGES:
        return [MESSAGES[name][0]]
    if name in SERVICES:
        return [SERVICES[name].request, SERVICES[name].response]
    action = ACTIONS[name]
    return [action.goal, action.result, action.feedback]


def source_of(name: str) -> str:
    return (
        MESSAGES[name][1] if name in MESSAGES else SERVICES[name].source if name in SERVICES else ACTIONS[name].source
    )


def test_every_vendored_definition_has_its_released_file_and_no_more() -> None:
    assert sorted(released_files()) == sorted([*MESSAGES, *SERVICES, *ACTIONS])


@pytest.mark.parametrize(("name", "path"), sorted(released_files().items()), ids=sorted(released_files()))
def test_vendored_fields_equal_the_released_file(name: str, path: Path) -> None:
    package = name.split("/")[0]
    sections = SEPARATOR.split(path.read_text())
    ours = vendored(name)
    assert len(ours) == len(sections), name
    for released, own in zip(sections, ours, strict=True):
        assert fields(own, package) == fields(released, package), f"{name} differs from {path}"


@pytest.mark.parametrize(("name", "path"), sorted(released_files().items()), ids=sorted(released_files()))
def test_the_source_named_beside_a_definition_is_the_released_version(name: str, path: Path) -> None:
    """``released/ros2_control-4.46.0/…`` → the definition says ``ros2_control 4.46.0``."""
    repository, _, tag = path.parents[2].name.rpartition("-")
    assert f"{repository} {tag}" in source_of(name), (name, source_of(name))


def test_the_comparison_sees_a_changed_field() -> None:
    """The normalisation keeps what matters: a renamed field, a changed type or a moved line all differ."""
    base = fields("string name  # c\nint32 A=1\n\nChainConnection[] chain\n", "controller_manager_msgs")
    assert base == ["string name", "controller_manager_msgs/ChainConnection[] chain"]
    assert fields("string nam\ncontroller_manager_msgs/ChainConnection[] chain", "controller_manager_msgs") != base
    assert fields("ChainConnection[] chain\nstring name", "controller_manager_msgs") != base
    assert fields("string[<=3] name\nChainConnection[] chain", "controller_manager_msgs") != base
