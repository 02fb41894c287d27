"""``hild identify`` on the lockstep arm6 twin, whose friction is known (MuJoCo ``frictionloss`` and ``damping``
set in the twin's params): the fit recovers Coulomb within 5 % and viscous within 15 %, writes a copy of the config
with ``joints.<j>.friction`` and nothing else changed, and the fit itself on synthetic samples."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from hild.cli import main
from hild.config import load_config
from hild.dynamics.friction import FrictionArrays
from hild.dynamics.identification import fit_friction
from tests.conftest import CONFIGS
from tests.controllers.test_teach import arm6_config

TRUE_COULOMB = {"shoulder_pan": 1.5, "elbow": 0.8, "wrist_2": 0.3}  # N·m
TRUE_VISCOUS = {"shoulder_pan": 2.0, "elbow": 1.0, "wrist_2": 0.2}  # N·m·s/rad


def twin_with_friction(tmp_path: Path) -> Path:
    shutil.copy(CONFIGS / "arm6.xml", tmp_path)
    config = arm6_config()
    params = config["hardware"]["twin"]["params"]
    params["friction"], params["damping"] = TRUE_COULOMB, TRUE_VISCOUS
    path = tmp_path / "robot.yaml"
    text = yaml.safe_dump(config, sort_keys=False)
    path.write_text("# arm6 on a twin with known friction\n" + text)
    return path


def test_identify_recovers_the_twins_friction_and_writes_a_copy(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = twin_with_friction(tmp_path)
    before = path.read_text()
    assert main(["identify", str(path), "--joints", *TRUE_COULOMB]) == 0
    out = capsys.readouterr().out
    assert "shoulder_pan" in out and "R²" in out and "robot.identified.yaml" in out
    assert path.read_text() == before  # the config itself: untouched without --write
    copy = tmp_path / "robot.identified.yaml"
    assert copy.read_text().startswith("# arm6 on a twin with known friction")  # comments kept
    loaded = load_config(copy)
    for joint, coulomb in TRUE_COULOMB.items():
        friction = loaded.config.joints[joint].friction
        assert friction is not None
        assert friction.coulomb == pytest.approx(coulomb, rel=0.05), joint
        assert friction.viscous == pytest.approx(TRUE_VISCOUS[joint], rel=0.15), joint
        assert abs(friction.offset) < 0.05 * coulomb, joint
    assert loaded.config.joints["wrist_1"].friction is None  # not swept: not written
    original = load_config(path).config.model_dump()
    for joint in TRUE_COULOMB:
        original["joints"][joint]["friction"] = loaded.config.joints[joint].friction.model_dump()  # type: ignore[union-attr]
    assert loaded.config.model_dump() == original  # nothing else changed


def test_identify_write_changes_the_file_itself(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = twin_with_friction(tmp_path)
    assert main(["identify", str(path), "--joints", "wrist_2", "--speeds", "0.1", "0.2", "--write"]) == 0
    friction = load_config(path).config.joints["wrist_2"].friction
    assert friction is not None and friction.coulomb == pytest.approx(TRUE_COULOMB["wrist_2"], rel=0.05)
    assert not (tmp_path / "robot.identified.yaml").exists()


def test_identify_refuses_unknown_joints_and_bad_speeds(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = twin_with_friction(tmp_path)
    assert main(["identify", str(path), "--joints", "nose"]) == 2
    assert "unknown joints ['nose']" in capsys.readouterr().err
    assert main(["identify", str(path), "--speeds", "1.5"]) == 2
    assert "fractions in (0, 1]" in capsys.readouterr().err


def test_a_joint_without_room_to_sweep_is_reported_not_written(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = twin_with_friction(tmp_path)
    config = yaml.safe_load(path.read_text())
    config["joints"]["wrist_1"]["limits"]["position"] = {"lower": -1.05, "upper": -0.9}  # home -0.97: soft ±0.025
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    assert main(["identify", str(path), "--joints", "wrist_1", "wrist_2", "--speeds", "0.1", "0.2"]) == 1
    out = capsys.readouterr().out
    assert "wrist_1         not identified: no room to sweep" in out
    copy = load_config(tmp_path / "robot.identified.yaml")
    assert copy.config.joints["wrist_1"].friction is None and copy.config.joints["wrist_2"].friction is not None


def test_the_fit_recovers_the_model_it_fits_and_pins_negative_friction_at_zero() -> None:
    rng = np.random.default_rng(1)
    v = np.concatenate([rng.uniform(0.05, 0.6, 200), -rng.uniform(0.05, 0.6, 200)])
    model = FrictionArrays(np.array([0.7]), np.array([0.4]), np.array([0.05]), np.array([0.02]))
    tau = np.array([model.torque(np.array([x]), np.zeros(1))[0] for x in v]) + rng.normal(0.0, 0.002, v.size)
    fit = fit_friction(v, tau)
    assert fit.viscous == pytest.approx(0.7, abs=0.01) and fit.coulomb == pytest.approx(0.4, abs=0.01)
    assert fit.offset == pytest.approx(0.05, abs=0.005) and fit.r2 > 0.99 and fit.samples == 400
    pushing = fit_friction(v, -0.3 * v)  # a torque *with* the motion: no friction, pinned at 0
    assert pushing.viscous == 0.0 and pushing.coulomb == 0.0
    with pytest.raises(ValueError, match="one direction only"):
        fit_friction(np.abs(v), tau)
    with pytest.raises(ValueError, match="two speeds or more"):
        fit_friction(np.array([0.3, 0.31, -0.3, -0.3]), np.array([1.0, 1.0, -1.0, -1.0]))
    with pytest.raises(ValueError, match="at least 3"):
        fit_friction(np.array([0.1, -0.1]), np.array([0.0, 0.0]))
