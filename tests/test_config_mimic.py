"""The config's mimic_joints: each follows a robot joint, is not one, and no controller commands it."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from hild.config import ConfigError, load_config
from tests.conftest import merge, mock_robot


def issues_of(path: Path) -> list[str]:
    with pytest.raises(ConfigError) as info:
        load_config(path)
    return [str(i) for i in info.value.issues]


def test_mimic_joints_load_with_their_defaults(write_config: Callable[..., Path]) -> None:
    cfg = load_config(write_config(merge(mock_robot(), {"mimic_joints": {"a2": {"joint": "a"}}}))).config
    assert (cfg.mimic_joints["a2"].joint, cfg.mimic_joints["a2"].multiplier, cfg.mimic_joints["a2"].offset) == (
        "a",
        1.0,
        0.0,
    )


def test_a_mimic_joint_must_follow_a_robot_joint(write_config: Callable[..., Path]) -> None:
    [issue] = issues_of(write_config(merge(mock_robot(), {"mimic_joints": {"a2": {"joint": "z"}}})))
    assert "mimic_joints.a2.joint: joint 'z' is not defined under joints (defined: a, b, c)" in issue


def test_a_chain_is_refused_with_the_composed_coupling(write_config: Callable[..., Path]) -> None:
    mimics = {"a2": {"joint": "a", "multiplier": -1, "offset": 0.1}, "a3": {"joint": "a2", "multiplier": 2}}
    [issue] = issues_of(write_config(merge(mock_robot(), {"mimic_joints": mimics})))
    assert "mimic_joints.a3.joint: 'a2' is a mimic joint itself" in issue
    assert "follow 'a' with multiplier -2 and offset 0.2" in issue


def test_a_mimic_joint_may_not_share_a_robot_joints_name(write_config: Callable[..., Path]) -> None:
    [issue] = issues_of(write_config(merge(mock_robot(), {"mimic_joints": {"b": {"joint": "a"}}})))
    assert "mimic_joints.b: 'b' is also a joint under joints" in issue


def test_a_controller_naming_a_mimic_joint_is_refused(write_config: Callable[..., Path]) -> None:
    data = merge(mock_robot(), {"mimic_joints": {"a2": {"joint": "a"}}})
    data["controllers"]["fwd"]["params"]["joints"] = ["a", "a2"]
    issues = issues_of(write_config(data))
    assert any("'a2' is a mimic joint of 'a': it follows that joint and cannot be commanded" in i for i in issues)


def test_multiplier_and_offset_must_be_finite(write_config: Callable[..., Path]) -> None:
    [issue] = issues_of(
        write_config(merge(mock_robot(), {"mimic_joints": {"a2": {"joint": "a", "offset": float("inf")}}}))
    )
    assert "mimic_joints.a2.offset" in issue and "finite" in issue
