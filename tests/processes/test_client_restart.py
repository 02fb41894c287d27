"""The client domain dies while the cycle runs: the cycle holds, the main process starts another client domain,
clients reconnect, and nothing a client asked for is lost silently (issue [rt-split], "Failure of either side").

Each test runs ``hild run`` in a child process (three processes: main, client domain, cycle) on the mock robot,
its sim clock paced at real time.
"""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hild.config import load_config
from hild.crossing.cells import Ask
from hild.main.process import RESTARTS_ALLOWED, MainProcess
from hild.telemetry import replay
from tests.conftest import merge, mock_robot, with_trajectory
from tests.helpers import HildRun, free_endpoint

REAL_TIME = {"clock": {"source": "sim", "real_time_factor": 1.0}}


def robot(patch: dict[str, Any] | None = None) -> dict[str, Any]:
    return merge(with_trajectory(merge(mock_robot(), REAL_TIME), "jtc"), patch or {})


def test_a_killed_client_domain_is_restarted_while_the_cycle_holds(write_config: Callable[..., Path]) -> None:
    with HildRun(write_config(robot()), free_endpoint(), "mock3") as run, run.client() as client:
        cycle, first = run.cycle_process(), run.client_process()
        client.switch(["fwd"], [])
        for _ in range(30):  # fwd owns the joints
            client.send("fwd", [0.3, -0.4, 0.5])
            time.sleep(0.01)
        before = client.status()
        assert [j["owner"] for j in before["joints"]] == ["fwd"] * 3
        os.kill(first, signal.SIGKILL)
        run.wait_log("the client domain ended unexpectedly (exit code -9); the cycle holds the arm")
        after = run.wait(lambda: _status(client), "the same client to reach the new client domain")
        second = run.client_process()
        assert second != first and run.cycle_process() == cycle  # the cycle process never stopped
        assert after["loop"]["cycles"] > before["loop"]["cycles"]
        assert before["realtime"]["client_process"] == f"pid {first}, 0 restart(s)"
        assert after["realtime"]["client_process"] == f"pid {second}, 1 restart(s)"
        assert after["realtime"]["cycle_process"] == f"pid {cycle}, 1 Python thread(s)"
        assert [j["mode"] for j in after["joints"]] == ["hold"] * 3, after["joints"]  # fwd's stream timed out
        run.wait_log("no command for 0.2 s: joints return to hold")
        run.wait_log("[cycle] the client domain ended: its goals are aborted and the joints hold until it is back")
        run.wait_log("the client domain was restarted (the client domain ended unexpectedly (exit code -9))")
        # The new client domain continues the old one's counters: an e-stop is answered, a reset clears it.
        assert client.estop()["deactivated"] == ["fwd"]
        assert client.status()["mode"] == "estop"
        assert client.reset()["cleared"] == ["e-stop"]
        client.switch(["fwd"], [])
        joint_states: list[dict[str, Any]] = []
        client.subscribe("joint_states", joint_states.append)

        def reached() -> bool:
            client.send("fwd", [0.2, 0.1, -0.1])
            return bool(joint_states) and joint_states[-1]["position"] == pytest.approx([0.2, 0.1, -0.1])

        run.wait(reached, "a stream through the new client domain to reach the joints")
        assert run.stop() == 0
    assert "stopped: hardware released" in run.log


def test_a_goal_running_when_the_client_domain_dies_ends_aborted_and_stays_queryable(
    write_config: Callable[..., Path],
) -> None:
    """The goal is the cycle's: it is aborted there (no one could cancel it) and its result waits in the shared
    region for the next client domain, which answers for it."""
    with HildRun(write_config(robot()), free_endpoint(), "mock3") as run, run.client() as client:
        client.switch(["jtc"], [])
        goal = {"positions": [0.9, -0.9, 0.9], "duration": 20.0}
        handle = client.send_goal("jtc", goal, watched=False)
        goal_id = handle.goal_id
        handle.close()
        run.wait(lambda: client.goal_result("jtc", goal_id)["status"] == "executing", "the goal to run")
        os.kill(run.client_process(), signal.SIGKILL)
        result = run.wait(lambda: _result(client, goal_id), "the new client domain to answer for the goal")
        assert result["status"] == "aborted", result
        assert "the client domain ended" in result["error_string"], result
        status = client.status()
        assert [j["owner"] for j in status["joints"]] == ["jtc"] * 3  # jtc stopped the arm and holds it
        follow = client.send_goal("jtc", {"positions": [0.0, 0.0, 0.0], "duration": 0.5}).wait(20.0)
        assert follow["status"] == "succeeded", follow
        assert run.stop() == 0


