"""Config safety: unsafe combinations refuse the config on real hardware (with the joint, key and line), and are
warnings on simulated drivers; suspicious ones are warnings everywhere. The shipped configs pass."""

from __future__ import annotations

import uuid
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import pytest

from drivers.can.mit_driver import MitCanDriver
from drivers.mock import MockHardware
from hild.cli import main
from hild.config import ConfigError, load_config
from hild.config.loader import LoadedConfig
from hild.config.params import Params
from hild.config.safety import review_safety
from hild.hardware import GainRange
from tests.conftest import CONFIGS, merge, mock_robot

Write = Callable[..., Path]


def can_robot() -> dict[str, Any]:
    """mock_robot's joints on Damiao motors over a virtual bus: real hardware as far as the rules go."""
    data = mock_robot()
    data["clock"] = {"source": "wall"}
    data["hardware"] = {
        "arm": {
            "driver": "mit_can",
            "params": {
                "bus": {"interface": "virtual", "channel": f"safety-{uuid.uuid4().hex[:8]}"},
                "flavour": "damiao",
                "motors": {j: {"id": k + 1, "reply_id": 0x11 + k, "model": "DM8009"} for k, j in enumerate("abc")},
            },
            "joints": {"a": {}, "b": {}, "c": {}},
        }
    }
    return data


@pytest.fixture
def any_gains(monkeypatch: pytest.MonkeyPatch) -> None:
    """The rules these tests trip are about the joint's effort limit, not the drive's gain range (tested on its own
    below): lift mit_can's kp 500 / kd 5 so the gains that trip them can be written at reduction 1."""
    monkeypatch.setattr(MitCanDriver, "gain_ranges", classmethod(lambda cls, params, joints: {}))


def refused(path: Path) -> list[str]:
    with pytest.raises(ConfigError) as info:
        load_config(path)
    return [str(i) for i in info.value.issues]


def warnings(loaded: LoadedConfig) -> list[str]:
    return [n for n in loaded.notes if n.startswith("warning: ") and "bus " not in n]


@pytest.mark.parametrize(
    "path", sorted(CONFIGS.glob("*.yaml")) + sorted((CONFIGS / "secure").glob("*.yaml")), ids=lambda p: p.name
)
def test_shipped_configs_pass(path: Path) -> None:
    loaded = load_config(path)
    notes = warnings(loaded)
    if path.name == "rrbot_twin.yaml":  # the twin's damping would surge past its effort limit in a collision
        assert len(notes) == 2 and all("a collision at the velocity limit (10 rad/s)" in n for n in notes)
    else:
        assert notes == []


def test_the_base_configs_pass(write_config: Write) -> None:
    assert warnings(load_config(write_config(can_robot()))) == []
    assert warnings(load_config(write_config(mock_robot(), "mock.yaml"))) == []


def test_infinite_limits_are_refused_on_real_hardware_with_the_line(write_config: Write) -> None:
    text = """\
robot: {name: r}
update_rate: 500
hardware:
  arm:
    driver: mit_can
    params: PARAMS
    joints: {a: {}}
joints:
  a:
    limits:
      position: {lower: -1, upper: 1}
      velocity: .inf
      effort: .inf
    hold: {kp: 10, kd: 1}
"""
    can = "{bus: {interface: virtual, channel: inf-limits}, flavour: damiao, motors: {a: {id: 1, model: DM8009}}}"
    path = write_config(text.replace("PARAMS", can))
    issues = refused(path)
    assert f"{path}:12: joints.a.limits.velocity: the velocity limit must be a finite number, not inf" in issues
    assert f"{path}:13: joints.a.limits.effort: the effort limit must be a finite number, not inf" in issues
    mock = write_config(text.replace("driver: mit_can", "driver: mock").replace("PARAMS", "{}"), "mock.yaml")
    notes = warnings(load_config(mock))
    assert any("joints.a.limits.velocity: the velocity limit must be a finite number" in n for n in notes)


