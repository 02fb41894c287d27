"""The opt-in ``ros2:`` section: validated like the other sections, absent by default."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from hild.config import ConfigError, load_config
from tests.conftest import merge, mock_robot


def test_absent_by_default(write_config: Callable[..., Path]) -> None:
    assert load_config(write_config(mock_robot())).config.ros2 is None


def test_defaults_when_present(write_config: Callable[..., Path]) -> None:
    ros2 = load_config(write_config(merge(mock_robot(), {"ros2": {}}))).config.ros2
    assert ros2 is not None
    assert (ros2.distro, ros2.domain_id, ros2.namespace, ros2.node) == ("jazzy", 0, "/", "controller_manager")


@pytest.mark.parametrize(
    "section",
    [
        {"distro": "humble"},
        {"domain_id": 233},
        {"domain_id": -1},
        {"namespace": "arm"},
        {"namespace": "/arm/"},
        {"namespace": "/a//b"},
        {"node": "my node"},
        {"node": "a/b"},
        {"unknown": 1},
    ],
)
def test_refused(write_config: Callable[..., Path], section: dict[str, Any]) -> None:
    with pytest.raises(ConfigError):
        load_config(write_config(merge(mock_robot(), {"ros2": section})))
