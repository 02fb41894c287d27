"""cia402 at config load (``hild check``): per-mode command fields, review findings, the bus budget."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml

from drivers.can.bus import frame_bits
from drivers.can.cia402.driver import Cia402Driver
from drivers.can.params import Cia402Params
from hild.config.loader import ConfigError, load_config
from tests.helpers import rig_joint

EDS = Path(__file__).resolve().parents[3] / "configs" / "cia402_generic.eds"
NAMES = [f"j{k + 1}" for k in range(6)]


def robot(n: int = 2, rate: float = 500.0, **params: Any) -> dict[str, Any]:
    names = NAMES[:n]
    hardware = {
        "bus": {"interface": "virtual", "channel": "cia402-config", "bitrate": 1_000_000},
        "eds": str(EDS),
        "drives": {j: {"node_id": k + 1} for k, j in enumerate(names)},
        **params,
    }
    return {
        "robot": {"name": "cia402"},
        "update_rate": rate,
        "clock": {"source": "sim", "real_time_factor": 0},
        "hardware": {"arm": {"driver": "cia402", "params": hardware, "joints": {j: {} for j in names}}},
        "joints": {j: rig_joint() for j in names},
        "controllers": {
            "forward_position": {
                "type": "forward_command",
                "params": {"joints": names, "interface": "position", "command_timeout": 0.1},
            }
        },
        "safety": {"fault_action": "hold", "estop_action": "hold"},
    }


def load(tmp_path: Path, config: dict[str, Any]) -> Any:
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(config))
    return load_config(path)


def test_a_csp_config_loads_and_reports_its_bus_load(tmp_path: Path) -> None:
    loaded = load(tmp_path, robot())
    assert any("bus virtual:cia402-config: worst-case load" in note for note in loaded.notes)


def test_a_controller_claiming_what_the_mode_ignores_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"claims 'j1/position', which driver 'cia402' does not offer \(it applies "
                       r"effort, velocity for j1\)"):  # fmt: skip
        load(tmp_path, robot(mode="csv"))


def test_cst_takes_the_whole_servo_command_on_the_torque_path(tmp_path: Path) -> None:
    """CST applies kp·(p − q) + kd·(v − q̇) + effort hild-side, so a position controller may claim a CST joint."""
    loaded = load(tmp_path, robot(mode="cst"))
    assert "forward_position" in loaded.config.controllers


def test_per_drive_modes_give_per_joint_fields() -> None:
    params = Cia402Params.model_validate(
        {
            "bus": {"interface": "virtual", "channel": "x"},
            "eds": "x.eds",
            "mode": "csp",
            "drives": {"a": {"node_id": 1}, "b": {"node_id": 2, "mode": "csv"}, "c": {"node_id": 3, "mode": "cst"}},
        }
    )
    fields = Cia402Driver.command_fields(params, ["a", "b", "c"])
    assert fields == {
        "a": {"position", "effort"},
        "b": {"velocity", "effort"},
        "c": {"position", "velocity", "effort", "kp", "kd"},
    }


def test_six_drives_at_500_hz_fit_classic_can_and_1_khz_does_not(tmp_path: Path) -> None:
    params = Cia402Params.model_validate(robot(6)["hardware"]["arm"]["params"])
    (usage,) = Cia402Driver.bus_usage(params, NAMES, 500.0)
    per_cycle = 6 * 2 * frame_bits(8) + frame_bits(0)  # RPDO + TPDO per drive, then SYNC
    heartbeats = 6 * 10 * frame_bits(1)  # 100 ms
    assert usage.bits_per_second == pytest.approx(500 * per_cycle + heartbeats)
    assert 0.83 < usage.bits_per_second / usage.capacity < 0.85
    assert {0x80, 0x201, 0x181, 0x81, 0x701, 0x206, 0x186} <= usage.ids
    with pytest.raises(ConfigError, match="over 100 %"):
        load(tmp_path, robot(6, rate=1000.0))


def test_fd_carries_everything_in_one_frame_each_way() -> None:
    raw = robot(6)["hardware"]["arm"]["params"]
    raw["bus"] |= {"fd": True, "data_bitrate": 5_000_000}
    params = Cia402Params.model_validate(raw)
    (usage,) = Cia402Driver.bus_usage(params, NAMES, 1000.0)
    assert usage.bits_per_second / usage.capacity < 0.85  # 1 kHz fits on FD with a 5 Mbit/s data phase (classic: 167 %)
    assert not {0x281, 0x286} & usage.ids  # no second TPDO


def test_velocity_pdo_adds_a_second_tpdo() -> None:
    def usage(feedback: str) -> Any:
        raw = robot(1, velocity_feedback=feedback)["hardware"]["arm"]["params"]
        (used,) = Cia402Driver.bus_usage(Cia402Params.model_validate(raw), NAMES[:1], 500.0)
        return used

    derived, pdo = usage("derived"), usage("pdo")
    assert 0x281 in pdo.ids and 0x281 not in derived.ids
    assert pdo.bits_per_second - derived.bits_per_second == pytest.approx(500 * frame_bits(4))  # 0x606C


def test_review_findings(tmp_path: Path) -> None:
    params = Cia402Params.model_validate(
        robot(2, heartbeat_ms=100, heartbeat_timeout_ms=50)["hardware"]["arm"]["params"]
    )
    messages = [f.message for f in Cia402Driver.review(params, ["j1", "j2"], 300.0)]
    assert any("heartbeat_timeout_ms 50 must exceed heartbeat_ms 100" in m for m in messages)
    assert any("0x60C2 interpolation period cannot express the cycle period 3.33333 ms" in m for m in messages)


def test_review_warns_of_coarse_scales(tmp_path: Path) -> None:
    raw = robot(2, mode="csp")["hardware"]["arm"]["params"]
    raw["drives"]["j1"] |= {"counts_per_rev": 4096, "rated_torque": 100.0}
    params = Cia402Params.model_validate(raw)
    findings = Cia402Driver.review_files(params, ["j1", "j2"], 500.0, tmp_path)
    text = "; ".join(f"{f.level}: {f.message}" for f in findings)
    assert "warning: j1: one position unit is 1.53 mrad at the actuator" in text
    assert "warning: j1: one per mille of rated torque is 100 mN·m" in text
    assert "j2" not in text  # the EDS's 2^17 counts per rev and 10 N·m are fine


def test_review_names_a_mode_the_eds_lacks_and_a_missing_file(tmp_path: Path) -> None:
    raw = robot(1)["hardware"]["arm"]["params"]
    raw["eds"] = "missing.eds"
    params = Cia402Params.model_validate(raw)
    findings = Cia402Driver.review_files(params, ["j1"], 500.0, tmp_path)
    assert [f.level for f in findings] == ["error"] and "cannot read the EDS" in findings[0].message


def test_a_missing_eds_is_refused_at_load(tmp_path: Path) -> None:
    config = robot(1)
    config["hardware"]["arm"]["params"]["eds"] = "nowhere.eds"
    with pytest.raises(ConfigError, match=r"hardware\.arm\.params\.eds: file not found: .*nowhere\.eds"):
        load(tmp_path, config)


def test_drives_that_brake_on_disable_hold_at_stop() -> None:
    """hild check's stop review asks for stop_descent only where disabling drops the arm."""
    raw = robot(2)["hardware"]["arm"]["params"]
    assert not Cia402Driver.holds_at_stop(Cia402Params.model_validate(raw))
    assert Cia402Driver.holds_at_stop(Cia402Params.model_validate({**raw, "brakes": True}))
    assert Cia402Driver.holds_at_stop(Cia402Params.model_validate({**raw, "on_deactivate": "hold"}))
