"""Signals: the first SIGTERM/SIGINT asks for an orderly stop; a second one forces the exit at once."""

from __future__ import annotations

import signal
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import zenoh

from hild.api.keys import Keys
from hild.api.session import client_config
from hild.config import load_config
from hild.daemon.daemon import Daemon
from tests.conftest import merge, mock_robot
from tests.helpers import HildRun, free_endpoint


def test_a_second_signal_forces_the_exit(write_config: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    daemon = Daemon(load_config(write_config(mock_robot())))
    exits: list[int] = []
    monkeypatch.setattr("hild.daemon.daemon.os._exit", exits.append)
    daemon._on_signal(signal.SIGTERM)
    assert daemon._stopping.is_set() and exits == []  # orderly: hold, release, exit 0
    daemon._on_signal(signal.SIGINT)
    assert exits == [1]  # the operator insists: out now (the drives' own timeouts take over)


def test_at_sigterm_a_watching_client_sees_the_robot_go_before_the_hardware_is_released(
    write_config: Callable[..., Path],
) -> None:
    """Issue [layout] 8.4: under ``hild run`` the ``alive`` token went only when the client domain closed, after the
    cycle's descent and release. It is withdrawn as the stop begins: a client's liveliness watch sees the robot go
    while the cycle still descends (3 s here), before the engine's "stopped: hardware released"."""
    data = merge(mock_robot(), {"clock": {"real_time_factor": 1.0}, "safety": {"stop_descent": 3.0}})
    with HildRun(write_config(data), endpoint := free_endpoint(), "mock3") as run:
        seen: list[tuple[zenoh.SampleKind, str]] = []

        def on_alive(sample: zenoh.Sample) -> None:  # a Zenoh thread: what the daemon had logged by then
            seen.append((sample.kind, run.log))

        with zenoh.open(client_config([endpoint])) as session:
            watch = session.liveliness().declare_subscriber(Keys("mock3").alive, on_alive, history=True)
            run.wait(lambda: seen, "the alive token")
            run.process.send_signal(signal.SIGTERM)
            run.wait(lambda: len(seen) > 1, "the alive token to go")
            kind, logged = seen[1]
            assert kind == zenoh.SampleKind.DELETE
            assert "stopping: a 3 s damped descent" in logged or "SIGTERM" in logged
            assert "hardware released" not in logged, logged
            watch.undeclare()
        assert run.process.wait(30) == 0  # one SIGTERM: a second would force the exit
    assert "stopped: hardware released" in run.log  # the descent ran to its end after the token went
