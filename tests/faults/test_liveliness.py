"""A goal's sender disappears: the action server's bookkeeping, joint_trajectory's ``on_client_lost``, and the
whole path over Zenoh with two client sessions (the table's client rows run the same path in tests/faults/scenarios.py).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from hild.action import PENDING_GOALS, ActionServer, ClientLost, GoalRejected, GoalRequest, GoalStatus
from hild.api.goal_senders import client_of_key, client_token_key
from hild.api.goals import GoalEndpoint, split_client
from tests.faults.rigs import JTC, ApiRig, TwinRig


def server() -> ActionServer[Any]:
    return ActionServer(["a"], parse=lambda payload: payload, accepting=lambda: None, notify=lambda: None)


def test_a_goal_names_its_client_and_the_body_goes_on_without_it() -> None:
    assert split_client({"positions": [1.0], "client": "c-1.x_Y"}) == ({"positions": [1.0]}, "c-1.x_Y")
    assert split_client({"positions": [1.0]}) == ({"positions": [1.0]}, None)
    assert split_client([1, 2]) == ([1, 2], None)
    # "c-1\n": a final newline slipped past the pattern's `$` (a key chunk with a newline in it)
    for bad in ("", "a/b", "*", "x" * 65, 7, None, "c-1\n"):
        with pytest.raises(GoalRejected, match="liveliness id"):
            split_client({"positions": [1.0], "client": bad})
    assert GoalEndpoint.of(server()).submit({"positions": [1.0], "client": "a/b"})["ok"] is False


def test_client_token_keys_round_trip() -> None:
    key = client_token_key("arm6", "abc")
    assert key == "hild/arm6/client/abc"
    assert client_of_key("arm6", key) == "abc"
    assert client_of_key("arm6", "hild/arm6/alive") is None
    assert client_of_key("arm6", "hild/other/client/abc") is None
    assert client_of_key("arm6", "hild/arm6/client/abc/extra") is None


def test_only_the_lost_clients_running_goals_are_told() -> None:
    action = server()
    mine = GoalEndpoint.of(action).submit({"n": 1, "client": "gone"})["goal_id"]
    other = GoalEndpoint.of(action).submit({"n": 2, "client": "here"})["goal_id"]
    anonymous = GoalEndpoint.of(action).submit({"n": 3})["goal_id"]
    done = GoalEndpoint.of(action).submit({"n": 4, "client": "gone"})["goal_id"]
    action.finish(done, GoalStatus.SUCCEEDED)
    assert GoalEndpoint.of(action).client_lost("gone") == [mine]
    assert GoalEndpoint.of(action).client_lost("nobody") == []
    requests = []
    while (request := action.requests.poll()) is not None:
        requests.append(request)
    assert [r.goal_id for r in requests if isinstance(r, GoalRequest)] == [mine, other, anonymous, done]
    (notice,) = [r for r in requests if isinstance(r, ClientLost)]
    assert notice.goal_id == mine and notice.client == "gone" and "gone" in notice.reason


def test_a_notice_that_finds_the_queue_full_is_offered_at_the_next_collect() -> None:
    action = server()
    ids = [GoalEndpoint.of(action).submit({"n": k, "client": "gone"})["goal_id"] for k in range(PENDING_GOALS)]
    assert GoalEndpoint.of(action).client_lost("gone") == ids
    assert len(action.requests) == PENDING_GOALS  # full of goals: no notice got in
    action.requests.poll()  # the cycle takes a goal…
    GoalEndpoint.of(action).collect()  # …and the next collect offers the first notice
    assert isinstance(action.requests.poll(), GoalRequest)
    *_, last = [action.requests.poll() for _ in range(PENDING_GOALS - 1)]
    assert isinstance(last, ClientLost) and last.goal_id == ids[0]


def test_a_result_a_query_stored_first_is_still_published() -> None:
    """collect() returns every result once, even one a result or cancel query moved into the store first."""
    action = server()
    goal = GoalEndpoint.of(action).submit({"n": 1})["goal_id"]
    action.finish(goal, GoalStatus.CANCELED)
    assert GoalEndpoint.of(action).result({"goal_id": goal})["status"] == "canceled"  # the query took it in
    assert [r.goal_id for r in GoalEndpoint.of(action).collect()] == [goal]  # the publisher still gets it
    assert GoalEndpoint.of(action).collect() == []


@pytest.mark.parametrize("setting", ["stop", "continue"])
def test_joint_trajectory_applies_on_client_lost(setting: str) -> None:
    rig = TwinRig(controllers={JTC: {"on_client_lost": setting}})
    try:
        rig.switch([JTC])
        target = rig.engine.state.position + 0.4
        reply = GoalEndpoint.of(rig.jtc.action).submit({"positions": target.tolist(), "client": "c1"})
        goal = reply["goal_id"]
        rig.seconds(0.3)
        assert GoalEndpoint.of(rig.jtc.action).client_lost("c1") == [goal]
        rig.cycle()
        if setting == "stop":
            result = rig.result(goal)
            assert result is not None and result.status == "aborted"
            assert result.error_string == "the client that sent it (c1) is gone (on_client_lost: stop)"
            assert np.abs(rig.jtc.vd).max() > 0.1  # decelerating, not frozen: the jump guard ran every cycle
            rig.until(lambda: not rig.jtc.vd.any(), 2.0, "the stop")
            assert np.abs(rig.engine.state.position - target).max() > 0.05  # it did not go on to the target
        else:
            assert rig.result(goal) is None
            assert any("it runs on (on_client_lost: continue)" in e.message for _, e in rig.events)
            assert rig.finish(goal).status == "succeeded"
            np.testing.assert_allclose(rig.engine.state.position, target, atol=0.01)
    finally:
        rig.close()


def test_over_zenoh_an_unwatched_goal_outlives_its_client_and_a_watched_one_does_not() -> None:
    rig = ApiRig()
    try:
        rig.switch([JTC])
        with rig.client() as sender, rig.client() as watcher:
            free = sender.send_goal(JTC, {"positions": (rig.engine.state.position + 0.2).tolist()}, watched=False)
            free.close()
            assert GoalEndpoint.of(rig.jtc.action).client_lost(sender.client_id) == []  # it named no client
            rig.finish(free.goal_id)
            watched = sender.send_goal(JTC, {"positions": (rig.engine.state.position - 0.2).tolist()})
            watched.close()
            rig.seconds(0.1)
            sender.close()
            rig.wait(lambda: len(rig.jtc.action.requests) > 0, "the notice")
            rig.cycle()
            result = watcher.goal_result(JTC, watched.goal_id)
            assert result["status"] == "aborted" and sender.client_id in result["error_string"], result
            assert watcher.goal_result(JTC, free.goal_id)["status"] == "succeeded"
    finally:
        rig.close()
