"""A client domain's API half leaves the results it collected in the shared region; the API half of the client
domain started after it died answers for them (tests/processes/test_client_restart.py does it with real processes)."""

from __future__ import annotations

from typing import Any

from hild.action import KEPT_BYTES, ActionServer, GoalStatus
from hild.api.goals import GoalEndpoint
from hild.crossing.mailboxes import Shared
from hild.crossing.region import Region

SIZE = 64 << 20


def server(region: Region, *, create: bool = False) -> ActionServer[Any]:
    view = region if create else Region.attach(region.fd, SIZE)
    return ActionServer(["a"], lambda goal: goal, lambda: None, lambda: None, Shared(view, create=create))


def finished(api: ActionServer[Any], cycle: ActionServer[Any], count: int, text: str = "") -> list[str]:
    ids = [GoalEndpoint.of(api).submit({"n": n})["goal_id"] for n in range(count)]
    for goal_id in ids:  # one at a time, as goals end: the results queue holds a few large ones at most
        cycle.finish(goal_id, GoalStatus.SUCCEEDED, text=text)
        assert [r.goal_id for r in GoalEndpoint.of(api).collect()] == [goal_id]
    return ids


def test_the_successor_answers_for_results_its_predecessor_collected_and_publishes_none_again() -> None:
    region = Region(SIZE)
    first = server(region, create=True)
    ids = finished(first, server(region), 3)
    successor = server(region)
    assert [GoalEndpoint.of(successor).result({"goal_id": g})["status"] for g in ids] == ["succeeded"] * 3
    assert GoalEndpoint.of(successor).collect() == []  # the predecessor published them


def test_results_too_large_to_leave_whole_leave_the_newest() -> None:
    region = Region(SIZE)
    first = server(region, create=True)
    ids = finished(first, server(region), 8, text="x" * (KEPT_BYTES // 6))  # 8 × 1/6: over; the newest 4 fit
    successor = server(region)
    answers = [GoalEndpoint.of(successor).result({"goal_id": g}) for g in ids]
    assert ["unknown goal" in a.get("error", "") for a in answers] == [True] * 4 + [False] * 4
    assert [a.get("status") for a in answers[4:]] == ["succeeded"] * 4
