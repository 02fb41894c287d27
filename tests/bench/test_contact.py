"""``hild bench --only contact``: its reduced form runs and reports every target in group ``contact``; its
measurements work end to end through the adapter seam (with test doubles for the pieces); the seam reads the real
config keys."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from drivers.can.protocol.mit import TORQUE_BITS, quantize
from hild.bench import contact as contact_bench
from hild.bench.cli import bench, selected
from hild.bench.contact import ContactSettings, contact_targets, run_contact, target
from hild.bench.contact_adapters import TEACH_CONTROLLER, ContactAdapters
from hild.bench.contact_rig import JOINTS, JTC, ContactRig, RigSpec, rig_config
from hild.bench.report import format_report, write_json
from hild.bench.scenarios import Settings
from hild.cycle.engine import Engine
from hild.cycle.supervisor import Fault

TINY = ContactSettings(
    hits=2, quiet_seconds=1.0, obstacle_hits=1, wall_runs=1, guide_poses=1, cost_cycles=400, seed=3, quick=True
)


def test_contact_runs_only_when_named() -> None:
    assert "contact" not in selected(None)
    assert selected(["contact"]) == ["contact"]


def test_the_seam_switches_the_observer_on_with_the_configs_own_thresholds() -> None:
    adapters = ContactAdapters()
    data = rig_config(RigSpec(safety=adapters.observer_safety(True)), "x")
    contact = data["safety"]["contact"]
    assert contact["enabled"] is True and contact["force"]["collision"] == adapters.collision_force_threshold()
    assert data["safety"]["stop_descent"] == 2.0  # the rest of the section kept
    assert rig_config(RigSpec(safety=adapters.observer_safety(False)), "x")["safety"]["contact"]["enabled"] is False


def test_the_reduced_group_prints_and_writes_contact_rows(tmp_path: Path) -> None:
    settings = Settings.make(True, None, None)
    report = bench(settings, ["contact"], tmp_path)
    rows = [t for t in report["targets"] if t["group"] == "contact"]
    assert len(rows) == 9 and report["contact"]["settings"]["quick"] is True
    text = format_report(report)
    assert "TARGETS [contact]" in text and "20 N hit detected, median" in text
    write_json(report, tmp_path / "bench.json")
    written = json.loads((tmp_path / "bench.json").read_text())
    assert [t["target"] for t in written["targets"] if t["group"] == "contact"] == [t["target"] for t in rows]


def test_a_row_passes_only_on_a_measurement_within_its_limit() -> None:
    assert target("x", 9.0, 10.0, "ms", "b")["status"] == "PASS"
    assert target("x", 11.0, 10.0, "ms", "b")["status"] == "MISS"
    assert target("x", None, 10.0, "ms", "b")["status"] == "MISS"
    assert target("x", float("nan"), 10.0, "ms", "b")["status"] == "MISS"
    assert target("x", 1.0, 10.0, "ms", "b", error="boom")["detail"] == "error: boom"


# ---- the measurements, end to end, through test doubles of the pieces ---------------------------------------------
class DoubleAdapters(ContactAdapters):
    """Test doubles: a "detector" that reads the plant's truth (the push, the contact force) and trips the
    supervisor, no walls at all, and a teach "controller" that is a zero-effort forward_command. They check the
    harness's plumbing (timing, recovery, rows), not any piece."""

    rig: ContactRig | None = None

    def observer_safety(self, on: bool) -> dict[str, Any]:
        return {}

    def walls_safety(self, lower: Any, upper: Any) -> dict[str, Any]:
        return {}

    def teach_controllers(self, joints: Any) -> dict[str, Any]:
        params = {"joints": list(joints), "interface": "position", "command_timeout": 1000.0}
        return {TEACH_CONTROLLER: {"type": "forward_command", "params": params}}

    def collision_latched(self, engine: Engine) -> bool:
        rig = DoubleAdapters.rig
        if rig is not None and rig.engine is engine and not engine.supervisor.fault.any():
            plant = rig.plant
            if np.linalg.norm(plant.push_now) > 10.0 or np.linalg.norm(plant.contact_force()) > 5.0:
                engine.supervisor.trip_all(Fault.COLLISION, "collision (test double)")
        return super().collision_latched(engine)


@pytest.fixture
def doubles(monkeypatch: pytest.MonkeyPatch) -> DoubleAdapters:
    made = ContactRig.__init__

    def remember(self: ContactRig, spec: RigSpec | None = None) -> None:
        made(self, spec)
        DoubleAdapters.rig = self

    monkeypatch.setattr(ContactRig, "__init__", remember)
    return DoubleAdapters()


def test_detection_latency_is_measured_from_the_push_onset_and_the_arm_recovers(doubles: DoubleAdapters) -> None:
    result = contact_bench.measure_detection(TINY, doubles)
    assert result["detected"] == TINY.hits and result["undetected"] == 0 and result["latched_before_the_push"] == 0
    # the double reads the plant's truth, so it latches after the first cycle whose plant step carried the push;
    # an observer on the drives' replies reads it one cycle later (the replies of that step)
    assert result["latency_ms"]["median"] == pytest.approx(1.0, abs=0.01)


