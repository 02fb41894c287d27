"""Security: loopback by default, and the roles of configs/secure/ enforced by Zenoh against the real API server.

The daemon runs the committed ``configs/secure/zenoh-server.json5`` (its access-control rules unchanged) on a free
loopback port, with a temporary password file; clients use the committed ``zenoh-<role>.json5`` files. Without TLS
the subjects' certificate names are dropped (a TCP link carries none); the TLS test keeps the file as written and
uses certificates from ``make-certs.sh``. "Never reached the daemon" is read from the server's own counters.
"""

from __future__ import annotations

import argparse
import ipaddress
import json
import secrets
import subprocess
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hild.api.client import HildClient, HildUnreachable
from hild.api.ctl import EXIT_OK, EXIT_UNREACHABLE, ZENOH_CONFIG_ENV, add_ctl_parser, run_ctl
from hild.api.session import client_config, file_endpoints, server_config
from hild.cli import main as hild_main
from hild.config import load_config
from hild.config.model import TelemetrySection, ZenohSection
from hild.cycle.engine import Engine
from tests.api.conftest import ROBOT, Daemon, engine_with_trajectory
from tests.conftest import CONFIGS
from tests.helpers import free_endpoint, wait_for

SECURE = CONFIGS / "secure"
SERVER_FILE = SECURE / "zenoh-server.json5"
ROLES = ("operator", "observer", "estop")
TIMEOUT = 5.0  # s per request; a denied query must end long before it
TARGET = [0.3, -0.2, 0.25]


# ---- fixtures ---------------------------------------------------------------------------------------------------
@pytest.fixture
def engine(tmp_path: Path) -> Engine:
    return engine_with_trajectory(tmp_path)


@pytest.fixture
def passwords(tmp_path: Path) -> dict[str, str]:
    return {role: secrets.token_hex(8) for role in ROLES}


def users_file(directory: Path, passwords: dict[str, str]) -> Path:
    path = directory / "users.txt"
    path.write_text("".join(f"{user}:{password}\n" for user, password in passwords.items()))
    return path


def subjects_without_certificates() -> list[dict[str, Any]]:
    """The committed subjects, matched on the username only (a TCP link has no certificate name to match)."""
    committed = json.loads(server_config(ZenohSection(config_file=str(SERVER_FILE))).get_json("access_control"))
    return [{"id": s["id"], "usernames": s["usernames"]} for s in committed["subjects"]]


@pytest.fixture
def secure_daemon(engine: Engine, tmp_path: Path, passwords: dict[str, str]) -> Iterator[Daemon]:
    """The committed server file over TCP: user/password and access control, no TLS."""
    settings = ZenohSection(
        config_file=str(SERVER_FILE),
        config={
            "transport.link.protocols": ["tcp"],
            "transport.auth.usrpwd.dictionary_file": str(users_file(tmp_path, passwords)),
            "access_control.subjects": subjects_without_certificates(),
        },
    )
    daemon = Daemon(engine, free_endpoint(), settings)
    daemon.start()
    try:
        yield daemon
    finally:
        daemon.stop()


def role_client(
    role: str, endpoint: str, password: str, overrides: dict[str, Any] | None = None, tcp: bool = True
) -> HildClient:
    """A client loaded from the committed ``zenoh-<role>.json5``, with this test's password and endpoint."""
    extra: dict[str, Any] = {"transport.auth.usrpwd.password": password}
    if tcp:
        extra["transport.link.protocols"] = ["tcp"]
    extra.update(overrides or {})
    return HildClient(
        ROBOT, connect=[endpoint], timeout=TIMEOUT, zenoh_config=SECURE / f"zenoh-{role}.json5", zenoh_overrides=extra
    )


@pytest.fixture
def clients(secure_daemon: Daemon, passwords: dict[str, str]) -> Iterator[dict[str, HildClient]]:
    opened = {role: role_client(role, secure_daemon.endpoint, passwords[role]) for role in ROLES}
    try:
        yield opened
    finally:
        for client in opened.values():
            client.close()


# ---- helpers ----------------------------------------------------------------------------------------------------
def refused(daemon: Daemon, attempt: Callable[[], Any]) -> None:
    """The request is denied by Zenoh before the daemon sees it: no reply, at once, and no query counted."""
    before = daemon.server.counters.queries
    start = time.monotonic()
    with pytest.raises(HildUnreachable, match=r"no reply .* access control refused this station"):
        attempt()
    assert time.monotonic() - start < TIMEOUT / 2, "a denied query should end at once, not by timing out"
    assert daemon.server.counters.queries == before


