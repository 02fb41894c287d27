"""Provenance in the cycle log: each row says per joint who moved it (hild.modes.Source) — the commanding
controller's source, the head of a chain's for a chained one, a change of source from the next row on, and HOLD
where no controller commands the joint (lockstep mock engine)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from hild.config import load_config
from hild.crossing.cyclelog import CycleLog, CycleRows
from hild.cycle.engine import Engine
from hild.modes import JointMode, Source
from tests.conftest import mock_robot, with_trajectory
from tests.test_engine import send
from tests.test_manager_chains import chained_robot

T, S, P, H = Source.TRAJECTORY, Source.STREAM, Source.POLICY, Source.HOLD


def engine_with_log(path: Path) -> tuple[Engine, Callable[[], CycleRows]]:
    loaded = load_config(path)
    log = CycleLog.private(3, 64)
    engine = Engine(loaded, cycle_log=log)
    engine.start()
    reader = log.reader()

    def step() -> CycleRows:
        engine.run_cycles(1)
        return reader.take()

    return engine, step


def test_each_joint_records_its_controller_s_source_and_hold_where_none_commands_it(
    write_config: Callable[..., Path],
) -> None:
    config = with_trajectory(mock_robot(), "traj", joints=("a", "b"))
    config["controllers"]["fwd"]["params"]["joints"] = ["c"]
    engine, step = engine_with_log(write_config(config))
    assert step().source.tolist() == [[H, H, H]]
    assert engine.switch(["traj", "fwd"], []).ok
    send(engine, "fwd", [0.3])
    assert step().source.tolist() == [[T, T, S]]

    engine.manager.records["fwd"].instance.source = Source.POLICY  # as a servo does when chunks take over
    send(engine, "fwd", [0.3])
    assert step().source.tolist() == [[T, T, P]]

    assert engine.switch([], ["fwd"]).ok
    assert step().source.tolist() == [[T, T, H]]
    engine.supervisor.trip(0, 5, "test: a's drive")  # a faulted joint is not moved by anyone: HOLD in the record
    rows = step()
    assert rows.source[0, 0] == H and rows.mode[0, 0] == JointMode.FAULT
    assert rows.source.tolist() == [[T if m == JointMode.CONTROLLED else H for m in rows.mode[0]]]


def test_a_chain_records_the_source_at_its_head(write_config: Callable[..., Path]) -> None:
    """A trajectory chained into the impedance controller moves the joints as a trajectory; the impedance controller
    alone, streamed targets."""
    engine, step = engine_with_log(write_config(chained_robot()))
    assert engine.switch(["imp"], []).ok
    assert step().source.tolist() == [[S, S, S]]
    assert engine.switch(["jtc_ab"], []).ok
    assert step().source.tolist() == [[T, T, S]]
