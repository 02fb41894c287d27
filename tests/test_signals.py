"""Signals: the first SIGTERM/SIGINT asks for an orderly stop; a second one forces the exit at once."""

from __future__ import annotations

import signal
from typing import Any

import pytest

from hild.config import load_config
from hild.daemon.daemon import Daemon


def test_a_second_signal_forces_the_exit(write_config: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    from tests.conftest import mock_robot

    daemon = Daemon(load_config(write_config(mock_robot())))
    exits: list[int] = []
    monkeypatch.setattr("hild.daemon.daemon.os._exit", exits.append)
    daemon._on_signal(signal.SIGTERM)
    assert daemon._stopping.is_set() and exits == []  # orderly: hold, release, exit 0
    daemon._on_signal(signal.SIGINT)
    assert exits == [1]  # the operator insists: out now (the drives' own timeouts take over)
