"""Links whose <collision> (and kept <visual>) elements share a name: MuJoCo's URDF loader would print "WARNING: Geom
with duplicate name … creating an unnamed geom" to stderr on every load — unexplained, during the import and at each
start of the twin. The twin's URDF names them uniquely instead, and the report says why."""

from __future__ import annotations

import re
from pathlib import Path

import mujoco
import pytest

from tests.importers.helpers import ARM2, import_robot


def named_geoms(tmp_path: Path, keep_visuals: bool = False) -> Path:
    """arm2 with every <collision> and <visual> named "shape", as some exporters write them."""
    text = (ARM2 / "arm2_gz.urdf").read_text()
    text = re.sub(r"<(collision|visual)>", r'<\1 name="shape">', text)
    if keep_visuals:
        text = text.replace(
            '<robot name="arm2">', '<robot name="arm2"><mujoco><compiler discardvisual="false"/></mujoco>'
        )
    path = tmp_path / "arm2.urdf"
    path.write_text(text)
    return path


def test_repeated_geom_names_are_made_unique_for_the_twin_and_explained(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    result = import_robot(named_geoms(tmp_path), ARM2 / "arm2_controllers.yaml", tmp_path / "out" / "arm2.yaml")
    assert "duplicate name" not in capfd.readouterr().err  # MuJoCo had nothing to warn about
    (finding,) = [f for f in result.report.of("approximated") if "geom name 'shape'" in f.text]
    assert "Geom with duplicate name" in finding.text and "upper_arm_shape" in finding.text
    assert finding.where.line is not None
    model = mujoco.MjModel.from_xml_path(str(result.urdf))
    names = [model.geom(i).name for i in range(model.ngeom)]
    assert sorted(names) == ["forearm_shape", "shape", "upper_arm_shape"]  # the first keeps its name
    assert "duplicate name" not in capfd.readouterr().err


def test_kept_visuals_count_too(tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    result = import_robot(
        named_geoms(tmp_path, keep_visuals=True), ARM2 / "arm2_controllers.yaml", tmp_path / "out" / "arm2.yaml"
    )
    assert "duplicate name" not in capfd.readouterr().err
    model = mujoco.MjModel.from_xml_path(str(result.urdf))
    names = [model.geom(i).name for i in range(model.ngeom)]
    assert len(names) == 6 and len(set(names)) == 6
