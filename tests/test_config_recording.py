"""The ``recording:`` section (docs/recording.md): its defaults, its bounds, where ``dir`` is, and what ``hild check``
says about it (nothing, unless something is wrong)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from hild.cli import main
from hild.config import ConfigError, load_config
from hild.config.model import RecordingSection
from tests.conftest import merge, mock_robot


def recording(patch: dict[str, Any]) -> dict[str, Any]:
    return merge(mock_robot(), {"recording": patch})


def issues_of(path: Path) -> str:
    with pytest.raises(ConfigError) as info:
        load_config(path)
    return "\n".join(str(i) for i in info.value.issues)


def test_the_defaults_are_the_contracts(write_config: Callable[..., Path]) -> None:
    section = load_config(write_config(mock_robot())).config.recording
    assert section == RecordingSection()
    assert section.model_dump() == {
        "enabled": True,
        "dir": "recordings",
        "blackbox_seconds": 10.0,
        "blackbox_on": ["fault", "estop", "stall"],
        "stall_after": 0.5,
        "fps": 30.0,
        "chunk_period": 0.1,
        "fsync": True,
        "min_free_mb": 200.0,
    }
    assert all(field.description for field in RecordingSection.model_fields.values())


@pytest.mark.parametrize(
    ("patch", "words"),
    [
        ({"chunk_period": 0.005}, "recording.chunk_period"),
        ({"chunk_period": 0.25}, "recording.chunk_period"),
        ({"fps": 0}, "recording.fps"),
        (
            {"blackbox_on": ["fault", "brownout"]},
            "recording.blackbox_on[1]: expected: input should be 'fault', 'estop' or 'stall'",
        ),
        (
            {"blackbox_on": ["fault", "estop", "fault"]},
            "expected: each trigger at most once (fault listed more than once)",
        ),
        ({"blackbox_seconds": -1}, "recording.blackbox_seconds"),
        ({"stall_after": 0}, "recording.stall_after"),
        ({"dir": ""}, "recording.dir"),
        ({"min_free_mb": -5}, "recording.min_free_mb"),
        ({"record_everything": True}, "recording.record_everything"),
    ],
)
def test_a_bad_value_is_named(write_config: Callable[..., Path], patch: dict[str, Any], words: str) -> None:
    assert words in issues_of(write_config(recording(patch)))


def test_the_edges_of_the_ranges_are_accepted(write_config: Callable[..., Path]) -> None:
    for chunk in (0.01, 0.2):
        loaded = load_config(write_config(recording({"chunk_period": chunk, "blackbox_seconds": 0, "blackbox_on": []})))
        assert loaded.config.recording.chunk_period == chunk


def test_dir_is_beside_the_config_file_unless_absolute(write_config: Callable[..., Path], tmp_path: Path) -> None:
    (tmp_path / "robots").mkdir()
    loaded = load_config(write_config(recording({"dir": "data/episodes"}), "robots/arm.yaml"))
    assert loaded.recording_dir == tmp_path / "robots" / "data" / "episodes"
    assert load_config(write_config(mock_robot())).recording_dir == tmp_path / "recordings"
    elsewhere = tmp_path / "elsewhere"
    assert load_config(write_config(recording({"dir": str(elsewhere)}))).recording_dir == elsewhere


def test_a_dir_that_is_a_file_is_an_error_unless_recording_is_off(
    write_config: Callable[..., Path], tmp_path: Path
) -> None:
    (tmp_path / "recordings").write_text("not a directory")
    assert f"recording.dir: not a directory: {tmp_path / 'recordings'}" in issues_of(write_config(mock_robot()))
    load_config(write_config(recording({"enabled": False}), "off.yaml"))


def test_a_cycle_log_too_large_for_the_shared_region_is_refused(write_config: Callable[..., Path]) -> None:
    huge = merge(recording({"blackbox_seconds": 3600}), {"update_rate": 4000})
    text = issues_of(write_config(huge))
    assert "recording.blackbox_seconds: the cycle log would take" in text and "keep fewer seconds" in text
    load_config(write_config(merge(huge, {"recording": {"enabled": False}}), "off.yaml"))  # no ring: nothing to fit


def test_check_says_nothing_new_about_a_good_section(
    write_config: Callable[..., Path], capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["check", str(write_config(mock_robot(), "plain.yaml"))]) == 0
    plain = capsys.readouterr().out
    assert main(["check", str(write_config(recording({"fps": 15, "dir": "/tmp/x"}), "recording.yaml"))]) == 0
    assert capsys.readouterr().out.replace("recording.yaml", "plain.yaml") == plain
    assert "recording" not in plain
