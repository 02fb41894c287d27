"""Each floor probe and the CAN bench rig return sane figures for a tiny run (no timing targets asserted)."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import can
import pytest

from drivers.can.protocol.flavours import DAMIAO
from drivers.can.protocol.models import ranges_for
from hild.api.client import HildClient, HildError
from hild.bench.floor import measure_empty_threads, probe, run_probe
from hild.bench.host import proc_ticks
from hild.bench.probes.zenoh_loopback import Decoy, zenoh_round_trip
from hild.bench.rigs import rig_class
from hild.bench.rigs.mit_can import CanBenchRig, motors_per_bus
from hild.config import load_config
from hild.config.model import RealtimeSection
from tests.conftest import CONFIGS


def ordered(p: dict[str, float]) -> bool:
    return 0.0 < p["p50"] <= p["p99"] <= p["max"]


def test_python_can_virtual_probe_is_found_by_name_and_times_both_directions() -> None:
    result = probe("can_virtual")(count=200)
    assert result["frames"] == 200
    assert ordered(result["one_way_us"]) and ordered(result["round_trip_us"])
    assert result["round_trip_us"]["p50"] > result["one_way_us"]["p50"]


def test_mj_step_probe_steps_the_configs_model_at_its_physics_step() -> None:
    result = probe("mj_step")(count=50, config=str(CONFIGS / "arm6_twin.yaml"))
    assert result["model"] == "arm6.xml"
    assert result["timestep_ms"] == pytest.approx(1.0)  # 500 Hz, 2 substeps
    assert result["steps"] == 50 and ordered(result["step_us"])


def test_a_missing_or_failing_probe_is_reported_not_raised() -> None:
    assert "no probe 'nope'" in run_probe("nope")["error"]
    assert "needs a robot config" in run_probe("mj_step", count=5)["error"]


def test_zenoh_probe_measures_a_round_trip_and_put_to_subscriber_across_processes() -> None:
    result = zenoh_round_trip(count=50, puts=50)
    assert result["lost"] == 0
    assert ordered(result["round_trip_us"])
    assert result["one_way_us"]["p50"] == pytest.approx(result["round_trip_us"]["p50"] / 2, abs=0.1)
    assert result["received"] > 0 and ordered(result["put_to_subscriber_us"])


def test_the_decoy_answers_like_the_daemon_and_takes_servo_targets(tmp_path: Path) -> None:
    status = {"ok": True, "error": None, "robot": "arm", "mode": "hold"}
    spec = str(tmp_path / "decoy.json")
    with (
        Decoy("arm", {"status": json.dumps(status)}, [("servo", "target")], spec) as decoy,
        HildClient("arm", [decoy.endpoint], timeout=5.0) as client,
    ):
        assert client.call("status") == status
        client.servo_stream("servo").send([0.1, 0.2])  # a subscriber takes it; nothing to answer
        with pytest.raises(HildError, match="list_controllers"):
            client.call("list_controllers", timeout=0.5)  # only what it was given


def test_the_empty_thread_runs_hilds_cycle_thread_at_the_rate() -> None:
    (row,) = measure_empty_threads([1000.0], 0.3, RealtimeSection())
    assert row["rate_hz"] == 1000.0
    assert 0 < row["cycles"] <= 400  # paced: never faster than the rate
    assert row["duration_us"]["n"] == row["cycles"]
    assert row["lateness_us"]["n"] > 0
    assert "switch_interval" in row["realtime"] and "timer_slack" in row["realtime"]


def test_proc_ticks_reads_this_process() -> None:
    assert proc_ticks(f"/proc/{os.getpid()}/stat") > 0
    assert proc_ticks("/proc/0/none") == 0


def write(tmp_path: Path, data: dict[str, Any]) -> Path:
    path = tmp_path / "can.yaml"
    path.write_text(json.dumps(data))
    return path


@pytest.mark.parametrize(("motors", "rate", "buses"), [(6, 1000.0, 2), (3, 1000.0, 1), (6, 500.0, 1)])
def test_the_rigs_robot_spreads_motors_over_the_buses_a_config_check_accepts(
    tmp_path: Path, motors: int, rate: float, buses: int
) -> None:
    assert motors_per_bus(1000.0) == 3 and motors_per_bus(500.0) == 6
    loaded = load_config(write(tmp_path, rig_class("mit_can")().robot_config(motors, rate)))
    assert len(loaded.config.hardware) == buses
    assert list(loaded.config.joints) == [f"j{k + 1}" for k in range(motors)]


def test_the_rig_serves_the_drives_and_records_the_first_motors_frames(tmp_path: Path) -> None:
    loaded = load_config(write(tmp_path, CanBenchRig.robot_config(3, 1000.0)))
    params = loaded.driver_params["bus1"]
    rig = CanBenchRig()
    rig.start(loaded)
    host = can.Bus(interface="virtual", channel=params.bus.channel, receive_own_messages=False)
    try:
        assert rig.threads()["emulator"] > 0
        lsb = rig.listen(True)["lsb"]
        ranges = ranges_for("damiao", "DM4340")
        host.send(DAMIAO.command(1, 0.5, 0.0, 0.0, 0.0, 0.0, ranges))
        reply = host.recv(timeout=5.0)
        assert reply is not None and reply.arbitration_id == 0x11
        frames = rig.listen(False)
        assert frames["joint"] == "j1"
        ((_, position),) = frames["command"]
        assert position == pytest.approx(0.5, abs=lsb)
        assert frames["reply"] and frames["reply"][0][0] >= frames["command"][0][0]
        assert rig.counters()["emulator received"] >= 1
    finally:
        host.shutdown()
        rig.stop()


def test_mj_step_gives_the_gil_away_and_pure_python_does_not() -> None:
    """Why the twin's cycle can wait on other threads: each mj_step releases the GIL (measured, not assumed)."""
    import mujoco

    from hild.bench.probes.mj_step import gil_release

    model = mujoco.MjModel.from_xml_path(str(CONFIGS / "arm6.xml"))
    counts = gil_release(model, mujoco.MjData(model), seconds=0.2)
    assert counts["mj_step"] > 1000
    assert counts["pure Python"] == 0