def test_a_stiffness_that_outruns_the_effort_clamp_within_a_cycle_is_refused(
    write_config: Write, any_gains: None
) -> None:
    # kp·(overspeed_factor·v)·dt = 20000 · 1.5 · 2 · 0.002 = 120 N·m of spring change in one cycle, against 50 N·m.
    stiff = {"joints": {"b": {"position_gains": {"kp": 20000.0, "kd": 1.0}}}}
    [issue] = refused(write_config(merge(can_robot(), stiff)))
    assert ": joints.b.position_gains: kp 20000: at 3 rad/s (velocity limit × overspeed_factor)" in issue
    assert "torque by kp·v·dt = 120 N·m within one cycle, more than the whole effort limit 50 N·m" in issue
    [note] = warnings(load_config(write_config(merge(mock_robot(), stiff), "mock.yaml")))
    assert "joints.b.position_gains: kp 20000" in note and "(simulated here; refused on real hardware)" in note


def test_the_stiffness_rule_tracks_the_cycle_period(write_config: Write, any_gains: None) -> None:
    """kp·v·dt: the same stiffness is refused at 100 Hz and accepted at 1 kHz."""
    stiff = {"joints": {"a": {"hold": {"kp": 5000.0, "kd": 0.0}}}}  # 5000·3·dt: 150 N·m at 100 Hz, 15 at 1 kHz
    assert any("joints.a.hold" in i for i in refused(write_config(merge(can_robot(), {**stiff, "update_rate": 100}))))
    fast = warnings(load_config(write_config(merge(can_robot(), {**stiff, "update_rate": 1000}), "fast.yaml")))
    assert [n for n in fast if "soft_margin" not in n] == []  # only "the hold saturates inside the soft margin"


@pytest.mark.parametrize(
    ("patch", "key", "surge"),
    [
        ({"hold": {"kp": 100.0, "kd": 30.0}}, "hold", 100 * 2 * 0.002 + 30 * 2),  # 60.4 N·m > 50
        ({"position_gains": {"kp": 100.0, "kd": 40.0}}, "position_gains", 100 * 2 * 0.002 + 40 * 2),
        ({"velocity_gains": {"kd": 26.0}}, "velocity_gains", 26 * 2),
    ],
)
def test_damping_that_surges_past_the_effort_limit_in_a_collision_is_a_warning(
    write_config: Write, patch: dict[str, Any], key: str, surge: float, any_gains: None
) -> None:
    for robot, name in ((can_robot(), "can.yaml"), (mock_robot(), "mock.yaml")):
        [note] = warnings(load_config(write_config(merge(robot, {"joints": {"b": patch}}), name)))
        assert f"joints.b.{key}: " in note and "a collision at the velocity limit (2 rad/s)" in note
        assert f"kp·v·dt + kd·v = {surge:.3g} N·m within one cycle" in note
        assert "more than the effort limit 50 N·m" in note


def test_a_hold_that_saturates_inside_the_soft_margin_is_a_warning(write_config: Write, any_gains: None) -> None:
    # kp 1500 × margin 0.05 = 75 N·m > 50: suspicious, not unsafe (the surge 1500·2·0.002 + 0 = 6 N·m is fine).
    loaded = load_config(write_config(merge(can_robot(), {"joints": {"c": {"hold": {"kp": 1500.0, "kd": 0.0}}}})))
    [note] = warnings(loaded)
    assert "joints.c.hold: hold kp 1500 × soft_margin 0.05 = 75 N·m exceeds the effort limit 50 N·m" in note
    assert "saturates 0.0333 rad from where it holds" in note


def test_no_soft_margin_on_real_hardware_is_a_warning(write_config: Write) -> None:
    loaded = load_config(write_config(merge(can_robot(), {"joints": {"a": {"limits": {"soft_margin": 0.0}}}})))
    [note] = warnings(loaded)
    assert "joints.a.limits.soft_margin: soft_margin 0: commands may reach the hard position limit" in note
    assert warnings(load_config(write_config(merge(mock_robot(), {"joints": {"a": {"limits": {"soft_margin": 0}}}}),
                                             "mock.yaml"))) == []  # fmt: skip


def test_slow_stale_feedback_detection_is_refused_on_real_hardware(write_config: Write) -> None:
    slow = {"safety": {"stale_feedback_cycles": 300}}  # 0.6 s at 500 Hz
    [issue] = refused(write_config(merge(can_robot(), slow)))
    assert "safety.stale_feedback_cycles: 300 cycles at 500 Hz: a servo that stops answering is noticed only " in issue
    assert "after 0.6 s; keep it within 0.5 s on real hardware" in issue
    load_config(write_config(merge(can_robot(), {"safety": {"stale_feedback_cycles": 250}}), "edge.yaml"))  # 0.5 s
    load_config(write_config(merge(mock_robot(), slow), "mock.yaml"))


