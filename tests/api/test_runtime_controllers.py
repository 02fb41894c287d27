"""Controllers loaded, configured, reloaded and unloaded while the robot runs (issue [runtime], item 1), over the
JSON services and the Python client, with the cycle in this process (tests/processes has the three-process case).

The arm never moves because of a lifecycle request: only a switch hands joints to a controller.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from hild.api.client import HildClient, HildError
from hild.api.ctl import EXIT_OK, EXIT_SERVICE
from hild.crossing.requests import Load
from hild.cycle.engine import Engine
from tests.api.conftest import Daemon
from tests.api.test_ctl import ctl
from tests.api.test_services import raw_call
from tests.helpers import wait_for

FWD_PARAMS = {"joints": ["a", "b"], "interface": "position"}


def states(client: HildClient) -> dict[str, str]:
    return {c["name"]: c["state"] for c in client.list_controllers()}


def positions(engine: Engine) -> np.ndarray:
    return engine.state.position.copy()


def test_load_configure_switch_stream_and_unload_a_controller(client: HildClient, daemon: Daemon) -> None:
    engine = daemon.engine
    before = positions(engine)
    reply = client.load_controller("late", "forward_command", FWD_PARAMS)
    assert reply == {"ok": True, "error": None, "name": "late", "type": "forward_command", "state": "unconfigured"}
    assert states(client)["late"] == "unconfigured"
    with pytest.raises(HildError, match="late is not configured"):
        client.switch(["late"])
    assert client.configure_controller("late")["state"] == "inactive"
    np.testing.assert_allclose(positions(engine), before, atol=1e-9)  # loading and configuring moved nothing
    assert [j["mode"] for j in client.status()["joints"]] == ["hold"] * 3

    client.switch(["late"])
    target = [0.3, -0.4]

    def followed() -> bool:
        client.send("late", target)
        return bool(np.allclose(engine.state.position[:2], target, atol=0.01))

    wait_for(followed, what="the joints at the streamed target")
    with pytest.raises(HildError, match="'late' is active; deactivate it first"):
        client.unload_controller("late")
    client.switch([], ["late"])
    assert client.unload_controller("late") == {"ok": True, "error": None, "name": "late"}
    assert "late" not in states(client)
    wait_for(lambda: daemon.events_with("unloaded late"), what="the unload event")
    assert daemon.events_with(f"loaded late (forward_command) by {client.sender}: unconfigured")


def test_a_loaded_controller_gets_its_zenoh_input_and_loses_it_when_unloaded(client: HildClient) -> None:
    publisher = client.session.declare_publisher(client.keys.input("late", "commands"))
    assert not publisher.matching_status.matching
    client.load_controller("late", "forward_command", FWD_PARAMS)
    wait_for(lambda: publisher.matching_status.matching, what="the new controller's input declared")
    client.unload_controller("late")
    wait_for(lambda: not publisher.matching_status.matching, what="its input withdrawn")
    publisher.undeclare()


@pytest.mark.parametrize(
    ("request_", "reason"),
    [
        ({"name": "x", "type": "no_such_type"}, "unknown controller type 'no_such_type' (known: "),
        ({"name": "x", "type": "forward_command", "params": {"joints": ["a"], "bogus": 1}}, "bogus: unknown key"),
        ({"name": "x", "type": "forward_command", "params": {"joints": "a"}}, "controllers.x.params.joints"),
        ({"name": "x", "type": "forward_command", "params": {"joints": ["z"]}}, "unknown joint 'z'"),
        ({"name": "x", "type": "forward_command", "params": {"joints": ["a"], "interface": "current"}}, "current"),
        ({"name": "fwd", "type": "forward_command", "params": FWD_PARAMS}, "'fwd' is already loaded"),
        ({"name": "a/b", "type": "forward_command", "params": FWD_PARAMS}, "cannot be used in a Zenoh key"),
        ({"name": "x", "type": "forward_command", "params": FWD_PARAMS, "fallback_controllers": ["nope"]}, "nope"),
        ({"name": "x", "type": "forward_command", "params": FWD_PARAMS, "autostart": True}, "autostart"),
        ({"name": "x", "type": "forward_command", "params": [1, 2]}, "params must be a JSON object"),
        ({"type": "forward_command"}, 'give the name: {"name": ...}'),
        ({"name": "x"}, "give the controller's type"),
    ],
)
def test_a_load_that_does_not_check_out_is_refused_with_the_reason_and_changes_nothing(
    client: HildClient, request_: dict[str, Any], reason: str
) -> None:
    before = client.list_controllers()
    reply = client.call("load_controller", request_, check=False)
    assert reply["ok"] is False and reason in reply["error"], reply["error"]
    assert client.list_controllers() == before


def test_ten_thousand_params_or_a_megabyte_value_are_refused_before_anything_is_built(client: HildClient) -> None:
    before = client.list_controllers()
    many = {"name": "x", "type": "forward_command", "params": {f"p{i}": i for i in range(10_000)}}
    reply = raw_call(client, "load_controller", json.dumps(many).encode())
    assert reply["ok"] is False and "exceeds the" in reply["error"], reply["error"]
    huge = {"name": "x", "type": "forward_command", "params": {"joints": ["a"], "interface": "x" * (1 << 20)}}
    reply = raw_call(client, "load_controller", json.dumps(huge).encode())
    assert reply["ok"] is False and "exceeds the" in reply["error"], reply["error"]
    assert client.list_controllers() == before


def test_configure_and_unload_name_a_loaded_controller(client: HildClient) -> None:
    for service in ("configure_controller", "unload_controller", "reload_controller"):
        reply = client.call(service, {"name": "ghost"}, check=False)
        assert reply["ok"] is False
        assert "ghost" in reply["error"], reply["error"]
    reply = client.call("configure_controller", {"name": "fwd", "extra": 1}, check=False)
    assert reply["ok"] is False and "unknown field(s) 'extra'" in reply["error"]


def test_a_controller_another_falls_back_to_stays_loaded(client: HildClient) -> None:
    client.load_controller("late", "forward_command", FWD_PARAMS, fallback_controllers=["fwd_a"])
    with pytest.raises(HildError, match=r"'fwd_a' is the fallback of \['late'\]"):
        client.unload_controller("fwd_a")
    client.unload_controller("late")
    client.unload_controller("fwd_a")
    assert set(states(client)) == {"jsb", "fwd"}


def test_configuring_an_inactive_controller_configures_it_again(client: HildClient) -> None:
    assert client.configure_controller("fwd")["state"] == "inactive"
    client.switch(["fwd"])
    with pytest.raises(HildError, match="'fwd' is active; deactivate it first"):
        client.configure_controller("fwd")


def test_reload_reads_the_config_file_as_it_is_now(client: HildClient, daemon: Daemon) -> None:
    path = Path(daemon.engine.loaded.path)
    config = yaml.safe_load(path.read_text())
    config["controllers"]["fwd_a"]["params"]["joints"] = ["c"]
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    reply = client.reload_controller("fwd_a")
    assert reply["state"] == "inactive"  # it was configured: the new one is too
    fwd_a = next(c for c in client.list_controllers() if c["name"] == "fwd_a")
    assert fwd_a["claimed"] == ["c/position"]
    assert daemon.events_with(f"reloaded fwd_a (forward_command) from {path}")

    client.switch(["fwd_a"])
    with pytest.raises(HildError, match="deactivate it before reloading it"):
        client.reload_controller("fwd_a")
    client.switch([], ["fwd_a"])

    config["controllers"]["fwd_a"]["params"]["joints"] = ["nope"]
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    with pytest.raises(HildError, match="does not load, so nothing was reloaded"):
        client.reload_controller("fwd_a")
    del config["controllers"]["fwd_a"]
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    with pytest.raises(HildError, match="has no controller 'fwd_a'"):
        client.reload_controller("fwd_a")
    assert next(c for c in client.list_controllers() if c["name"] == "fwd_a")["claimed"] == ["c/position"]


def test_list_controller_types_names_each_installed_type_and_its_class(client: HildClient) -> None:
    types = {t["type"]: t["class"] for t in client.list_controller_types()}
    assert types["forward_command"] == "hild.controllers.forward_command:ForwardCommandController"
    assert {"joint_state_broadcaster", "joint_trajectory"} <= set(types)


# ---- on the cycle: after the write, one per cycle -------------------------------------------------------------------
def test_lifecycle_requests_are_applied_after_the_write_one_per_cycle(engine: Engine) -> None:
    engine.start()
    params = engine.loaded.controller_params["fwd"]
    futures = [engine.request(Load(f"late{k}", "forward_command", params)) for k in range(3)]
    written = []
    for _ in range(3):
        engine.step(round(engine.t + engine.period, 12), engine.period)
        written.append(sum(f.done() for f in futures))
    assert written == [1, 2, 3]
    assert [f.result()["state"] for f in futures] == ["unconfigured"] * 3
    engine.stop()


def test_a_constructor_that_raises_is_refused_and_leaves_nothing_loaded(engine: Engine) -> None:
    engine.start()
    bad = engine.request(Load("late", "forward_command", {"joints": ["a"], "interface": "position"}, doors="x"))
    broken = engine.request(Load("late2", "forward_command", {"joints": ["nope"]}))
    engine.run_cycles(2)
    assert bad.result()["state"] == "unconfigured"
    with pytest.raises(Exception, match="late2: building a forward_command failed"):
        broken.result()
    assert "late2" not in engine.manager.records and "late2" not in engine.loads
    engine.stop()


# ---- hild ctl ------------------------------------------------------------------------------------------------------
def test_hild_ctl_load_switch_and_unload_as_a_new_user_would(
    daemon: Daemon, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    params = tmp_path / "fwd.yaml"
    params.write_text("joints: [a, b]\ninterface: position\n")
    assert ctl(daemon, "load", "my_fwd", "--type", "forward_command", "--params", str(params)) == EXIT_OK
    assert capsys.readouterr().out.splitlines() == ["my_fwd: loaded", "my_fwd: configured"]
    assert ctl(daemon, "switch", "--activate", "my_fwd") == EXIT_OK
    assert ctl(daemon, "unload", "my_fwd") == EXIT_SERVICE
    assert "'my_fwd' is active; deactivate it first" in capsys.readouterr().err
    assert ctl(daemon, "switch", "--deactivate", "my_fwd") == EXIT_OK
    assert ctl(daemon, "unload", "my_fwd") == EXIT_OK
    assert capsys.readouterr().out.splitlines()[-1] == "my_fwd: unloaded"

    assert ctl(daemon, "load", "on", "--type", "forward_command", "--params", str(params), "--state", "active") == 0
    assert capsys.readouterr().out.splitlines() == ["on: loaded", "on: configured", "on: activated"]
    assert ctl(daemon, "--json", "load", "raw", "--type", "forward_command", "--state", "unconfigured") == EXIT_SERVICE
    (refusal,) = json.loads(capsys.readouterr().out)
    assert "controllers.raw.params.joints: missing required key" in refusal["error"]
    assert ctl(daemon, "list-types") == EXIT_OK
    assert "hild.controllers.forward_command:ForwardCommandController" in capsys.readouterr().out


def test_hild_ctl_cleanup_and_hardware_state(daemon: Daemon, capsys: pytest.CaptureFixture[str]) -> None:
    assert ctl(daemon, "cleanup", "fwd") == EXIT_OK
    assert capsys.readouterr().out.splitlines() == ["fwd: unconfigured"]
    assert ctl(daemon, "cleanup", "fwd") == EXIT_SERVICE
    assert "'fwd' is unconfigured: it cannot be cleaned up" in capsys.readouterr().err
    assert ctl(daemon, "configure", "fwd") == EXIT_OK and ctl(daemon, "switch", "--activate", "fwd") == EXIT_OK
    capsys.readouterr()
    assert ctl(daemon, "hardware-state", "bus", "inactive") == EXIT_OK
    assert capsys.readouterr().out.splitlines() == ["bus: inactive; deactivated fwd, their joints held"]
    assert ctl(daemon, "interfaces") == EXIT_OK
    listing = capsys.readouterr().out
    assert "AVAILABLE" in listing and " yes" not in listing  # every command interface is out of reach
    assert ctl(daemon, "switch", "--activate", "fwd") == EXIT_SERVICE
    assert "of inactive hardware ['bus'] (set it active first)" in capsys.readouterr().err
    assert ctl(daemon, "hardware-state", "bus", "active") == EXIT_OK
    assert ctl(daemon, "switch", "--activate", "fwd") == EXIT_OK


def test_hild_ctl_load_refuses_a_params_file_that_is_not_a_mapping(
    daemon: Daemon, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    params = tmp_path / "list.yaml"
    params.write_text("- a\n- b\n")
    assert ctl(daemon, "load", "x", "--type", "forward_command", "--params", str(params)) == EXIT_SERVICE
    assert "expected a mapping of params, found list" in capsys.readouterr().err
    assert ctl(daemon, "load", "x", "--type", "forward_command", "--params", str(tmp_path / "none.yaml")) == 1
    assert "none.yaml" in capsys.readouterr().err


def test_hild_ctl_load_chains_a_controller_to_one_loaded_at_runtime(
    daemon: Daemon, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    impedance = tmp_path / "imp.yaml"
    impedance.write_text(
        "joints: [a, b]\nstiffness: [50, 50]\ndamping: [1, 1]\nmax_stiffness: [100, 100]\n"
        "max_damping: [5, 5]\ngravity_compensation: false\n"
    )
    fwd = tmp_path / "fwd.yaml"
    fwd.write_text("joints: [a, b]\ninterface: position\n")
    assert ctl(daemon, "load", "imp", "--type", "joint_impedance", "--params", str(impedance)) == EXIT_OK
    assert (
        ctl(daemon, "load", "fwd_chained", "--type", "forward_command", "--params", str(fwd), "--chain-to", "imp") == 0
    )
    assert ctl(daemon, "switch", "--activate", "fwd_chained") == EXIT_SERVICE  # imp is not active: refused
    assert "chains to imp, which would not be active after the switch" in capsys.readouterr().err
    assert ctl(daemon, "switch", "--activate", "fwd_chained", "imp") == EXIT_OK  # one switch, the chain whole
    capsys.readouterr()
    assert ctl(daemon, "--json", "controllers") == EXIT_OK
    listing = {c["name"]: c for c in json.loads(capsys.readouterr().out)["controllers"]}
    assert listing["fwd_chained"]["chain_to"] == "imp" and listing["fwd_chained"]["state"] == "active"
    assert listing["fwd_chained"]["claimed"] == ["imp/a/position", "imp/b/position"]
    assert listing["imp"]["is_chained"] is True and listing["imp"]["state"] == "active"
