"""The ROS 2 face of ``hild run`` as the operator starts it (main process, client domain, cycle process), on the
wall clock: pyzeros lists the controllers and a FollowJointTrajectory goal runs to SUCCEEDED. Controllers reach
the face through their API halves and shared-memory rings here, not the in-process engine of the other tests."""

import asyncio
import time
from pathlib import Path
from typing import Any

import pytest
import yaml
import zenoh

pyzeros = pytest.importorskip("pyzeros", reason="the ros2-verify extra (pyzeros) is not installed")

import asyncio_for_robotics as afor  # noqa: E402

from tests.api.conftest import WAIT  # noqa: E402
from tests.api.ros2.conftest import peer_config, ros_robot_config  # noqa: E402
from tests.api.ros2.test_against_pyzeros import (  # noqa: E402
    ListControllers,
    ListControllers_Request,
    _goal_session,
)
from tests.helpers import HildRun, free_endpoint  # noqa: E402


async def _listing() -> Any:
    client = pyzeros.Client(ListControllers, "/controller_manager/list_controllers")
    await asyncio.wait_for(client.wait_for_service(), WAIT)
    return await asyncio.wait_for(client.call_async(ListControllers_Request()), WAIT)


def test_hild_run_speaks_ros2(tmp_path: Path) -> None:
    config = ros_robot_config(tmp_path)
    config["clock"] = {"source": "wall"}
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    endpoint = free_endpoint()
    target = [0.2, -0.15, 0.1]
    with HildRun(path, endpoint, config["robot"]["name"]) as daemon:
        assert daemon.cycle_process() and daemon.client_process()
        session = zenoh.open(peer_config(endpoint))

        @afor.scoped
        async def main() -> dict[str, Any]:
            listing = await _listing()
            return {"listing": listing, **await _goal_session(target)}

        try:
            with pyzeros.auto_context(node="pyzeros_run_probe", zenoh_session=session, domain_id=0):
                got = asyncio.run(main())
        finally:
            session.close()
    assert {c.name for c in got["listing"].controller} == {"jsb", "fwd", "fwd_a", "traj"}
    assert got["accepted"].accepted and (got["result"].status, got["result"].result.error_code) == (4, 0)
    assert max(abs(p - t) for p, t in zip(got["state"].position, target, strict=True)) < 0.02
    stamp = got["state"].header.stamp  # on the wall clock ROS time is the epoch's, as any ROS node's (no /clock)
    assert abs(stamp.sec + stamp.nanosec * 1e-9 - time.time()) < 60