def test_overrun_detection_disabled_or_slow_is_a_warning(write_config: Write) -> None:
    [off] = warnings(load_config(write_config(merge(can_robot(), {"safety": {"max_consecutive_overruns": 0}}))))
    assert "safety.max_consecutive_overruns: 0 disables the overrun fault" in off
    slow = merge(can_robot(), {"safety": {"max_consecutive_overruns": 400}})
    [late] = warnings(load_config(write_config(slow, "slow.yaml")))
    assert "a stalled cycle faults the joints only after 0.8 s" in late


@pytest.mark.parametrize("key", ["fault_action", "estop_action"])
def test_disable_on_real_hardware_warns_about_gravity(write_config: Write, key: str) -> None:
    [note] = warnings(load_config(write_config(merge(can_robot(), {"safety": {key: "disable"}}))))
    assert f"safety.{key}: disable leaves a, b, c limp: an arm under gravity falls unless these joints" in note
    assert "have brakes or carry no load" in note
    assert warnings(load_config(write_config(merge(mock_robot(), {"safety": {key: "disable"}}), "mock.yaml"))) == []


def test_the_sim_clock_with_real_hardware_is_a_warning(write_config: Write) -> None:
    data = merge(can_robot(), {"clock": {"source": "sim", "real_time_factor": 0}})
    [note] = warnings(load_config(write_config(data)))
    assert "clock.source: the sim clock with real hardware" in note


class RangedDrive(MockHardware):
    """A real drive (as far as the rules know) that accepts kp ≤ 500 and kd ≤ 5 at the motor, like MIT servos."""

    SIMULATED = False

    @classmethod
    def gain_ranges(cls, params: Params, joints: Sequence[str]) -> dict[str, GainRange]:
        return {j: GainRange(500.0, 5.0) for j in joints}


def test_gains_beyond_the_drive_range_after_the_transmission_are_refused(write_config: Write) -> None:
    data = merge(mock_robot(), {"joints": {j: {"hold": {"kp": 600.0, "kd": 8.0}} for j in "abc"}})
    data["hardware"]["bus"]["joints"] = {"a": {}, "b": {"reduction": 2.0}, "c": {"reduction": 1.2}}
    data["joints"]["a"]["limits"]["effort"] = data["joints"]["b"]["limits"]["effort"] = 500.0
    data["joints"]["c"]["limits"]["effort"] = 500.0
    loaded = load_config(write_config(data))  # on the mock: no ranges to respect
    findings = review_safety(loaded.config, {"bus": RangedDrive}, loaded.driver_params)
    errors = {(f.loc, f.message) for f in findings if f.level == "error"}
    # a: 600 > 500 and 8 > 5 at the motor; b: 600/4 = 150, 8/4 = 2, within; c: 600/1.44 = 417 within, 8/1.44 = 5.56 not.
    assert {loc for loc, _ in errors} == {("joints", "a", "hold", "kp"), ("joints", "a", "hold", "kd"),
                                          ("joints", "c", "hold", "kd")}  # fmt: skip
    message = dict(errors)[("joints", "c", "hold", "kd")]
    assert "kd 8 is 5.55556 at the motor (÷ reduction² 1.44), above the drive's range 0..5" in message
    assert "clamp it silently" in message


def test_mit_can_gains_beyond_the_motor_range_are_refused(write_config: Write) -> None:
    """The real driver reports its range (DM8009: kp ≤ 500, kd ≤ 5 at the motor): the codec would clamp silently."""
    issues = refused(write_config(merge(can_robot(), {"joints": {"b": {"hold": {"kp": 600.0, "kd": 1.0}}}})))
    assert any(
        "joints.b.hold.kp: kp 600 is 600 at the motor" in i and "above the drive's range 0..500" in i for i in issues
    )


def test_hild_check_refuses_an_unsafe_config(write_config: Write, capsys: pytest.CaptureFixture[str]) -> None:
    bad = write_config(merge(can_robot(), {"joints": {"a": {"hold": {"kp": 20000.0}}}}))
    assert main(["check", str(bad)]) == 1
    err = capsys.readouterr().err
    assert f"{bad}:" in err and "joints.a.hold: kp 20000: at 3 rad/s" in err
