"""``home`` with the cycle in a process of its own: the request crosses, and the end comes back in the status
(the snapshot carries the ``homing`` entries), on the mock's homing simulation paced at real time."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from hild.api.client import HildClient
from hild.daemon.daemon import Daemon
from tests.processes.test_cycle_process import run_split

HOMING = {"hardware": {"bus": {"params": {"homing": {"duration": 0.3, "switch": {"c": 0.5}, "home_offset": -0.1}}}}}


def test_a_homing_in_the_cycle_process_ends_in_the_status(write_config: Callable[..., Path]) -> None:
    seen: dict[str, Any] = {}

    def entry(client: HildClient) -> dict[str, Any] | None:
        return next((h for h in client.status()["homing"] if h["joint"] == "c"), None)

    async def scenario(daemon: Daemon, client: HildClient) -> None:
        seen["refused"] = await asyncio.to_thread(client.call, "home", {"joint": "nope"}, check=False)
        seen["started"] = await asyncio.to_thread(client.call, "home", {"joint": "c"})
        seen["again"] = await asyncio.to_thread(client.call, "home", {"joint": "c"}, check=False)

        async def ended() -> dict[str, Any] | None:
            found = await asyncio.to_thread(entry, client)
            return found if found and found["state"] != "running" else None

        deadline = asyncio.get_running_loop().time() + 20.0
        while (done := await ended()) is None and asyncio.get_running_loop().time() < deadline:
            await asyncio.sleep(0.05)
        seen["done"] = done

    run_split(write_config, scenario, HOMING)
    assert seen["refused"]["ok"] is False and "unknown joint 'nope'" in seen["refused"]["error"]
    assert seen["started"] == {"ok": True, "error": None, "joint": "c", "attempt": 1, "state": "running"}
    assert seen["again"]["ok"] is False and "already being homed (attempt 1)" in seen["again"]["error"]
    done = seen["done"]
    assert done is not None and done["state"] == "attained" and done["attempt"] == 1
    assert done["position"] == pytest.approx(-0.1)