def controller_state(client: HildClient, name: str) -> str:
    return next(c["state"] for c in client.list_controllers() if c["name"] == name)


def mock_position(engine: Engine) -> np.ndarray:
    return engine.hardware[0].component.position.copy()


def commands_received(daemon: Daemon, count: int) -> bool:
    return daemon.server.counters.commands >= count


# ---- defaults: loopback ------------------------------------------------------------------------------------------
def is_loopback(endpoint: str) -> bool:
    host = endpoint.split("/", 1)[1].rsplit(":", 1)[0].strip("[]")
    return host == "localhost" or ipaddress.ip_address(host).is_loopback


def test_default_daemon_and_client_configs_stay_on_loopback() -> None:
    server = server_config(ZenohSection())
    listen = json.loads(server.get_json("listen/endpoints"))
    assert listen and all(is_loopback(e) for e in listen), listen
    assert json.loads(server.get_json("scouting/multicast/enabled")) is False
    assert json.loads(server.get_json("scouting/gossip/enabled")) is False
    client = client_config()
    assert json.loads(client.get_json("listen/endpoints")) == []
    assert all(is_loopback(e) for e in json.loads(client.get_json("connect/endpoints")))
    assert json.loads(client.get_json("scouting/multicast/enabled")) is False
    for path in sorted(CONFIGS.glob("*.yaml")):  # the configs people start from keep the defaults
        zenoh = load_config(path).config.zenoh
        assert all(is_loopback(e) for e in zenoh.listen) and not zenoh.multicast_scouting, path.name


def test_rerun_serve_sink_binds_loopback_by_default() -> None:
    """Config level; tests/telemetry checks the bound socket itself (/proc/net/tcp: 127.0.0.1 only)."""
    telemetry = TelemetrySection.model_validate({"enabled": True, "sinks": [{"kind": "serve"}]})
    assert ipaddress.ip_address(telemetry.sinks[0].bind).is_loopback


# ---- the secure example -------------------------------------------------------------------------------------------
def test_secure_example_checks_and_builds_a_tls_only_access_controlled_session() -> None:
    path = SECURE / "arm6_twin_secure.yaml"
    assert hild_main(["check", str(path)]) == 0
    loaded = load_config(path)
    assert loaded.config.zenoh.listen and all(e.startswith("tls/") for e in loaded.config.zenoh.listen)
    config = server_config(loaded.config.zenoh, base_dir=loaded.directory)
    acl = json.loads(config.get_json("access_control"))
    assert acl["enabled"] is True and acl["default_permission"] == "deny"
    assert {p["id"] for p in acl["policies"]} == set(ROLES)
    assert json.loads(config.get_json("transport/link/protocols")) == ["tls"]
    assert json.loads(config.get_json("transport/link/tls/enable_mtls")) is True
    assert json.loads(config.get_json("scouting/multicast/enabled")) is False
    for role in ROLES:
        assert all(e.startswith("tls/") for e in file_endpoints(SECURE / f"zenoh-{role}.json5"))
    assert not [p.name for p in SECURE.iterdir() if p.suffix in (".key", ".pem", ".txt")], "no keys or passwords"


# ---- roles over user/password + access control ------------------------------------------------------------------
def test_an_operators_goal_stops_when_the_operator_goes(
    secure_daemon: Daemon, clients: dict[str, HildClient], passwords: dict[str, str]
) -> None:
    """The committed rules let a goal sender's liveliness token in, so on_client_lost: stop works on the robot
    network too (without the rule, the token is dropped and every goal behaves as on_client_lost: continue)."""
    watcher = clients["operator"]
    watcher.switch(activate=["traj"])
    leaving = role_client("operator", secure_daemon.endpoint, passwords["operator"])
    handle = leaving.send_goal("traj", {"positions": TARGET, "duration": 30.0})
    handle.close()
    leaving.close()

    def ended() -> bool:
        return watcher.goal_result("traj", handle.goal_id)["status"] not in ("accepted", "executing")

    wait_for(ended, what="the lost operator's goal to end")
    result = watcher.goal_result("traj", handle.goal_id)
    assert result["status"] == "aborted" and leaving.client_id in result["error_string"], result