def test_results_of_goals_that_ended_before_the_client_domain_died_stay_queryable(
    write_config: Callable[..., Path],
) -> None:
    """The client domain leaves its store of results in the shared region, and the next one answers for them: a
    client that asks for a goal's result after a restart is not told the goal is unknown."""
    with HildRun(write_config(robot()), free_endpoint(), "mock3") as run, run.client() as client:
        client.switch(["jtc"], [])
        ended = [client.send_goal("jtc", {"positions": [p, -p, p], "duration": 0.2}).wait(20.0) for p in (0.2, 0.0)]
        assert [r["status"] for r in ended] == ["succeeded", "succeeded"], ended
        os.kill(run.client_process(), signal.SIGKILL)
        for before in ended:
            after = run.wait(lambda g=before["goal_id"]: _result(client, g), "the new client domain to answer")
            assert after == before
        assert run.stop() == 0


def test_killing_the_main_process_stops_both_domains_and_releases_the_arm(write_config: Callable[..., Path]) -> None:
    with HildRun(write_config(robot()), free_endpoint(), "mock3") as run:
        cycle, client = run.cycle_process(), run.client_process()
        run.process.kill()
        run.process.wait()
        run.wait_gone(cycle, "the orphaned cycle process to stop")
        run.wait_gone(client, "the orphaned client domain to stop")
        log = run.log
    assert "the daemon that started the cycle process is gone: stopping" in log
    assert "the daemon's main process is gone: stopping" in log
    assert "stopped: hardware released" in log


def test_a_client_domain_that_keeps_dying_stops_the_unit(
    write_config: Callable[..., Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Restarts are bounded: a crash loop that keeps answering and dying is worse than a stopped service. Each
    loss is told to the cycle, restart or not."""
    main = MainProcess(load_config(write_config(robot())))
    started: list[str | None] = []
    monkeypatch.setattr(main, "_start_client", started.append)
    monkeypatch.setattr(main, "_client_code", lambda: -9)
    assert all(main._restart_client() for _ in range(RESTARTS_ALLOWED))
    assert main._restart_client() is False
    assert len(started) == RESTARTS_ALLOWED
    assert started[0] == "the client domain ended unexpectedly (exit code -9)"
    assert int(main.cells.asks[Ask.CLIENT_LOST]) == RESTARTS_ALLOWED + 1


def _status(client: Any) -> dict[str, Any] | None:
    try:
        return client.status()  # type: ignore[no-any-return]
    except Exception:  # unreachable until the new client domain serves
        return None


def _result(client: Any, goal_id: str) -> dict[str, Any] | None:
    try:
        result = client.goal_result("jtc", goal_id)
    except Exception:
        return None
    return result if result.get("status") != "executing" else None


def test_the_recording_goes_on_in_a_new_file_after_a_client_domain_restart(
    write_config: Callable[..., Path],
) -> None:
    """The cycle process records into the ring of the client domain that started it; when that one dies, it
    switches to the new one's ring, so the new recording has the arm in it, every cycle."""
    telemetry = {"telemetry": {"enabled": True, "sinks": [{"kind": "file", "path": "rec/run.rrd"}]}}
    path = write_config(robot(telemetry))
    with HildRun(path, free_endpoint(), "mock3") as run, run.client() as client:
        os.kill(run.client_process(), signal.SIGKILL)
        run.wait_log("the client domain was restarted")
        run.wait(lambda: _status(client), "the new client domain to answer")
        client.switch(["fwd"], [])
        for _ in range(100):  # a second of commands: the joints move in the second recording
            client.send("fwd", [0.3, -0.4, 0.5])
            time.sleep(0.01)
        assert run.stop() == 0
    first = path.parent / "rec" / "run.rrd"  # the crashed client domain's, kept
    (second,) = (path.parent / "rec").glob("run-*.rrd")
    commanded, measured = replay.tracking(second, "position")
    assert len(measured.tick) > 200 and np.all(np.diff(measured.tick) == 1), "cycles lost in the new recording"
    assert np.abs(commanded.column("a") - 0.3).min() < 1e-9  # what the new client domain commanded
    assert len(replay.tracking(first, "position")[1].tick) > 0
