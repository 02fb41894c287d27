"""measure_window: the one recipe (warm up, restart the statistics on the cycle thread, count a window)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from hild.bench.measure import RateRefused, cycle_running, lockstep_engine, measure_window, start_engine
from hild.config import load_config
from hild.cycle.engine import Engine
from tests.conftest import CONFIGS, mock_robot


def test_it_warms_up_restarts_and_returns_exactly_the_cycles_asked_for(make_engine: Callable[..., Engine]) -> None:
    engine = make_engine()  # lockstep: sim clock, as fast as it goes
    realtime = engine.loaded.config.realtime
    with cycle_running(engine, realtime, clock="sim", real_time_factor=0.0):
        window = measure_window(engine, warmup=0.05, cycles=300, take_every=0.01)
        ran = engine.cycle
    assert window.warmup_cycles > 0  # the warm-up ran, and is not in the window
    assert ran >= window.warmup_cycles + 300
    assert 300 <= engine.stats.cycles <= engine.cycle - window.warmup_cycles  # restarted after the warm-up
    assert window.cycles == 300 and window.lost == 0
    assert len(window.duration_ns) == len(window.period_error_ns) == 300
    assert (window.duration_ns > 0).all()
    figures = window.figures()
    assert figures["cycles"] == 300 and figures["duration_us"]["n"] == 300


def test_a_window_of_seconds_holds_every_cycle_it_counted(make_engine: Callable[..., Engine]) -> None:
    engine = make_engine()
    with cycle_running(engine, engine.loaded.config.realtime, clock="sim", real_time_factor=0.0):
        window = measure_window(engine, warmup=0.0, seconds=0.1, take_every=0.01)
    assert window.seconds >= 0.1
    assert window.cycles > 0 and window.lost == 0
    assert len(window.duration_ns) == window.cycles


def test_it_wants_seconds_or_cycles_not_both(make_engine: Callable[..., Engine]) -> None:
    engine = make_engine()
    with pytest.raises(ValueError, match="one of the two"):
        measure_window(engine, warmup=0.0)
    with pytest.raises(ValueError, match="one of the two"):
        measure_window(engine, warmup=0.0, seconds=1.0, cycles=10)


def test_start_engine_starts_the_configs_engine_with_the_controllers_asked_for(
    write_config: Callable[..., Path],
) -> None:
    loaded = load_config(write_config(mock_robot()))
    engine = start_engine(loaded, ["fwd"])
    try:
        assert {r.name for r in engine.manager.active} == {"jsb", "fwd"}  # autostart, and the one asked for
    finally:
        engine.stop()
    with pytest.raises(RuntimeError, match="cannot activate nope"):
        start_engine(load_config(write_config(mock_robot())), ["nope"])


def test_a_lockstep_engine_at_another_rate_keeps_the_twins_physics_step() -> None:
    engine = lockstep_engine(CONFIGS / "arm6_twin.yaml", rate=1000.0)  # the config runs at 500 Hz, substeps 2
    try:
        assert engine.update_rate == 1000.0 and engine.clock_source == "sim"
        assert engine.loaded.config.clock.real_time_factor == 0.0
        (params,) = engine.loaded.driver_params.values()
        assert params.substeps == 1  # type: ignore[attr-defined]
    finally:
        engine.stop()


def test_a_lockstep_engine_refuses_a_rate_its_hardware_cannot_follow(write_config: Callable[..., Path]) -> None:
    with pytest.raises(RateRefused, match="no substeps"):
        lockstep_engine(write_config(mock_robot()), rate=1000.0)  # the mock robot runs at 500 Hz