def test_operator_switches_and_runs_a_goal(secure_daemon: Daemon, clients: dict[str, HildClient]) -> None:
    operator, observer = clients["operator"], clients["observer"]
    assert operator.discover() == [ROBOT]
    operator.switch(activate=["traj"])
    assert controller_state(operator, "traj") == "active"
    result = operator.move_to("traj", TARGET, timeout=20.0)
    assert result["status"] == "succeeded", result
    state = observer.next_message("joint_states", TIMEOUT)  # the observer sees the arm move
    np.testing.assert_allclose(state["position"], TARGET, atol=1e-3)

    # Streamed commands: the operator's reach the daemon and move the arm.
    operator.switch(activate=["fwd"], deactivate=["traj"])
    before = secure_daemon.server.counters.commands
    operator.send("fwd", [0.0, 0.0, 0.0])
    wait_for(lambda: commands_received(secure_daemon, before + 1), what="the operator's command")
    assert secure_daemon.server.counters.accepted >= 1


def test_observer_reads_but_cannot_command(
    secure_daemon: Daemon, clients: dict[str, HildClient], engine: Engine
) -> None:
    operator, observer = clients["operator"], clients["observer"]
    start = mock_position(engine)
    assert observer.discover() == [ROBOT]
    assert observer.status()["mode"] == "hold"
    assert {c["name"] for c in observer.list_controllers()} >= {"fwd", "traj"}
    assert observer.list_interfaces() and observer.list_hardware()
    state = observer.next_message("joint_states", TIMEOUT)
    assert state["name"] == ["a", "b", "c"]

    refused(secure_daemon, lambda: observer.switch(activate=["traj"]))
    refused(secure_daemon, lambda: observer.move_to("traj", TARGET))
    refused(secure_daemon, observer.estop)
    refused(secure_daemon, observer.reset)
    refused(secure_daemon, lambda: observer.call("enable", {"joints": []}))
    refused(secure_daemon, lambda: observer.call("set_zero", {"joint": "a", "confirm": True}))
    refused(secure_daemon, lambda: observer.call("home", {"joint": "a"}))
    # The operator's reaches the daemon (whose mock cannot home: the driver's refusal is the reply).
    assert "no homing configured" in operator.call("home", {"joint": "a"}, check=False)["error"]
    status = operator.status()
    assert status["mode"] == "hold"
    assert {c["name"]: c["state"] for c in status["controllers"]}["traj"] == "inactive"
    np.testing.assert_array_equal(mock_position(engine), start)

    # Its streamed commands never leave it (it is never shown hild's subscribers); the operator's next one arrives.
    operator.switch(activate=["fwd"])
    before = secure_daemon.server.counters.commands
    for _ in range(20):
        observer.send("fwd", [0.9, 0.9, 0.9])
    observer.status()
    operator.send("fwd", state["position"])  # hold where it is
    wait_for(lambda: commands_received(secure_daemon, before + 1), what="the operator's command")
    operator.status()  # one more round trip for any straggler
    assert secure_daemon.server.counters.commands == before + 1
    np.testing.assert_allclose(mock_position(engine), start, atol=1e-6)  # nothing went towards the observer's 0.9


def test_estop_station_can_stop_but_not_move_or_reset(secure_daemon: Daemon, clients: dict[str, HildClient]) -> None:
    operator, estop = clients["operator"], clients["estop"]
    assert estop.discover() == [ROBOT]
    assert estop.status()["mode"] == "hold"
    refused(secure_daemon, lambda: estop.switch(activate=["traj"]))
    refused(secure_daemon, lambda: estop.move_to("traj", TARGET))
    refused(secure_daemon, lambda: estop.list_controllers())
    operator.switch(activate=["fwd"])

    assert estop.estop()["deactivated"] == ["fwd"]
    assert estop.status()["mode"] == "estop"
    refused(secure_daemon, estop.reset)
    assert operator.status()["mode"] == "estop"
    assert operator.reset()["cleared"] == ["e-stop"]
    assert estop.status()["mode"] == "hold"


