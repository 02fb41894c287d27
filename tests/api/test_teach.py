"""``hild ctl teach``, the ``teach`` service and ``HildClient.teach`` over Zenoh on the arm6 twin: on loads and
switches a teach controller in (deactivating the controllers on those joints), off brakes and hands over to hold,
single joints on and off, a wider set replaces the controller, refusals under e-stop and for unknown joints."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from hild.api.client import HildClient, HildError
from hild.api.ctl import EXIT_OK, EXIT_SERVICE
from hild.config import load_config
from hild.cycle.engine import Engine
from tests.api.conftest import Daemon
from tests.api.test_ctl import ctl
from tests.controllers.test_teach import JOINTS, arm6_config, engine_of
from tests.helpers import free_endpoint


@pytest.fixture
def arm(tmp_path: Path) -> Iterator[Daemon]:
    config = arm6_config()
    del config["controllers"]["teach"]  # the service loads it
    engine_of(tmp_path, config).stop()  # writes robot.yaml and arm6.xml; a fresh engine serves
    daemon = Daemon(Engine(load_config(tmp_path / "robot.yaml")), free_endpoint())
    daemon.start()
    try:
        yield daemon
    finally:
        daemon.stop()


def modes(client: HildClient) -> dict[str, str]:
    return {j["name"]: ("teach" if j.get("teach") else j["mode"]) for j in client.status()["joints"]}


def test_teach_on_and_off_through_ctl(arm: Daemon, capsys: pytest.CaptureFixture[str]) -> None:
    assert ctl(arm, "switch", "--activate", "hold_all") == EXIT_OK
    capsys.readouterr()
    assert ctl(arm, "--json", "teach", "on") == EXIT_OK
    reply = json.loads(capsys.readouterr().out)
    assert reply["ok"] and reply["teach"] == JOINTS and reply["deactivated"] == ["hold_all"] and reply["loaded"]
    assert ctl(arm, "status") == EXIT_OK
    out = capsys.readouterr().out
    assert out.count("teach") >= len(JOINTS)  # every joint's mode, and the controller
    assert ctl(arm, "teach", "off") == EXIT_OK
    out = capsys.readouterr().out
    assert "in teach: none" in out and "deactivated teach" in out and "held where released: shoulder_pan" in out
    with HildClient(None, [arm.endpoint], 2.0) as client:
        assert set(modes(client).values()) == {"hold"}
    assert not arm.engine.supervisor.fault.any()


def test_single_joints_on_and_off_and_a_wider_set(arm: Daemon) -> None:
    with HildClient(None, [arm.endpoint], 2.0) as client:
        reply = client.teach(True, ["wrist_2", "wrist_3"])
        assert reply["teach"] == ["wrist_2", "wrist_3"] and reply["deactivated"] == []
        reply = client.teach(False, ["wrist_3"])
        assert reply["released"] == ["wrist_3"] and reply["teach"] == ["wrist_2"] and reply["deactivated"] == []
        assert modes(client)["wrist_3"] == "hold" and modes(client)["wrist_2"] == "teach"
        reply = client.teach(True, ["wrist_3"])  # still its joint: turned on again through its input
        assert reply["teach"] == ["wrist_2", "wrist_3"] and reply["loaded"] is False
        reply = client.teach(True, ["wrist_1"])  # wider: the controller is replaced, its joints handed over first
        assert reply["teach"] == ["wrist_1", "wrist_2", "wrist_3"] and reply["loaded"] is True
        assert [m for j, m in modes(client).items() if m == "teach"] == ["teach"] * 3
        reply = client.teach(False)
        assert reply["teach"] == [] and reply["deactivated"] == ["teach"]
        assert client.teach(False)["teach"] == []  # nothing in teach: nothing to do


def test_refusals(arm: Daemon) -> None:
    with HildClient(None, [arm.endpoint], 2.0) as client:
        with pytest.raises(HildError, match="unknown joints"):
            client.teach(True, ["gripper"])
        reply = client.call("teach", {"joints": ["wrist_1"]}, check=False)
        assert not reply["ok"] and '"on"' in reply["error"]
        reply = client.call("teach", {"on": True, "joints": ["wrist_1", "wrist_1"]}, check=False)
        assert not reply["ok"] and "twice" in reply["error"]
        with pytest.raises(HildError, match="no joint is in teach"):
            client.teach(False, ["wrist_1"])
        client.estop()
        with pytest.raises(HildError, match="e-stop is engaged"):
            client.teach(True)
        client.reset()
        client.teach(True, ["elbow"])
        with pytest.raises(HildError, match="not in teach"):
            client.teach(False, ["wrist_1"])
        before = arm.engine.state.position.copy()
        client.teach(False)
        assert np.abs(arm.engine.state.position - before).max() < 0.01  # nothing moved the arm


def test_ctl_teach_says_why_it_was_refused(arm: Daemon, capsys: pytest.CaptureFixture[str]) -> None:
    assert ctl(arm, "teach", "on", "nose") == EXIT_SERVICE
    assert "unknown joints ['nose']" in capsys.readouterr().err
