"""A daemon with a ``ros2:`` section on a free loopback port, and a bare Zenoh peer speaking rmw_zenoh's bytes
by hand (hild.api.ros2.wire/types build them; test_against_* check those against independent implementations)."""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh

from hild.api.ros2 import types, wire
from hild.cycle.engine import Engine
from tests.api.conftest import WAIT, Daemon, engine_from, robot_config, running
from tests.conftest import with_trajectory

# pyzeros' CDR library (cydr) compiles and caches its codecs in the working directory unless told otherwise: keep
# them out of the repository. Read when cydr is imported, which is after this conftest.
os.environ.setdefault("CYDR_CACHE_DIR", os.path.join(tempfile.gettempdir(), "hild-tests-cydr-cache"))

CLIENT_GID = bytes(range(16))
RELEASED = Path(__file__).parent / "released"  # the released .msg/.srv/.action files definitions.py copies
URDF = """<robot name="mock3"><link name="base"/></robot>"""


def ros_robot_config(tmp_path: Path) -> dict[str, Any]:
    config = robot_config()
    config["ros2"] = {"domain_id": 0, "namespace": "/"}
    (tmp_path / "mock3.urdf").write_text(URDF)
    config["robot"]["model"] = "mock3.urdf"
    config["safety"] = {"gravity_compensation": False}
    return with_trajectory(config, "traj")


@pytest.fixture
def ros_engine(tmp_path: Path) -> Engine:
    return engine_from(ros_robot_config(tmp_path), tmp_path)


@pytest.fixture
def ros_daemon(ros_engine: Engine) -> Iterator[Daemon]:
    with running(ros_engine) as d:
        yield d


def peer_config(endpoint: str) -> zenoh.Config:
    config = zenoh.Config()
    for path, value in (
        ("mode", "client"),
        ("connect/endpoints", [endpoint]),
        ("scouting/multicast/enabled", False),
        ("scouting/gossip/enabled", False),
    ):
        config.insert_json5(path, json.dumps(value))
    return config


def peer_of(daemon: Daemon) -> Iterator[zenoh.Session]:
    """A client session connected to ``daemon`` only (no scouting), closed on leaving: for fixtures."""
    session = zenoh.open(peer_config(daemon.endpoint))
    try:
        yield session
    finally:
        session.close()


@pytest.fixture
def peer(ros_daemon: Daemon) -> Iterator[zenoh.Session]:
    yield from peer_of(ros_daemon)


def call(session: zenoh.Session, service: str, type_name: str, payload: bytes, sequence: int = 1) -> zenoh.Reply:
    """One rmw_zenoh-style service call: a get with the CDR request and the attachment; the one reply."""
    replies = session.get(
        wire.data_key(0, service, type_name),
        payload=payload,
        attachment=wire.attachment(sequence, CLIENT_GID),
        target=zenoh.QueryTarget.ALL_COMPLETE,
        timeout=WAIT,
    )
    got = list(replies)
    assert len(got) == 1, f"{len(got)} replies"
    return got[0]


def request(type_name: str, **fields: Any) -> bytes:
    return types.encode(types.message(f"{type_name}_Request", **fields), f"{type_name}_Request")


def released_files() -> dict[str, Path]:
    """``pkg/kind/Name`` → its released file under ``released/<repository>-<tag>/<pkg>/<kind>/``."""
    return {
        f"{path.parent.parent.name}/{path.parent.name}/{path.stem}": path
        for path in sorted(RELEASED.glob("*/*/*/*"))
        if path.suffix in (".msg", ".srv", ".action")
    }


def ask(session: zenoh.Session, service: str, type_name: str, **fields: Any) -> Any:
    """One service call as a ROS client makes it: the decoded response (the call must be answered, not refused)."""
    reply = call(session, service, type_name, request(type_name, **fields))
    assert reply.ok is not None, reply.err.payload.to_bytes() if reply.err is not None else "no reply"
    return types.decode(reply.ok.payload.to_bytes(), f"{type_name}_Response")
