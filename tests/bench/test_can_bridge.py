"""The CAN bridge's config rewrite: pure, no sockets."""

from __future__ import annotations

from hild.bench.rigs.can_bridge import bridged_document, virtual_channels


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
