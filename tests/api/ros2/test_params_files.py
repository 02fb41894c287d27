"""A controller's section of ROS 2 parameter files (what ``<c>.params_file`` names), read as hild params: the node
matched as ROS matches it, later files overriding, dotted and nested keys alike, the manager's keys left out, and
every unreadable file refused with its name."""

from __future__ import annotations

from pathlib import Path

import pytest

from hild.api.ros2.params_files import MAX_FILE_BYTES, controller_params


def write(tmp_path: Path, name: str, text: str) -> str:
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def test_the_controllers_section_without_the_managers_keys(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        "controllers.yaml",
        """
controller_manager:
  ros__parameters:
    update_rate: 100
fwd2:
  ros__parameters:
    type: forward_command_controller/ForwardCommandController
    fallback_controllers: [fwd_a]
    use_sim_time: true
    joints: [a, b]
    interface: position
other:
  ros__parameters:
    joints: [c]
""",
    )
    assert controller_params([path], "fwd2", "/fwd2") == {"joints": ["a", "b"], "interface": "position"}


def test_wildcards_then_the_node_and_later_files_override_parameter_by_parameter(tmp_path: Path) -> None:
    first = write(
        tmp_path,
        "a.yaml",
        """
/**:
  ros__parameters:
    command_timeout: 0.1
/**/traj2:
  ros__parameters:
    constraints: {goal_time: 2.0, stopped_velocity_tolerance: 0.02}
/arm/traj2:
  ros__parameters:
    joints: [a, b, c]
""",
    )
    second = write(tmp_path, "b.yml", "traj2:\n  ros__parameters:\n    constraints.goal_time: 0.5\n")
    assert controller_params([first, second], "traj2", "/arm/traj2") == {
        "command_timeout": 0.1,
        "constraints": {"goal_time": 0.5, "stopped_velocity_tolerance": 0.02},
        "joints": ["a", "b", "c"],
    }
    assert "joints" not in controller_params([first], "traj2", "/traj2")  # another namespace's section


@pytest.mark.parametrize(
    ("name", "text", "reason"),
    [
        ("none.yaml", None, "cannot read it on the robot PC"),
        ("bad.yaml", "a: [1,\n", "not valid YAML"),
        ("list.yaml", "- a\n", "not a ROS parameter file"),
        ("params.txt", "x: 1\n", "a params_file is an absolute path to a .yaml file"),
        ("other.yaml", "other:\n  ros__parameters: {joints: [a]}\n", "no parameters for fwd2 in"),
        ("flat.yaml", "fwd2:\n  ros__parameters: [1, 2]\n", "ros__parameters of fwd2 is not a mapping"),
        ("big.yaml", "#" * (MAX_FILE_BYTES + 1), "a params_file has at most"),
    ],
)
def test_a_file_that_cannot_give_the_section_is_refused_with_its_name(
    tmp_path: Path, name: str, text: str | None, reason: str
) -> None:
    path = str(tmp_path / name) if text is None else write(tmp_path, name, text)
    with pytest.raises(ValueError, match=reason) as caught:
        controller_params([path], "fwd2", "/fwd2")
    assert path in str(caught.value)


def test_a_relative_path_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="absolute path"):
        controller_params(["controllers.yaml"], "fwd2", "/fwd2")
