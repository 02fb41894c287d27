"""The CAN bridge's config rewrite (pure, no sockets), and the rig process that serves the channels."""

from __future__ import annotations

import json
import time
from pathlib import Path

import can

from drivers.can.params import MitCanParams
from drivers.can.protocol.mit import encode_command
from drivers.can.wiring import wire_motors
from hild.bench.rigs.can_bridge import bridged_document, virtual_channels
from hild.bench.rigs.can_process import CanRigProcess
from hild.bench.rigs.mit_can import robot_config
from hild.config.documents import load_document
from tests.helpers import wait_for


def test_virtual_buses_are_renamed_to_their_servers_and_nothing_else_changes() -> None:
    data = {
        "robot": {"name": "can6"},
        "hardware": {
            "bus1": {"driver": "mit_can", "params": {"bus": {"interface": "virtual", "channel": "a", "bitrate": 1}}},
            "bus2": {"driver": "mit_can", "params": {"bus": {"interface": "virtual", "channel": "b"}}},
            "can0": {"driver": "mit_can", "params": {"bus": {"interface": "socketcan", "channel": "can0"}}},
            "twin": {"driver": "mujoco", "params": {"model": "arm6.xml"}},
        },
    }
    assert virtual_channels(data) == ["a", "b"]
    out = bridged_document(data, {"a": "ws://127.0.0.1:1/", "b": "ws://127.0.0.1:2/"})
    assert out["hardware"]["bus1"]["params"]["bus"] == {
        "interface": "remote",
        "channel": "ws://127.0.0.1:1/",
        "bitrate": 1,
    }
    assert out["hardware"]["bus2"]["params"]["bus"]["channel"] == "ws://127.0.0.1:2/"
    assert out["hardware"]["can0"] == data["hardware"]["can0"] and out["hardware"]["twin"] == data["hardware"]["twin"]
    assert data["hardware"]["bus1"]["params"]["bus"]["interface"] == "virtual"  # the input is left alone


def test_the_rig_process_serves_each_channel_and_stamps_the_frames_it_reads(tmp_path: Path) -> None:
    """The [teleop] fix: the emulated drives in a process of their own, each bus a loopback server their loop
    reads; a frame sent to it is kept with a perf_counter_ns stamp between its send and the read-back."""
    config = tmp_path / "can3.yaml"
    data = robot_config(3, 1000.0)
    config.write_text(json.dumps(data))
    bus1 = data["hardware"]["bus1"]
    wiring, problems = wire_motors(MitCanParams.model_validate(bus1["params"]), list(bus1["joints"]))
    assert not problems
    rig = CanRigProcess()
    try:
        bridged = load_document(rig.serve(config))
        channel = bridged["hardware"]["bus1"]["params"]["bus"]
        assert channel["interface"] == "remote" and channel["channel"].startswith("ws://127.0.0.1:")
        assert set(rig.processes()) == {"emulator"} and rig.threads() == {}  # none of the daemon's threads
        assert rig.listen(True)["joint"] == "j1"
        client = can.Bus(interface="remote", channel=channel["channel"], receive_own_messages=False)
        try:
            sent = time.perf_counter_ns()
            frame = encode_command(0.1, 0.0, 0.0, 0.0, 0.0, wiring[0].ranges)
            client.send(can.Message(arbitration_id=wiring[0].command_id, data=frame, is_extended_id=False))
            wait_for(lambda: rig.counters().get("emulator handled", 0) >= 1, what="the drive to handle the frame")
        finally:
            client.shutdown()
        heard = rig.listen(False)
        ((stamp, position),) = heard["command"]
        assert sent < stamp < time.perf_counter_ns() and abs(position - 0.1) <= heard["lsb"]
    finally:
        rig.stop()
    assert rig.processes() == {}
