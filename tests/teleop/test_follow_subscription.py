"""The subscription plumbing (``Controller.subscriptions``) in one process: a follow controller's leader key is
declared by the API beside its inputs, the cycle takes the newest leader sample each cycle, nothing is reported
while the controller is inactive, and the dead-man input arrives on ``ctrl/<follow>/enable``. The daemon in
miniature of tests/api (a mock engine stepped by a thread, the ApiServer on its loop) and a raw Zenoh publisher
playing the leader."""

from __future__ import annotations

import argparse
import json
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import yaml
import zenoh

from hild.api.client import HildClient
from hild.api.ctl import EXIT_OK, EXIT_SERVICE, add_ctl_parser, run_ctl
from hild.api.session import client_config, open_session
from hild.config import load_config
from hild.cycle.engine import Engine
from hild.modes import JointMode
from tests.api.conftest import Daemon, robot_config
from tests.conftest import merge
from tests.helpers import free_endpoint, wait_for

LEADER_KEY = "hild/lead/joint_states"
TARGET = [0.3, -0.2, 0.1]


class LeaderStream(threading.Thread):
    """Publishes a still leader at ~100 Hz (a seq per message) until stopped."""

    def __init__(self, session: zenoh.Session) -> None:
        super().__init__(name="leader", daemon=True)
        self.publisher = session.declare_publisher(LEADER_KEY)
        self.stopped = threading.Event()

    def run(self) -> None:
        seq = 0
        while not self.stopped.wait(0.01):
            seq += 1
            message = {"stamp": seq * 0.01, "seq": seq, "name": ["a", "b", "c"], "position": TARGET}
            self.publisher.put(json.dumps(message))


@pytest.fixture
def rig(tmp_path: Path) -> Iterator[tuple[Daemon, HildClient, LeaderStream]]:
    cfg = merge(
        robot_config(),
        {
            "joints": {j: {"limits": {"acceleration": 8.0, "jerk": 80.0}} for j in "abc"},
            "controllers": {"follow": {"type": "follow", "params": {"joints": ["a", "b", "c"], "leader": "lead"}}},
        },
    )
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(cfg))
    engine = Engine(load_config(path))
    daemon = Daemon(engine, free_endpoint())
    daemon.start()
    session = open_session(client_config([daemon.endpoint]))
    leader = LeaderStream(session)
    leader.start()
    client = HildClient(connect=[daemon.endpoint], timeout=5.0)
    try:
        yield daemon, client, leader
    finally:
        leader.stopped.set()
        leader.join(5.0)
        client.close()
        session.close()
        daemon.stop()


def test_the_leader_key_is_followed_once_active_and_enabled(rig: tuple[Daemon, HildClient, LeaderStream]) -> None:
    daemon, client, _ = rig
    engine = daemon.engine
    counters = daemon.server.counters
    wait_for(lambda: counters.commands > 20, what="leader samples reaching the controller's slot")
    assert counters.rejected == 0  # inactive: ignored, not refused
    assert not [e for e in daemon.published_events if "lead" in e.get("message", "")]
    client.switch(activate=["follow"])
    stop = threading.Event()

    def hold() -> None:
        while not stop.wait(0.05):
            client.put("follow", {"enable": True}, input="enable")

    holder = threading.Thread(target=hold, daemon=True)
    holder.start()
    try:
        wait_for(lambda: np.allclose(engine.command.position, TARGET, atol=1e-6), what="the follower at the leader")
    finally:
        stop.set()
        holder.join(5.0)
    client.put("follow", {"enable": False}, input="enable")
    wait_for(lambda: (engine.supervisor.mode == JointMode.HOLD).all(), what="hold after release")


def test_hild_ctl_deadman_holds_it_for_its_duration_then_releases(
    rig: tuple[Daemon, HildClient, LeaderStream], capsys: pytest.CaptureFixture[str]
) -> None:
    daemon, client, _ = rig
    assert ctl(daemon, "deadman", "follow", "--duration", "0.2") == EXIT_SERVICE  # not active yet
    assert "hild ctl switch --activate follow" in capsys.readouterr().err
    assert ctl(daemon, "deadman", "fwd") == EXIT_SERVICE
    assert "not a follow controller" in capsys.readouterr().err
    client.switch(activate=["follow"])
    engine = daemon.engine
    follow = engine.manager.records["follow"].instance
    assert ctl(daemon, "--json", "deadman", "follow", "--duration", "1.0", "--rate", "20") == EXIT_OK
    assert json.loads(capsys.readouterr().out)["sent"] >= 5
    wait_for(lambda: follow.released_at > 0.0, what="the release after the duration")  # it had engaged, then let go


def ctl(daemon: Daemon, *argv: str) -> int:
    parser = argparse.ArgumentParser(prog="hild")
    add_ctl_parser(parser.add_subparsers(dest="command", required=True))
    return run_ctl(parser.parse_args(["ctl", "--connect", daemon.endpoint, *argv]))
