"""The cycle process writes the cycle log into the shared region; the client domain's side of a SpawnedCycle maps it
from the fd and place its link hands over (as the recorder process does) and reads every cycle."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from hild.config import load_config
from hild.crossing.cyclelog import OWNER_NONE, CycleLog, CycleRows
from hild.crossing.requests import Switch
from hild.daemon.remote import SpawnedCycle
from hild.modes import JointMode
from tests.conftest import merge, mock_robot

SPLIT = {"realtime": {"cycle_process": True}, "clock": {"source": "sim", "real_time_factor": 1.0}}
WAIT = 20.0


def test_the_cycle_process_writes_every_cycle_and_the_client_side_reads_them(
    write_config: Callable[..., Path],
) -> None:
    loaded = load_config(write_config(merge(mock_robot(), SPLIT)))
    remote = SpawnedCycle(loaded)
    taken: list[CycleRows] = []
    seen: dict[str, object] = {}

    async def take_until(count: int, reader: object, command: list[float] | None = None) -> None:
        deadline = time.monotonic() + WAIT
        while sum(len(r) for r in taken) < count:
            assert time.monotonic() < deadline, "the cycle log did not fill"
            taken.append(reader.take())  # type: ignore[attr-defined]
            remote.take()  # what the loop does when the cycle rings: replies answered
            if command is not None:  # streamed into the controller's API half, as a client's samples are
                remote.controllers()["fwd"].accept({"values": command})
            await asyncio.sleep(0.01)

    async def main() -> None:
        await remote.bring_up(None)
        handed = remote.cycle_log()
        assert handed is not None
        log = CycleLog.attach(*handed)
        reader = log.reader(start_tick=1)
        seen["wall"] = time.time()
        await remote.go_live()
        await take_until(200, reader)
        switched = remote.request(Switch(("fwd",)))
        await take_until(250, reader)
        seen["switch"] = switched.result(timeout=0)
        seen["switched_at"] = sum(len(r) for r in taken)
        await take_until(500, reader, [0.1, -0.2, 0.3])
        seen["codes"] = remote.snapshot().controller_codes
        assert await remote.stop(WAIT)
        taken.append(reader.take())  # the last rows, the final hold cycle's among them
        seen["lost"] = reader.lost
        seen["head"] = log.head
        log.close()

    try:
        asyncio.run(main())
    finally:
        remote.close()
    rows = CycleRows.concat(taken, 3)
    assert seen["lost"] == 0 and len(rows) == seen["head"]  # every cycle, once, from the first
    assert rows.tick.tolist() == list(range(1, len(rows) + 1))
    assert np.allclose(rows.t, rows.tick * 0.002) and (rows.period == 0.002).all()  # the sim clock
    assert seen["wall"] <= rows.wall[0] <= rows.wall[-1] <= time.time()  # type: ignore[operator]
    assert (rows.duration[1:] > 0).all()  # the previous cycle's, from the cycle process's loop statistics
    assert (rows.measured_position == [0.1, -0.2, 0.3]).all()  # held, then commanded where it is
    assert seen["switch"] == {"ok": True, "error": None, "activated": ["fwd"], "deactivated": []}
    codes = {name: code for code, name in seen["codes"].items()}  # type: ignore[attr-defined]
    assert sorted(codes) == ["fwd", "jsb"]
    before = rows.select(slice(0, 200))
    assert (before.mode == JointMode.HOLD).all() and (before.owner == OWNER_NONE).all()
    controlled = (rows.mode == JointMode.CONTROLLED).all(axis=1)
    assert controlled[seen["switched_at"] :].any()  # type: ignore[misc]
    assert (rows.owner[controlled] == codes["fwd"]).all()  # the owner code crossed with the snapshot's map
    assert (rows.owner[~controlled] == OWNER_NONE).all()
