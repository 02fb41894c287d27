"""`hild check` on CAN configs: per-bus worst-case load, ids shared between components, driver review findings.

At 1 Mbit/s classic CAN one MIT motor costs a command and a reply of 135 bit times each per cycle, so at 1 kHz
three motors load a bus to 81 % (warning above 70 %) and four to 108 % (refused).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from hild.cli import main
from tests.conftest import joint

WriteConfig = Callable[..., Path]


def robot(rate: float, hardware: dict[str, Any]) -> dict[str, Any]:
    joints = [j for hw in hardware.values() for j in hw["joints"]]
    return {
        "robot": {"name": "canarm"},
        "update_rate": rate,
        "hardware": hardware,
        "joints": {j: joint() for j in joints},
    }


def mit(channel: str, ids: list[int], *, first_joint: int = 0, **extra: Any) -> dict[str, Any]:
    names = [f"j{first_joint + i}" for i in range(len(ids))]
    return {
        "driver": "mit_can",
        "params": {
            "bus": {"interface": "socketcan", "channel": channel, **extra.pop("bus", {})},
            "flavour": "damiao",
            "motors": {n: {"id": i, "reply_id": 0x10 + i, "model": "DM4310"} for n, i in zip(names, ids, strict=True)},
            **extra,
        },
        "joints": {n: {} for n in names},
    }


def check(write_config: WriteConfig, capsys: pytest.CaptureFixture[str], data: dict[str, Any]) -> tuple[int, str]:
    status = main(["check", str(write_config(data))])
    out = capsys.readouterr()
    return status, out.out + out.err


def test_three_mit_motors_at_1khz_fit_with_a_warning(write_config: WriteConfig, capsys: Any) -> None:
    status, text = check(write_config, capsys, robot(1000, {"arm": mit("can0", [1, 2, 3])}))
    assert status == 0, text
    assert "warning: bus socketcan:can0: worst-case load 81% at 1000 Hz (arm): above 70%" in text


def test_four_mit_motors_at_1khz_are_refused(write_config: WriteConfig, capsys: Any) -> None:
    status, text = check(write_config, capsys, robot(1000, {"arm": mit("can0", [1, 2, 3, 4])}))
    assert status == 1
    assert "bus socketcan:can0: worst-case load 108% at 1000 Hz (arm): over 100 %" in text


def test_six_motors_at_500hz_fit(write_config: WriteConfig, capsys: Any) -> None:
    status, text = check(write_config, capsys, robot(500, {"arm": mit("can0", [1, 2, 3, 4, 5, 6])}))
    assert status == 0, text
    assert "worst-case load 81% at 500 Hz" in text


def test_two_buses_are_budgeted_separately(write_config: WriteConfig, capsys: Any) -> None:
    hardware = {"left": mit("can0", [1, 2, 3]), "right": mit("can1", [1, 2, 3], first_joint=3)}
    status, text = check(write_config, capsys, robot(1000, hardware))
    assert status == 0, text
    assert "bus socketcan:can0: worst-case load 81%" in text and "bus socketcan:can1: worst-case load 81%" in text


def test_components_sharing_a_bus_are_summed_and_id_overlaps_refused(write_config: WriteConfig, capsys: Any) -> None:
    hardware = {"left": mit("can0", [1, 2]), "right": mit("can0", [2, 3], first_joint=2)}
    status, text = check(write_config, capsys, robot(1000, hardware))
    assert status == 1
    assert "worst-case load 108% at 1000 Hz (left, right)" in text
    assert "id 0x2 on socketcan:can0 is also used by hardware 'left'" in text
    assert "id 0x12 on socketcan:can0 is also used by hardware 'left'" in text  # the reply id too


def test_can_fd_with_bit_rate_switch_carries_seven_motors_at_1khz(write_config: WriteConfig, capsys: Any) -> None:
    fd = {"fd": True, "data_bitrate": 5_000_000}
    status, text = check(write_config, capsys, robot(1000, {"arm": mit("can0", list(range(1, 8)), bus=fd)}))
    assert status == 0, text
    assert "worst-case load 79% at 1000 Hz" in text
    status, text = check(write_config, capsys, robot(1000, {"arm": mit("can0", list(range(1, 10)), bus=fd)}))
    assert status == 1 and "over 100 %" in text


def test_driver_review_errors_are_refused_with_the_reason(write_config: WriteConfig, capsys: Any) -> None:
    arm = mit("can0", [1, 2])
    arm["params"]["motors"]["j1"]["model"] = "DM9999"
    status, text = check(write_config, capsys, robot(500, {"arm": arm}))
    assert status == 1
    assert "hardware.arm.params: j1: unknown damiao model 'DM9999'" in text


def test_odrive_config_is_checked_too(write_config: WriteConfig, capsys: Any) -> None:
    hardware = {
        "legs": {
            "driver": "odrive_can",
            "params": {"bus": {"channel": "can2"}, "axes": {"hip": {"node_id": 1}, "knee": {"node_id": 2}}},
            "joints": {"hip": {}, "knee": {}},
        }
    }
    status, text = check(write_config, capsys, robot(1000, hardware))
    assert status == 0, text
    assert "bus socketcan:can2: worst-case load 65% at 1000 Hz (legs)" in text  # 2 × (135 + 55 + 135) + heartbeats
    hardware["legs"]["params"]["axes"]["knee"]["node_id"] = 1
    status, text = check(write_config, capsys, robot(1000, hardware))
    assert status == 1 and "knee: node id 1 is also used by hip" in text
