"""What many tests need, in one place: free loopback ports, waiting for a condition, and ``hild run`` as the
operator starts it. They live in the measuring room (``hild.bench.children``, ``hild.bench.daemon``), which the
tools and ``hild bench`` share; this module names them for the tests."""

import asyncio
import re
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any, TypeVar

from hild.bench.children import distinct_free_ports, free_endpoint, free_port, wait_for
from hild.bench.daemon import HildRun, domain_pid, running

__all__ = [
    "HildRun",
    "component",
    "distinct_free_ports",
    "domain_pid",
    "free_endpoint",
    "free_port",
    "heavier_plant",
    "rig_joint",
    "running",
    "serve",
    "until",
    "wait_for",
]

C = TypeVar("C")
UNTIL_WAIT = 20.0  # s


async def until(condition: Callable[[], Any], what: str, timeout: float = UNTIL_WAIT) -> Any:
    """``condition()``'s first truthy value, polled on the running event loop (``wait_for``'s asyncio twin)."""
    deadline = time.monotonic() + timeout
    while not (value := condition()):
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:g} s waiting for {what}")
        await asyncio.sleep(0.01)
    return value


def component(engine: Any, kind: type[C], index: int = 0) -> C:
    """The engine's hardware component ``index``, checked to be a ``kind`` (the twin, the mock)."""
    found = engine.hardware[index].component
    assert isinstance(found, kind), type(found)
    return found


def rig_joint() -> dict[str, Any]:
    """A joint of the small CAN test rigs, as a config writes it: ±3 rad, 4 rad/s, 9 N·m, hold gains 30 / 1."""
    return {
        "limits": {
            "position": {"lower": -3.0, "upper": 3.0},
            "soft_margin": 0.05,
            "velocity": 4.0,
            "acceleration": 12.0,
            "jerk": 120.0,
            "effort": 9.0,
        },
        "hold": {"kp": 30.0, "kd": 1.0},
    }


def heavier_plant(model: Path, directory: Path, scale: float) -> Path:
    """A copy of the MJCF ``model`` in ``directory`` with every link's mass and inertia ×``scale`` (the motors'
    armature and damping unchanged): the plant a twin drives when the model hild computes with is that far off."""

    def scaled(m: re.Match[str]) -> str:
        return f'{m.group(1)}="' + " ".join(f"{float(x) * scale:.6g}" for x in m.group(2).split()) + '"'

    path = directory / f"{model.stem}_x{scale:g}.xml"
    path.write_text(re.sub(r'(mass|diaginertia)="([^"]+)"', scaled, model.read_text()))
    return path


async def serve(
    daemon: Any, endpoint: str, scenario: Callable[[Any, Any], Awaitable[None]], robot: str = "mock3"
) -> int:
    """Run ``daemon`` (an embedded ``hild.daemon.daemon.Daemon`` listening on ``endpoint``) until it is ready, give
    ``scenario`` the daemon and a client of it, then stop it; its exit code (its start-up's, if it never got ready)."""
    from hild.api.client import HildClient

    task = asyncio.create_task(daemon.run())
    await until(lambda: daemon.ready or task.done(), "the daemon to be ready")
    if task.done():
        return int(task.result())
    client = HildClient(robot, [endpoint], timeout=5.0)
    try:
        await scenario(daemon, client)
    finally:
        client.close()
        daemon.request_stop()
    return int(await task)
