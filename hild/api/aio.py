"""The asyncio face of :class:`~hild.api.client.HildClient`.

Zenoh's Python API is thread-based, so each blocking call runs in a worker thread (``asyncio.to_thread``) and the
event loop stays free; streaming and subscriptions are non-blocking already and are passed straight through.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from hild.api.client import GoalHandle, HildClient, ServoStream, Subscription


class AsyncHildClient:
    def __init__(self, client: HildClient) -> None:
        self.sync = client

    @classmethod
    async def connect(
        cls,
        robot: str | None = None,
        connect: Sequence[str] | None = None,
        timeout: float = 2.0,
        *,
        zenoh_config: str | Path | None = None,
        zenoh_overrides: Mapping[str, Any] | None = None,
    ):
        """Open a session (in a worker thread) and wait until the robot's daemon is alive.

        ``zenoh_config`` / ``zenoh_overrides``: as for :class:`~hild.api.client.HildClient` (TLS, credentials)."""
        kwargs: dict[str, Any] = {
            "robot": robot,
            "timeout": timeout,
            "zenoh_config": zenoh_config,
            "zenoh_overrides": zenoh_overrides,
        }
        if connect is not None:
            kwargs["connect"] = connect
        client = await asyncio.to_thread(HildClient, **kwargs)
        try:
            await asyncio.to_thread(client.wait_alive)
        except BaseException:
            client.close()
            raise
        return cls(client)

    async def close(self) -> None:
        await asyncio.to_thread(self.sync.close)

    async def __aenter__(self) -> AsyncHildClient:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    async def status(self) -> dict[str, Any]:
        return await asyncio.to_thread(self.sync.status)

    async def list_controllers(self) -> list[dict[str, Any]]:
        return await asyncio.to_thread(self.sync.list_controllers)

    async def switch(
        self, activate: Iterable[str] = (), deactivate: Iterable[str] = (), strict: bool = True
    ) -> dict[str, Any]:
        return await asyncio.to_thread(self.sync.switch, list(activate), list(deactivate), strict)

    async def estop(self) -> dict[str, Any]:
        return await asyncio.to_thread(self.sync.estop)

    async def reset(self) -> dict[str, Any]:
        return await asyncio.to_thread(self.sync.reset)

    async def send_goal(
        self,
        controller: str,
        goal: dict[str, Any],
        feedback: Callable[[dict[str, Any]], None] | None = None,
        *,
        watched: bool = True,
    ) -> GoalHandle:
        """``watched``: as for :meth:`HildClient.send_goal` (the goal stops per ``on_client_lost`` if we go)."""
        return await asyncio.to_thread(self.sync.send_goal, controller, goal, feedback, watched=watched)

    @property
    def client_id(self) -> str:
        """The id watched goals name (this client's liveliness token)."""
        return self.sync.client_id

    async def wait_result(self, handle: GoalHandle, timeout: float | None = None) -> dict[str, Any]:
        return await asyncio.to_thread(handle.wait, timeout)

    async def execute_trajectory(
        self, controller: str, joint_names: Sequence[str], points: Sequence[dict[str, Any]], **options: Any
    ) -> dict[str, Any]:
        return await asyncio.to_thread(self.sync.execute_trajectory, controller, joint_names, points, **options)

    async def move_to(self, controller: str, positions: Sequence[float], **options: Any) -> dict[str, Any]:
        return await asyncio.to_thread(self.sync.move_to, controller, positions, **options)

    async def gripper(self, controller: str, position: float | str, **options: Any) -> dict[str, Any]:
        return await asyncio.to_thread(self.sync.gripper, controller, position, **options)

    async def teach(self, on: bool, joints: Iterable[str] = (), **options: Any) -> dict[str, Any]:
        return await asyncio.to_thread(self.sync.teach, on, list(joints), **options)

    async def record_start(
        self, task: str | None = None, fps: float | None = None, note: str | None = None, **options: Any
    ) -> dict[str, Any]:
        return await asyncio.to_thread(self.sync.record_start, task, fps, note, **options)

    async def record_stop(self, **options: Any) -> dict[str, Any]:
        return await asyncio.to_thread(self.sync.record_stop, **options)

    async def record_discard(self, **options: Any) -> dict[str, Any]:
        return await asyncio.to_thread(self.sync.record_discard, **options)

    async def record_status(self, **options: Any) -> dict[str, Any]:
        return await asyncio.to_thread(self.sync.record_status, **options)

    async def blackbox(self, seconds: float | None = None, **options: Any) -> dict[str, Any]:
        return await asyncio.to_thread(self.sync.blackbox, seconds, **options)

    async def cancel(self, controller: str, goal_id: str) -> dict[str, Any]:
        return await asyncio.to_thread(self.sync.cancel, controller, goal_id)

    async def next_message(self, topic: str, timeout: float | None = None) -> dict[str, Any]:
        return await asyncio.to_thread(self.sync.next_message, topic, timeout)

    def subscribe(self, topic: str, callback: Callable[[dict[str, Any]], None]) -> Subscription:
        """Callbacks run on a Zenoh thread; use ``loop.call_soon_threadsafe`` to reach the event loop."""
        return self.sync.subscribe(topic, callback)

    def servo_stream(self, controller: str) -> ServoStream:
        return self.sync.servo_stream(controller)
