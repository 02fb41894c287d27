"""Issue [layout] 8.1: every Zenoh session that sent the daemon a payload of 3 KB or more grew its client domain by
16 MiB for good (30 sessions: 44 → 525 MiB). Zenoh's shared-memory transport moves such payloads through a pool of
the sender's, which the receiving session maps and keeps after the sender is gone. The daemon's session now has it
off: a client with Zenoh's defaults sends over the link, and the client domain maps no sender's pool.

The growth itself is measured by ``tools/client_memory.py`` (USS before and after storms and sessions)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import zenoh

from hild.api.keys import Keys
from hild.api.session import client_config
from tests.conftest import merge, mock_robot
from tests.helpers import HildRun, free_endpoint

LARGE = json.dumps({"note": "x" * 4000}).encode()  # over Zenoh's 3 KB shared-memory threshold


def zenoh_pools(pid: int) -> list[str]:
    """The Zenoh shared-memory segments ``pid`` maps (``/dev/shm/<id>.zenoh``)."""
    maps = Path(f"/proc/{pid}/maps").read_text().splitlines()
    return sorted({line.split()[-1] for line in maps if line.endswith(".zenoh")})


def test_a_client_sending_large_payloads_leaves_no_pool_mapped_in_the_client_domain(
    write_config: Callable[..., Path],
) -> None:
    config = write_config(merge(mock_robot(), {"clock": {"real_time_factor": 1.0}}))
    with HildRun(config, endpoint := free_endpoint(), "mock3") as run:
        pid = run.client_process()
        sender = client_config([endpoint])
        assert json.loads(sender.get_json("transport/shared_memory/enabled")) is True  # a client with the defaults
        for _ in range(3):  # three sessions, one after the other, as the attack campaign's did
            with zenoh.open(sender) as session:
                for service in ("status", "switch_controllers"):
                    replies = list(session.get(Keys("mock3").service(service), payload=LARGE, timeout=5.0))
                    assert replies and replies[0].ok is not None  # answered (refused: too large), so received
        assert zenoh_pools(pid) == []
        assert run.stop() == 0
