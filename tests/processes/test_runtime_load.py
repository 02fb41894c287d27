"""A controller loaded while ``hild run`` runs (three processes): the client domain carves its cells and builds its
API half, the cycle process builds the cycle half; a restarted client domain rebuilds the half from what the cycle
has loaded; an unload gives the cells' pages back (issue [runtime], item 1).
"""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from hild.api.client import HildClient
from tests.conftest import merge, mock_robot
from tests.helpers import HildRun, free_endpoint

REAL_TIME = {"clock": {"source": "sim", "real_time_factor": 1.0}}
LATE = {"joints": ["a", "b"], "interface": "position", "command_timeout": 0.2}


def follows(run: HildRun, client: HildClient, controller: str, target: list[float]) -> None:
    """Stream ``target`` to ``controller`` until the joint states show it."""
    joint_states: list[dict[str, Any]] = []
    with client.subscribe("joint_states", joint_states.append):

        def reached() -> bool:
            client.send(controller, target)
            time.sleep(0.01)
            return bool(joint_states) and joint_states[-1]["position"][:2] == pytest.approx(target, abs=0.01)

        run.wait(reached, f"a stream to {controller} to reach the joints")


def test_a_controller_loaded_while_hild_run_runs_survives_a_client_domain_restart(
    write_config: Callable[..., Path],
) -> None:
    with HildRun(write_config(merge(mock_robot(), REAL_TIME)), free_endpoint(), "mock3") as run, run.client() as client:
        cycle = run.cycle_process()
        client.load_controller("late", "forward_command", LATE)
        client.configure_controller("late")
        client.switch(["late"])
        follows(run, client, "late", [0.3, -0.4])

        os.kill(run.client_process(), signal.SIGKILL)
        run.wait_log("the client domain was restarted")
        run.wait(lambda: _answers(client), "the same client to reach the new client domain")
        assert run.cycle_process() == cycle
        controllers = {c["name"]: c["state"] for c in client.list_controllers()}
        assert controllers["late"] == "active"  # the cycle kept it; its stream timed out to hold meanwhile
        follows(run, client, "late", [-0.2, 0.25])  # the new client domain built its API half: the input works

        client.switch([], ["late"])
        client.unload_controller("late")
        assert "late" not in {c["name"] for c in client.list_controllers()}
        client.load_controller("late", "forward_command", LATE)  # the name again: cells of its own
        client.configure_controller("late")
        client.switch(["late"])
        follows(run, client, "late", [0.1, 0.1])
        assert run.stop() == 0
    assert "loaded late (forward_command) by " in run.log and "unloaded late" in run.log


def _answers(client: HildClient) -> bool:
    try:
        client.status()
    except Exception:
        return False
    return True
