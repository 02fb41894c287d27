"""``hild check`` on stopping and on files: a limp stop of a gravity-loaded joint is a warning, a missing model
file named by a hardware section an error (issue [trust], finding 6)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest
import yaml

from hild.cli import main
from hild.config import ConfigError, load_config
from hild.config.stop_review import limp_at_stop
from tests.conftest import CONFIGS


def twin_doc(**safety: float) -> dict:
    data = yaml.safe_load((CONFIGS / "arm6_twin.yaml").read_text())
    data["robot"]["model"] = str(CONFIGS / "arm6.xml")
    data["hardware"]["twin"]["params"]["model"] = str(CONFIGS / "arm6.xml")
    data["safety"] = {**data.get("safety", {}), **safety}
    return data


def test_a_limp_stop_of_gravity_loaded_joints_is_a_warning_naming_them(write_config: Callable[..., Path]) -> None:
    (warning,) = limp_at_stop(load_config(write_config(twin_doc())))
    assert warning.startswith("warning: stopping releases gravity-loaded joints limp: shoulder_lift (up to ")
    assert "wrist_3" not in warning and "shoulder_pan" not in warning  # no weight on them
    assert "safety.stop_descent" in warning
    assert limp_at_stop(load_config(write_config(twin_doc(stop_descent=2.0)))) == []


def test_drives_that_hold_at_stop_draw_no_warning(write_config: Callable[..., Path]) -> None:
    data = yaml.safe_load((CONFIGS / "arm6_vcan.yaml").read_text())
    data["robot"]["model"] = str(CONFIGS / "arm6.xml")
    data["safety"]["stop_descent"] = 0.0
    assert limp_at_stop(load_config(write_config(data)))  # on_deactivate: disable → limp
    data["hardware"]["arm"]["params"]["on_deactivate"] = "hold"
    assert limp_at_stop(load_config(write_config(data))) == []


def test_a_missing_model_file_of_a_hardware_section_fails_the_check(
    write_config: Callable[..., Path], capsys: pytest.CaptureFixture[str]
) -> None:
    data = twin_doc()
    data["hardware"]["twin"]["params"]["model"] = "nowhere.xml"
    path = write_config(data)
    with pytest.raises(ConfigError) as refused:
        load_config(path)
    assert "hardware.twin.params.model" in str(refused.value) and "nowhere.xml" in str(refused.value)
    assert main(["check", str(path)]) == 1
    assert "file not found" in capsys.readouterr().err
