"""The Python client, sync and asyncio: ``from hild.client import HildClient, AsyncHildClient``.

    with HildClient(robot="arm6", connect=["tcp/127.0.0.1:7447"]) as hild:
        hild.switch(activate=["joint_trajectory"], deactivate=["servo"])
        result = hild.move_to("joint_trajectory", [0, 1.0, -1.6, -0.97, 1.57, 0])
        print(result["status"])                       # succeeded | aborted | canceled | preempted

docs/protocol.md shows the same calls as raw Zenoh keys and JSON.
"""

from hild.api.aio import AsyncHildClient
from hild.api.client import GoalHandle, HildClient, HildError, HildUnreachable, ServoStream, Subscription

__all__ = [
    "AsyncHildClient",
    "GoalHandle",
    "HildClient",
    "HildError",
    "HildUnreachable",
    "ServoStream",
    "Subscription",
]
