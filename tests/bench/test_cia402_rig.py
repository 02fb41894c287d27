"""The cia402 bench rig: its robot passes hild check at 500 Hz (the load the bench reports as "check"), its frame
tap counts what crosses in the same worst-case bits, and the bus figures put the two side by side."""

from __future__ import annotations

import json
from pathlib import Path

import can
import pytest

from drivers.can.bus import frame_bits
from hild.bench.rigs.cia402 import robot_config
from hild.bench.rigs.mit_can import FrameTap
from hild.bench.scenarios import bus_figures


def test_six_drives_at_500_hz_load_the_bus_as_hild_check_computes(tmp_path: Path) -> None:
    path = tmp_path / "robot.yaml"
    path.write_text(json.dumps(robot_config(6, 500.0)))
    seconds = 2.0
    per_cycle = 6 * 2 * frame_bits(8) + frame_bits(0)  # an RPDO and a TPDO per drive, then SYNC
    heartbeats = 6 * 10 * frame_bits(1)  # 100 ms
    bits = round((500 * per_cycle + heartbeats) * seconds)
    figures = bus_figures(path, {"bus frames": 13_000, "bus bits": bits}, seconds)
    assert figures["check_load_pct"] == pytest.approx(100.0 * bits / seconds / 1e6, abs=0.1)
    assert figures["measured_load_pct"] == pytest.approx(figures["check_load_pct"], abs=0.1)
    assert figures["frames_per_s"] == 6500


def test_the_frame_tap_counts_every_frame_both_ways_in_worst_case_bits() -> None:
    channel = "hild-test-tap"
    with can.Bus(interface="virtual", channel=channel) as host, can.Bus(interface="virtual", channel=channel) as bus:
        tap = FrameTap(bus, watched={0x201})
        host.send(can.Message(arbitration_id=0x201, data=bytes(8), is_extended_id=False))
        host.send(can.Message(arbitration_id=0x80, data=b"", is_extended_id=False))
        assert tap.recv(1.0) is not None and tap.recv(1.0) is not None
        tap.send(can.Message(arbitration_id=0x181, data=bytes(8), is_extended_id=False))
        assert tap.frame_count == 3
        assert tap.bits == pytest.approx(2 * frame_bits(8) + frame_bits(0))
        assert tap.frames == []  # recording is off: nothing kept
