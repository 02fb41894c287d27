"""Fixtures shared by the CAN driver and emulator tests."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from drivers.can.emulator.remote_host import RemoteServerBus


@pytest.fixture
def served() -> Iterator[RemoteServerBus]:
    """`hild emulate --serve-remote`'s bus on a free loopback port, shut down after the test."""
    bus = RemoteServerBus("127.0.0.1", 0)
    try:
        yield bus
    finally:
        bus.shutdown()
