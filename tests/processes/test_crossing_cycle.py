"""Both sides of the crossing in this process, in lockstep: the client domain's SpawnedCycle, and the cycle side's
engine and CrossingCycle attached to the same shared region. No process, no clock: each step is one cycle."""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from hild.config import load_config
from hild.crossing.cells import REQUESTS, EngineCells
from hild.crossing.mailboxes import Shared
from hild.crossing.region import Region
from hild.crossing.requests import Refused, Reset, SetZero, Switch
from hild.cycle.engine import Engine
from hild.cycle.process import PARENT_CHECK, ClientWakeup, CrossingCycle, Outbox
from hild.daemon.remote import SpawnedCycle
from tests.conftest import mock_robot


@dataclass
class Lockstep:
    remote: SpawnedCycle
    engine: Engine
    cycle: CrossingCycle

    def step(self, count: int = 1) -> None:
        for _ in range(count):
            self.cycle.step(round(self.engine.t + self.engine.period, 12), self.engine.period)


@pytest.fixture
def lockstep(write_config: Callable[..., Path]) -> Iterator[Lockstep]:
    loaded = load_config(write_config(mock_robot()))
    remote = SpawnedCycle(loaded)
    region = Region.attach(remote.region.fd, remote.region.size)
    cells = EngineCells(region, len(remote.joints), create=False)
    outbox = Outbox(cells, ClientWakeup(remote.wakeup_fd))
    engine = Engine(loaded, Shared(region, create=False), stats=cells.stats, wake_client=outbox.wakeup.mark)
    engine.start()
    yield Lockstep(remote, engine, CrossingCycle(engine, cells, outbox, os.getppid()))
    remote.close()


def test_an_estop_is_applied_in_the_very_next_cycle_whatever_the_request_queue_holds(lockstep: Lockstep) -> None:
    remote, engine = lockstep.remote, lockstep.engine
    assert remote.request(Switch(("fwd",))).done() is False
    lockstep.step()
    remote.take()
    busy = [remote.request(Reset()) for _ in range(REQUESTS - 1)]  # the queue full of requests, none applied yet
    estop = remote.request_estop()
    assert not engine.supervisor.estop
    lockstep.step()  # one cycle
    assert engine.supervisor.estop
    remote.take()
    assert estop.result(timeout=0) == {"deactivated": ["fwd"]}
    assert all(f.done() for f in busy)  # answered in the same cycle: refused, the e-stop is engaged
    assert remote.status()["mode"] == "estop"


def test_a_request_crosses_and_its_reply_or_refusal_comes_back(lockstep: Lockstep) -> None:
    remote = lockstep.remote
    switched = remote.request(Switch(("fwd",)))
    refused = remote.request(SetZero("nope"))
    lockstep.step()
    assert not switched.done()  # the reply waits in the shared queue until the client domain takes it
    remote.take()
    assert switched.result(timeout=0) == {"ok": True, "error": None, "activated": ["fwd"], "deactivated": []}
    with pytest.raises(Refused, match="unknown joint 'nope'"):
        refused.result(timeout=0)
    status = remote.status()
    assert [j["owner"] for j in status["joints"]] == ["fwd"] * 3
    assert status["loop"]["update_rate"] == 500 and status["stamp"] == lockstep.engine.t


def test_a_stop_asked_by_the_client_domain_stops_the_cycle(lockstep: Lockstep) -> None:
    remote, cycle = lockstep.remote, lockstep.cycle
    lockstep.step()
    assert not cycle._stop_requested.is_set()
    remote.ask_stop()
    lockstep.step()
    assert cycle._stop_requested.is_set()


def test_a_lost_parent_is_reported_once_however_long_the_stop_takes(
    lockstep: Lockstep, caplog: pytest.LogCaptureFixture
) -> None:
    """The cycle process whose daemon is gone stops (a descent may take seconds, the parent is looked at every
    PARENT_CHECK): it says so once, not once per look."""
    orphan = CrossingCycle(lockstep.engine, lockstep.cycle.cells, lockstep.cycle.outbox, parent_pid=-1)
    engine = lockstep.engine
    with caplog.at_level(logging.ERROR, logger="hild.events"):
        for _ in range(round(5 * PARENT_CHECK * engine.update_rate)):  # five looks at the parent
            orphan.step(round(engine.t + engine.period, 12), engine.period)
    assert [r.getMessage() for r in caplog.records].count(
        "[cycle] the daemon that started the cycle process is gone: stopping"
    ) == 1, caplog.text