def test_unknown_users_and_wrong_passwords_get_no_session(
    secure_daemon: Daemon, passwords: dict[str, str], tmp_path: Path
) -> None:
    with pytest.raises(HildUnreachable, match="cannot reach"):
        role_client("operator", secure_daemon.endpoint, "wrong-" + passwords["operator"])
    with pytest.raises(HildUnreachable, match="cannot reach"):
        role_client("operator", secure_daemon.endpoint, passwords["operator"], {"transport.auth.usrpwd.user": "eve"})
    with pytest.raises(HildUnreachable, match="cannot reach"):
        HildClient(ROBOT, connect=[secure_daemon.endpoint], timeout=TIMEOUT)  # no credentials at all
    assert secure_daemon.server.counters.queries == 0


def parse_ctl(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="hild")
    add_ctl_parser(parser.add_subparsers(dest="command", required=True))
    return parser.parse_args(["ctl", *argv])


def test_ctl_takes_a_zenoh_config_file_or_the_environment(
    secure_daemon: Daemon,
    passwords: dict[str, str],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    station = tmp_path / "observer.json5"  # JSON is JSON5; the endpoint comes from the file (no --connect)
    station.write_text(
        json.dumps(
            {
                "connect": {"endpoints": [secure_daemon.endpoint]},
                "transport": {"auth": {"usrpwd": {"user": "observer", "password": passwords["observer"]}}},
            }
        )
    )
    assert run_ctl(parse_ctl("--zenoh-config", str(station), "--json", "status")) == EXIT_OK
    assert json.loads(capsys.readouterr().out)["mode"] == "hold"

    monkeypatch.setenv(ZENOH_CONFIG_ENV, str(station))
    assert run_ctl(parse_ctl("switch", "--activate", "traj")) == EXIT_UNREACHABLE
    assert "access control refused" in capsys.readouterr().err
    assert run_ctl(parse_ctl("controllers")) == EXIT_OK

    monkeypatch.delenv(ZENOH_CONFIG_ENV)
    assert run_ctl(parse_ctl("--connect", secure_daemon.endpoint, "status")) == EXIT_UNREACHABLE  # no password
    assert run_ctl(parse_ctl("--zenoh-config", str(tmp_path / "missing.json5"), "status")) == EXIT_UNREACHABLE
    assert "missing.json5" in capsys.readouterr().err


# ---- TLS with client certificates: the committed file as written ------------------------------------------------
def test_tls_roles_need_the_matching_certificate(engine: Engine, tmp_path: Path, passwords: dict[str, str]) -> None:
    certs = tmp_path / "certs"
    subprocess.run(
        ["bash", str(SECURE / "make-certs.sh"), str(certs), "localhost", "127.0.0.1"],
        check=True,
        capture_output=True,
        timeout=60,
    )
    settings = ZenohSection(
        config_file=str(SERVER_FILE),
        config={
            "transport.link.tls.root_ca_certificate": str(certs / "ca.pem"),
            "transport.link.tls.listen_certificate": str(certs / "server.pem"),
            "transport.link.tls.listen_private_key": str(certs / "server.key"),
            "transport.auth.usrpwd.dictionary_file": str(users_file(tmp_path, passwords)),
        },
    )
    endpoint = free_endpoint().replace("tcp/", "tls/")
    daemon = Daemon(engine, endpoint, settings)
    daemon.start()

    def station(role: str, cert: str, password: str, **extra: Any) -> HildClient:
        tls = {
            "transport.link.tls.root_ca_certificate": str(certs / "ca.pem"),
            "transport.link.tls.connect_certificate": str(certs / f"{cert}.pem"),
            "transport.link.tls.connect_private_key": str(certs / f"{cert}.key"),
        }
        return role_client(role, endpoint, password, {**tls, **extra}, tcp=False)

    try:
        with station("operator", "operator", passwords["operator"]) as operator:
            operator.switch(activate=["traj"])
            assert controller_state(operator, "traj") == "active"
        # The operator's password on the observer's certificate matches no role: everything is denied.
        with station("operator", "observer", passwords["operator"]) as borrowed:
            refused(daemon, lambda: borrowed.switch(deactivate=["traj"]))
            refused(daemon, borrowed.status)
        with pytest.raises(HildUnreachable, match="cannot reach"):  # no client certificate: no TLS session
            station("operator", "operator", passwords["operator"], **{"transport.link.tls.enable_mtls": False})
        with station("observer", "observer", passwords["observer"]) as observer:
            assert observer.status()["mode"] == "active"
            refused(daemon, observer.estop)
    finally:
        daemon.stop()
