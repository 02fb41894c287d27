"""Shared by the importer tests: the fixture robots, an import into tmp_path, and a lockstep engine to run it."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import numpy as np

from hild.action import GoalResult
from hild.api.goals import GoalEndpoint
from hild.config import load_config
from hild.cycle.engine import Engine
from hild.importers.ros2_control.importer import ImportRequest, ImportResult, import_ros2_control

ROBOTS = Path(__file__).resolve().parent / "robots"
RRBOT = ROBOTS / "rrbot"
ARM2 = ROBOTS / "arm2"
MY_ARM = ROBOTS / "my_arm_description"


def import_robot(urdf: Path, controllers: Path | list[Path], output: Path, **options: Any) -> ImportResult:
    return import_ros2_control(ImportRequest(urdf=urdf, controllers=controllers, output=output, **options))


def copy_robot(source: Path, tmp_path: Path) -> Path:
    """A writable copy of a fixture robot's directory (for tests that edit its files)."""
    target = tmp_path / source.name
    shutil.copytree(source, target)
    return target


def lockstep(config: Path) -> Engine:
    """The imported config on the sim clock (the twin steps inside each cycle), started."""
    loaded = load_config(config)
    loaded.in_lockstep()
    engine = Engine(loaded)
    engine.start()
    return engine


def run_goal(engine: Engine, controller: str, goal: dict[str, Any], limit_s: float = 15.0) -> GoalResult:
    """Activate ``controller``, submit ``goal`` and run cycles until its result."""
    assert engine.switch([controller], []).ok
    action = GoalEndpoint.of(engine.manager.records[controller].instance.action)
    reply = action.submit(goal)
    assert reply["ok"], reply["error"]
    for _ in range(int(limit_s * engine.update_rate)):
        engine.run_cycles(1)
        for result in action.collect():
            if result.goal_id == reply["goal_id"]:
                return result
    raise AssertionError(f"no result after {limit_s} s")


def waypoints(joints: list[str], start: np.ndarray, offsets: list[list[float]]) -> dict[str, Any]:
    """An untimed trajectory through ``start + offset`` for each offset (planned within the joint limits)."""
    points = [{"positions": (start + np.asarray(o)).tolist()} for o in offsets]
    return {"trajectory": {"joint_names": joints, "points": points}}
