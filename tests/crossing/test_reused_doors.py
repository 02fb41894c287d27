"""A controller loaded while the robot runs takes cells a controller unloaded earlier gave back (found by name and
size, zeros again), so loads and unloads without end do not fill the region's directory (issue [runtime])."""

from __future__ import annotations

import concurrent.futures
from typing import Any

import pytest

from hild.crossing.mailboxes import Shared
from hild.crossing.region import Region
from hild.crossing.requests import Load
from hild.daemon import halves
from hild.daemon.halves import ApiHalves, configured_loads
from tests.crossing.test_halves import lockstep

SIZE = 256 << 20  # virtual: a joint_trajectory's goal queue alone is 32 MiB


def answered(value: Any = None) -> concurrent.futures.Future[Any]:
    future: concurrent.futures.Future[Any] = concurrent.futures.Future()
    future.set_result(value)
    return future


def refused() -> concurrent.futures.Future[Any]:
    future: concurrent.futures.Future[Any] = concurrent.futures.Future()
    future.set_exception(RuntimeError("refused"))
    return future


def ignore(level: str, source: str, message: str) -> None:
    """The API halves' events: none matter here."""


class Client:
    """The API halves of the arm6 twin's controllers over a region of their own, and one controller loaded later."""

    def __init__(self) -> None:
        self.loaded = lockstep()
        self.region = Region(SIZE)
        self.api = ApiHalves(self.loaded, configured_loads(self.loaded), Shared(self.region, create=True), ignore)
        self.params = self.loaded.controller_params["forward_position"]
        self.load, self.half = self.api.prepare(Load("late", "forward_command", self.params))
        self.api.loaded_one(self.load, self.half, answered())


def test_given_back_cells_serve_the_next_load_of_that_type_and_the_directory_stops_growing(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(halves, "REUSE_AFTER", 0.0)
    client = Client()
    loaded, region, api, params, load, half = (
        client.loaded,
        client.region,
        client.api,
        client.params,
        client.load,
        client.half,
    )
    half.set_active(True)  # something the cells hold: the active flag
    cells = len(region.cells())
    api.unloaded("late", answered())
    for k in range(50):  # load, unload, again and again: the same cells each time
        again, half = api.prepare(Load(f"late{k}", "forward_command", params))
        assert again.doors == load.doors and not half.active  # zeros again: nothing of the last owner's
        api.loaded_one(again, half, answered())
        api.unloaded(f"late{k}", answered())
    assert len(region.cells()) == cells

    trajectory = loaded.controller_params["joint_trajectory"]  # another type: other doors, its own cells
    other, _ = api.prepare(Load("traj2", "joint_trajectory", trajectory))
    assert other.doors != load.doors and len(region.cells()) > cells
    refused_load, half = api.prepare(Load("twice", "forward_command", params))
    assert refused_load.doors == load.doors
    api.loaded_one(refused_load, half, refused())  # the cycle refused it: its cells are given back at once
    assert api.prepare(Load("thrice", "forward_command", params))[0].doors == load.doors


def test_given_back_cells_wait_until_the_api_has_withdrawn_what_read_them() -> None:
    client = Client()
    client.api.unloaded("late", answered())
    soon, _ = client.api.prepare(Load("soon", "forward_command", client.params))
    assert soon.doors != client.load.doors  # within REUSE_AFTER