def test_the_quiet_run_counts_no_latch_without_contact(doubles: DoubleAdapters) -> None:
    result = contact_bench.measure_quiet(TINY, doubles)
    assert result["false_positives"] == 0 and result["moves"] >= 1 and result["seconds"] >= TINY.quiet_seconds


def test_the_obstacle_sweep_touches_the_sphere_and_reports_the_force_around_detection(
    doubles: DoubleAdapters,
) -> None:
    result = contact_bench.measure_obstacle(TINY, doubles)
    (hit,) = result["hits"]
    assert hit["contact_ms"] is not None and hit["detected_ms"] is not None
    assert (
        hit["detected_ms"] >= hit["contact_ms"]
        and result["peak_to_reflex_n"] >= 5.0
        and result["peak_n"] >= result["peak_to_reflex_n"]
    )
    assert hit["after_minus_at_detection_n"] is not None


def test_without_a_wall_the_tool_goes_past_it_and_the_row_misses(doubles: DoubleAdapters) -> None:
    result = contact_bench.measure_walls(TINY, doubles)
    assert result["overshoot_mm"] > 5.0  # nothing held the tool at the half-way wall
    rows = {t["target"]: t for t in contact_targets({"walls": result}, doubles)}
    assert rows["wall overshoot at full speed"]["status"] == "MISS"


def test_an_arm_that_holds_against_the_hand_is_not_guidable(doubles: DoubleAdapters) -> None:
    """The double "teach" controller gets no input, so the supervisor holds the arm: 5 N does not move it."""
    result = contact_bench.measure_guiding(TINY, doubles)
    (pose,) = result["poses"]
    assert pose["moved_at_n"] is None and result["unmoved"] == 1 and result["force_to_move_n"] is None
    assert result["drift_mrad_s"] < 2.0  # held, it stays
    rows = {t["target"]: t for t in contact_targets({"guiding": result}, doubles)}
    assert rows["hand-guiding force to move"]["status"] == "MISS"
    assert rows["hand-guiding drift after release"]["status"] == "PASS"


def test_the_rig_steps_the_emulated_arm_in_lockstep_deterministically() -> None:
    def run() -> np.ndarray:
        with ContactRig() as rig:
            rig.activate(JTC)
            target = rig.engine.state.position + np.array([0.3, -0.2, 0.2, 0.0, 0.0, 0.1])  # type: ignore[union-attr]
            rig.move(target)
            rig.push([0.0, 0.0, -20.0], 0.2, delay=0.1)
            rig.seconds(0.5)
            assert rig.plant.time == pytest.approx(rig.engine.t)  # type: ignore[union-attr]
            return np.concatenate([rig.plant.positions, rig.engine.state.effort])  # type: ignore[union-attr]

    first, second = run(), run()
    np.testing.assert_array_equal(first, second)
    assert len(JOINTS) == 6


def test_the_drives_report_the_torque_the_plant_got_quantised_to_12_bits() -> None:
    """What the observer will see: each Damiao reply carries the torque its law applied to the plant in the last
    step before the command arrived, through the MIT frame's 12 bits, and the engine reads exactly that."""
    with ContactRig() as rig:
        engine, runtime = rig.engine, rig.runtime
        assert engine is not None and runtime is not None
        rig.activate(JTC)
        rig.move(engine.state.position + np.array([0.4, -0.3, 0.3, 0.2, -0.2, 0.3]))
        steps = []
        for _ in range(50):
            rig.cycle(7)
            drives = runtime.rigs[0].joints
            applied = np.array([d.firmware.applied_torque for d in drives])
            wire = np.array(
                [quantize(d.firmware.applied_torque, -d.firmware.ranges.t_max, d.firmware.ranges.t_max, TORQUE_BITS)
                 for d in drives]
            )  # fmt: skip
            expected, exact = np.empty(6), np.empty(6)
            rig.plant.transmissions.joint_efforts(wire, expected)
            rig.plant.transmissions.joint_efforts(applied, exact)
            engine.run_cycles(1)  # reads the replies sent with that torque
            np.testing.assert_allclose(engine.state.effort, expected, rtol=0, atol=1e-9)
            steps.append(np.abs(engine.state.effort - exact).max())
            rig.now = engine.t
            runtime.service(rig.now)
        assert max(steps) > 1e-3  # quantised: not the float the plant used


def test_a_measurement_that_fails_misses_its_rows_with_the_error_and_the_rest_still_run(
    doubles: DoubleAdapters, monkeypatch: pytest.MonkeyPatch
) -> None:
    class Refusing(DoubleAdapters):
        def walls_safety(self, lower: Any, upper: Any) -> dict[str, Any]:
            return {"walls": {"no such key": True}}  # as a guess at a piece's config that it refuses

    def nothing(*args: Any) -> dict[str, Any]:
        return {}

    for name in ("detection", "quiet", "obstacle", "guiding"):
        monkeypatch.setattr(contact_bench, f"measure_{name}", nothing)
    report = run_contact(TINY, Refusing())
    rows = {t["target"]: t for t in report["targets"]}
    wall = rows["wall overshoot at full speed"]
    assert wall["status"] == "MISS" and wall["detail"].startswith("error: ConfigError") and "walls" in wall["detail"]
    assert report["cost"]["observer_on"]["n"] == TINY.cost_cycles  # measured all the same
    assert rows["cycle p99 rise with the observer"]["measured"] is not None
