"""SpawnedCycle without a cycle process behind it: what the client domain does when the cycle does not answer."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from hild.config import load_config
from hild.crossing.cells import REQUESTS, Ask, Vital
from hild.crossing.requests import Refused, Reset
from hild.daemon.remote import SpawnedCycle
from tests.conftest import mock_robot


@pytest.fixture
def remote(write_config: Callable[..., Path]) -> Iterator[SpawnedCycle]:
    cycle = SpawnedCycle(load_config(write_config(mock_robot())))
    yield cycle
    cycle.close()


def test_a_full_request_queue_refuses_at_once_and_an_estop_still_goes_through(remote: SpawnedCycle) -> None:
    accepted = [remote.request(Reset()) for _ in range(REQUESTS)]
    assert not any(f.done() for f in accepted)  # queued: the cycle has not run
    assert all(not f.cancel() for f in accepted)  # in the queue: it will be applied, it cannot be withdrawn
    refused = remote.request(Reset())
    with pytest.raises(Refused, match="too many pending requests"):
        refused.result(timeout=0)
    estop = remote.request_estop()  # never queued behind them
    assert int(remote.cells.asks[Ask.ESTOP]) == 1 and not estop.done()


def test_requests_of_a_cycle_that_is_gone_are_answered(remote: SpawnedCycle) -> None:
    waiting = [remote.request(Reset()), remote.request_estop()]
    remote.abandon("the cycle process ended")
    for future in waiting:
        with pytest.raises(Refused, match="the cycle process ended"):
            future.result(timeout=0)


def test_events_the_cycle_could_not_hand_over_are_reported_as_lost(remote: SpawnedCycle) -> None:
    remote.cells.events.offer((1.0, "info", "engine", "kept"))
    remote.cells.vitals[Vital.EVENTS_LOST] = 7  # the cycle found the queue full seven times
    events = remote.take()
    assert len(events) == 2 and events[0].message == "kept"
    assert events[-1].level == "warning" and events[-1].message.startswith("7 events of the cycle were lost")
    assert remote.take() == []  # reported once
