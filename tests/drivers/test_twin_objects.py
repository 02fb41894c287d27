"""The twin's scene objects: primitives added to the world (a box to grasp, a table), and the friction cone."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import mujoco
import pytest
import yaml

from hild.config import load_config
from hild.cycle.engine import Engine
from hild.hardware import HardwareError
from tests.controllers.test_parallel_gripper import rig_engine


def objects_engine(tmp_path: Path, twin: dict[str, Any]) -> Engine:
    rig_engine(tmp_path)  # writes rig.xml and rig.yaml
    config = yaml.safe_load((tmp_path / "rig.yaml").read_text())
    config["hardware"]["twin"]["params"].update(twin)
    (tmp_path / "rig.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
    return Engine(load_config(tmp_path / "rig.yaml"))


def test_a_free_object_falls_onto_a_fixed_one_and_rests(tmp_path: Path) -> None:
    engine = objects_engine(
        tmp_path,
        {
            "objects": [
                {"name": "shelf", "size": [0.05, 0.05, 0.01], "pos": [0.15, 0.0, 0.05], "fixed": True},
                {"name": "ball", "shape": "sphere", "size": [0.02], "pos": [0.15, 0.0, 0.2], "mass": 0.05},
            ],
            "friction_cone": "elliptic",
            "impratio": 10,
        },
    )
    engine.start()
    engine.run_cycles(1000)
    twin = engine.hardware[0].component
    ball = mujoco.mj_name2id(twin.model, mujoco.mjtObj.mjOBJ_BODY, "ball")
    assert twin.data.xpos[ball][2] == pytest.approx(0.06 + 0.02, abs=0.002)  # on the shelf's top, not the table
    assert twin.model.opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC and twin.model.opt.impratio == 10
    assert not engine.supervisor.fault.any()  # the arm's joints keep their addresses: it holds as before


def test_an_object_named_like_a_body_of_the_model_is_refused(tmp_path: Path) -> None:
    engine = objects_engine(tmp_path, {"objects": [{"name": "box", "size": [0.01, 0.01, 0.01], "pos": [0, 0, 1]}]})
    with pytest.raises(HardwareError, match="object names must be new and distinct: box"):
        engine.start()


def test_an_object_with_the_wrong_number_of_sizes_is_refused(tmp_path: Path) -> None:
    with pytest.raises(Exception, match="a sphere takes 1 half-size"):
        objects_engine(
            tmp_path, {"objects": [{"name": "ball", "shape": "sphere", "size": [0.01, 0.02], "pos": [0, 0, 1]}]}
        )
