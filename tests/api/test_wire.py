"""The pieces without a network: codec, keys, session configs, drop reporting, rendering."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hild.api.codec import MAX_PAYLOAD, PayloadError, decode, encode
from hild.api.keys import Keys, check_chunk, robot_of_alive_key
from hild.api.ports import REPORTS_PER_WINDOW, DropReporter
from hild.api.render import table
from hild.api.session import SessionConfigError, client_config, server_config
from hild.config.model import ZenohSection


def get(config: object, key: str) -> object:
    return json.loads(config.get_json(key))  # type: ignore[attr-defined]


def test_encode_is_always_valid_json() -> None:
    raw = encode({"a": np.array([1.0, np.nan]), "b": float("inf"), "c": np.int64(3), "d": (1, 2)})
    assert json.loads(raw) == {"a": [1.0, None], "b": None, "c": 3, "d": [1, 2]}


@pytest.mark.parametrize(
    ("raw", "reason"),
    [
        (b"NaN", "NaN is not valid JSON"),
        (b'{"a": -Infinity}', "-Infinity is not valid JSON"),
        (b"\xff", "payload is not UTF-8"),
        (b"{", "malformed JSON"),
        (b"[" * 100_000, "malformed JSON"),
        (b" " * (MAX_PAYLOAD + 1), "exceeds"),
    ],
)
def test_decode_is_strict(raw: bytes, reason: str) -> None:
    with pytest.raises(PayloadError, match=reason):
        decode(raw)


def test_keys() -> None:
    keys = Keys("arm")
    assert keys.alive == "hild/arm/alive"
    assert keys.service("estop") == "hild/arm/srv/estop"
    assert keys.input("fwd", "commands") == "hild/arm/ctrl/fwd/commands"
    assert keys.topic("joint_states") == "hild/arm/joint_states"
    assert robot_of_alive_key("hild/arm/alive") == "arm"
    assert robot_of_alive_key("hild/arm/status") is None
    for bad in ("a/b", "*", "a$", "", "..", "x?y", "arm\n"):  # "arm\n": `$` let a final newline by
        with pytest.raises(ValueError, match="cannot be used in a Zenoh key"):
            check_chunk(bad, "name")


def test_server_config_defaults_to_loopback_without_scouting() -> None:
    config = server_config(ZenohSection())
    assert get(config, "mode") == "peer"
    assert get(config, "listen/endpoints") == ["tcp/127.0.0.1:7447"]
    assert get(config, "scouting/multicast/enabled") is False
    assert get(config, "scouting/gossip/enabled") is False


def test_the_daemon_session_has_no_shared_memory_transport(tmp_path: Path) -> None:
    """Issue [layout] 8.1: Zenoh maps each sender's 16 MiB shared-memory pool (payloads of 3 KB and more) and keeps
    it after the sender is gone, so every client session grew the daemon by 16 MiB for good. Off by default, even
    under a config file that turns it on; the passthrough may still turn it on."""
    assert get(server_config(ZenohSection()), "transport/shared_memory/enabled") is False
    (tmp_path / "zenoh.json5").write_text("{transport: {shared_memory: {enabled: true}}}")
    from_file = server_config(ZenohSection(config_file="zenoh.json5"), base_dir=tmp_path)
    assert get(from_file, "transport/shared_memory/enabled") is False
    assert get(server_config(ZenohSection(shared_memory=True)), "transport/shared_memory/enabled") is True
    passthrough = ZenohSection(config={"transport.shared_memory.enabled": True})
    assert get(server_config(passthrough), "transport/shared_memory/enabled") is True


def test_server_config_order_file_then_hild_then_passthrough(tmp_path: Path) -> None:
    (tmp_path / "zenoh.json5").write_text('{mode: "router", transport: {link: {tx: {lease: 3000}}}}')
    settings = ZenohSection(
        mode="peer",
        listen=["tcp/0.0.0.0:7447"],
        connect=["tcp/10.0.0.2:7447"],
        multicast_scouting=True,
        config_file="zenoh.json5",
        config={"transport.link.tx.lease": 2000, "scouting.gossip.enabled": True},
    )
    config = server_config(settings, listen=["tcp/127.0.0.1:9000"], base_dir=tmp_path)
    assert get(config, "mode") == "peer"  # hild's keys override the file
    assert get(config, "listen/endpoints") == ["tcp/127.0.0.1:9000"]  # the command line overrides the config
    assert get(config, "connect/endpoints") == ["tcp/10.0.0.2:7447"]
    assert get(config, "scouting/multicast/enabled") is True
    assert get(config, "transport/link/tx/lease") == 2000  # the passthrough has the last word
    assert get(config, "scouting/gossip/enabled") is True


def test_bad_zenoh_settings_are_named() -> None:
    with pytest.raises(SessionConfigError, match=r"'no/such/key'"):
        server_config(ZenohSection(config={"no.such.key": 1}))
    with pytest.raises(SessionConfigError, match=r"config_file '/nonexistent\.json5'"):
        server_config(ZenohSection(config_file="/nonexistent.json5"))


def test_client_config() -> None:
    config = client_config(["tcp/127.0.0.1:1234"])
    assert get(config, "mode") == "client"
    assert get(config, "connect/endpoints") == ["tcp/127.0.0.1:1234"]
    assert get(config, "scouting/multicast/enabled") is False


def test_drop_reporter_limits_per_key_and_counts_the_rest() -> None:
    emitted: list[str] = []
    reporter = DropReporter(lambda level, source, message: emitted.append(message))
    for _ in range(REPORTS_PER_WINDOW + 5):
        reporter.report("fwd", "k1", "bad")
    reporter.report("fwd", "k2", "bad")
    assert len(emitted) == REPORTS_PER_WINDOW + 1
    assert emitted[-1] == "dropped command on k2: bad"


def test_table_aligns_and_shows_none_as_dash() -> None:
    assert table(["A", "LONG"], [["xyz", None], ["1", 2]]).splitlines() == ["A    LONG", "xyz  -", "1    2"]
