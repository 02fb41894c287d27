"""One robot name, one daemon (issue [trust], finding 9): behind one network, two daemons of one robot name both
answered every switch and one streamed command moved both arms. A second daemon now refuses to start, naming the
first; one that appears later (the first cannot refuse it) is reported by the first as an error event."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from hild.api.unique import RobotNameTaken
from hild.config import load_config
from hild.config.model import ZenohSection
from hild.engine import Engine
from tests.api.conftest import Daemon, free_endpoint, robot_config, wait_for


def another_engine(tmp_path: Path, name: str = "second.yaml") -> Engine:
    path = tmp_path / name
    path.write_text(yaml.safe_dump(robot_config(), sort_keys=False))
    return Engine(load_config(path))


def connected_to(endpoint: str) -> ZenohSection:
    return ZenohSection(connect=[endpoint])


def test_a_second_daemon_of_the_same_robot_refuses_to_start(daemon: Daemon, tmp_path: Path) -> None:
    second = Daemon(another_engine(tmp_path), free_endpoint(), connected_to(daemon.endpoint))
    second.thread.start()
    try:
        second.engine.bring_up()
        with pytest.raises(RobotNameTaken) as refused:
            second.run(second.server.start())
        text = str(refused.value)
        assert text.startswith("robot 'mock3' already has a daemon on this Zenoh network (Zenoh id ")
        assert f"listening on {daemon.endpoint}" in text  # where the other one runs, as it answers it
        assert not second.engine.started  # nothing was enabled
    finally:
        second.loop.call_soon_threadsafe(second.loop.stop)
        second.thread.join(10)
        second.engine.release()
    # The first one is untouched: it still answers.
    assert daemon.events_with("appeared") == []


def test_a_daemon_reports_another_that_appears_later(
    daemon: Daemon, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import hild.api.server as server

    # The second one starts without looking (an older hild, or both started at the same instant).
    monkeypatch.setattr(server, "check_unique", lambda session, keys: None)
    second = Daemon(another_engine(tmp_path), free_endpoint(), connected_to(daemon.endpoint))
    second.start()
    try:
        events = wait_for(lambda: daemon.events_with("another daemon of robot 'mock3' appeared"), what="the report")
        assert events[0]["level"] == "error" and f"listening on {second.endpoint}" in events[0]["message"]
        assert len(daemon.events_with("appeared")) == 1  # once, not per cycle
    finally:
        second.stop()
