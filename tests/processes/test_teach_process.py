"""``teach`` across processes (``hild run``: the service in the client domain, the controller's cycle half in the
cycle process): on loads it and switches it in, a single joint's release goes through its input's cell, off hands
every joint to hold and switches it off."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from hild.api.client import HildClient
from tests.conftest import merge, mock_robot
from tests.helpers import HildRun, free_endpoint

REAL_TIME = {"clock": {"source": "sim", "real_time_factor": 1.0}}


def taught(client: HildClient) -> list[str]:
    return [j["name"] for j in client.status()["joints"] if j["teach"]]


def test_teach_on_and_off_through_hild_run(write_config: Callable[..., Path]) -> None:
    with HildRun(write_config(merge(mock_robot(), REAL_TIME)), free_endpoint(), "mock3") as run, run.client() as client:
        client.switch(["fwd"])
        reply = client.teach(True)
        assert reply["teach"] == ["a", "b", "c"] and reply["deactivated"] == ["fwd"]
        assert taught(client) == ["a", "b", "c"]
        reply = client.teach(False, ["b"])
        assert reply["released"] == ["b"] and taught(client) == ["a", "c"]
        reply = client.teach(False)
        assert reply["teach"] == [] and reply["deactivated"] == ["teach"]
        assert taught(client) == [] and {j["mode"] for j in client.status()["joints"]} == {"hold"}
