"""The black box's own triggers: a fault newly latched, the e-stop engaged, a stall while live; one file per burst.

The cycle is a plain object the test changes, and time is passed in: nothing here waits."""

from __future__ import annotations

import asyncio
from dataclasses import dataclass, field
from typing import Any

from hild.record.triggers import ESTOP, FAULT, STALL, BlackBoxTriggers


@dataclass
class Snap:
    mode: str = "hold"
    joints: tuple[dict[str, Any], ...] = field(
        default_factory=lambda: tuple({"name": j, "fault": None} for j in ("a", "b", "c"))
    )


class Cycle:
    def __init__(self) -> None:
        self.change_seq = 0
        self.cycle = 0
        self.snap = Snap()

    def snapshot(self) -> Snap:
        return self.snap

    def fault(self, joint: str, text: str) -> None:
        self.snap = Snap("fault", tuple({**j, "fault": text} if j["name"] == joint else j for j in self.snap.joints))
        self.change_seq += 1

    def estop(self) -> None:
        self.snap = Snap("estop", self.snap.joints)
        self.change_seq += 1


def triggers(cycle: Cycle, on: tuple[str, ...] = (FAULT, ESTOP, STALL), live: bool = True) -> BlackBoxTriggers:
    async def write(reason: str) -> None:
        pass

    return BlackBoxTriggers(cycle, write, on, 0.5, live=lambda: live)


def test_a_fault_latched_before_the_first_look_is_not_news_one_latched_after_is() -> None:
    cycle = Cycle()
    cycle.fault("a", "stale feedback")
    t = triggers(cycle)
    assert t.check(0.0) is None
    cycle.cycle += 1
    cycle.fault("b", "drive fault 3")
    assert t.check(0.01) == FAULT
    assert t.due(0.01 + 0.49) is None and t.due(0.51) == FAULT and t.due(0.6) is None  # written once


def test_faults_latching_joint_after_joint_and_an_estop_are_one_burst() -> None:
    cycle = Cycle()
    t = triggers(cycle)
    t.check(0.0)
    fired = []
    for k, joint in enumerate(("a", "b", "c")):
        cycle.cycle += 1
        cycle.fault(joint, "overspeed")
        fired.append(t.check(0.1 * k))
    cycle.estop()
    fired.append(t.check(0.35))
    assert fired == [FAULT, None, None, None]
    assert t.due(0.6) == FAULT
    # Within QUIET of the last trigger: joins the burst that was written, no second file.
    assert t.trigger(ESTOP, "again", now=1.0) is None and t.due(2.0) is None
    # After a quiet spell a new trigger is a new burst.
    assert t.trigger(ESTOP, "later", now=1.0 + t.quiet + 0.01) == ESTOP


def test_an_estop_engaged_triggers_only_when_asked_for() -> None:
    cycle = Cycle()
    t = triggers(cycle, on=(FAULT,))
    t.check(0.0)
    cycle.estop()
    assert t.check(0.1) is None
    cycle2 = Cycle()
    t2 = triggers(cycle2, on=(ESTOP,))
    t2.check(0.0)
    cycle2.estop()
    assert t2.check(0.1) == ESTOP


def test_a_stall_fires_once_after_stall_after_and_rearms_when_the_cycle_moves() -> None:
    cycle = Cycle()
    t = triggers(cycle)
    assert t.check(0.0) is None
    assert t.check(0.49) is None
    assert t.check(0.5) == STALL
    assert t.due(1.0) == STALL
    assert t.check(5.0) is None  # the same stall: once
    cycle.cycle += 1
    assert t.check(5.1) is None
    assert t.check(5.1 + 0.5) == STALL  # stalled again, after a quiet spell


def test_no_stall_while_the_cycle_is_not_live() -> None:
    t = triggers(Cycle(), live=False)
    t.check(0.0)
    assert t.check(10.0) is None and t.due(11.0) is None


def test_run_writes_a_due_burst_and_flush_writes_a_waiting_one() -> None:
    cycle = Cycle()
    written: list[str] = []

    async def write(reason: str) -> None:
        written.append(reason)

    async def main() -> None:
        t = BlackBoxTriggers(cycle, write, (FAULT,), 0.5, delay=0.05)
        task = asyncio.create_task(t.run())
        while t._seq is None:  # its first look: what is latched before it is not news
            await asyncio.sleep(0.005)
        cycle.fault("a", "stale feedback")
        for _ in range(200):
            if written:
                break
            await asyncio.sleep(0.01)
        task.cancel()
        t.trigger(ESTOP, "e-stop", now=t._last_trigger + t.quiet + 1.0)
        await t.flush()

    asyncio.run(main())
    assert written == [FAULT, ESTOP]
