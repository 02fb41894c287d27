"""The cycle log (hild/crossing/cyclelog.py): the ring alone (readers, losses, torn rows, another process), then the
engine writing it in lockstep (every row equals that cycle's state, final command and modes; owner codes), then the
links that hand it to the recorder process."""

from __future__ import annotations

import multiprocessing
import os
import tracemalloc
from collections.abc import Callable
from multiprocessing.connection import Connection
from multiprocessing.reduction import recv_handle, send_handle
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hild.arrays import JointState, ServoCommand
from hild.config import load_config
from hild.crossing.attach import Crossing
from hild.crossing.cyclelog import (
    OWNER_NONE,
    CycleLog,
    CycleLogError,
    CycleLogPlace,
    CycleLogTap,
    CycleRow,
    CycleRows,
    capacity_of,
    cycle_log_bytes,
    cycle_log_capacity,
)
from hild.crossing.region import RegionError
from hild.crossing.requests import Load, Unload
from hild.crossing.stats import LoopStats
from hild.cycle.engine import Engine
from hild.cycle.supervisor import Fault
from hild.daemon.local import LocalCycle
from hild.daemon.remote import SpawnedCycle
from hild.modes import JointMode
from tests.conftest import merge, mock_robot
from tests.test_contact import THRESHOLDS
from tests.test_contact import config as contact_config
from tests.test_engine import send

JOINTS = 3


class Producer:
    """A cycle's arrays and a tap over them: ``cycle(k)`` writes row ``k`` with values derived from ``k``."""

    def __init__(self, log: CycleLog, stats: LoopStats | None = None) -> None:
        n = log.joints
        self.row = CycleRow(n)  # as the engine builds its arrays: the float ones are views of the row
        self.state = JointState.zeros(n, over=lambda name: self.row.field(f"measured_{name}"))
        self.final = ServoCommand.zeros(n, over=self.row.field)
        self.mode, self.fault = np.zeros(n, np.int64), np.zeros(n, np.int64)
        self.owner, self.tau_ext = self.row.field("owner"), self.row.field("tau_ext")
        self.change_seq = 0  # as the supervisor's: bumped with every fault or mode change
        self.tap = CycleLogTap(
            log, row=self.row, fresh=self.state.fresh, fault=self.fault, mode=self.mode, changes=self, stats=stats
        )

    def cycle(self, k: int) -> None:
        self.state.position[:] = k + np.arange(len(self.mode)) / 10
        self.final.position[:] = -self.state.position
        self.tap.record(k, k * 0.002, 1.7e9 + k * 0.002, 0.002)

    def run(self, first: int, count: int) -> None:
        for k in range(first, first + count):
            self.cycle(k)


def expect_ticks(rows: CycleRows, first: int, count: int) -> None:
    assert rows.tick.tolist() == list(range(first, first + count))
    assert rows.measured_position[:, 0].tolist() == [float(k) for k in range(first, first + count)]
    assert (rows.position == -rows.measured_position).all()  # a row is one cycle's, never two half rows


# ---- the ring alone -----------------------------------------------------------------------------------------------


def test_a_row_holds_every_field_of_its_cycle_with_the_types_of_cycle_rows() -> None:
    log = CycleLog.private(JOINTS, 16)
    stats = LoopStats()
    producer = Producer(log, stats)
    reader = log.reader()
    stats.record(250_000, 0, False)  # the last completed cycle took 250 µs
    producer.state.velocity[:] = [1.0, 2.0, 3.0]
    producer.state.effort[:] = [4.0, 5.0, 6.0]
    producer.state.fresh[:] = [True, False, True]
    producer.fault[:] = [0, int(Fault.STALE_FEEDBACK), 0]
    producer.mode[:] = [JointMode.CONTROLLED, JointMode.FAULT, JointMode.HOLD]
    producer.change_seq += 1
    producer.owner[:] = [2, 2, 0]
    producer.final.velocity[:], producer.final.effort[:] = [0.5, 0.6, 0.7], [7.0, 8.0, 9.0]
    producer.final.kp[:], producer.final.kd[:] = [100.0, 0.0, 100.0], [5.0, 1.0, 5.0]
    producer.tau_ext[:] = [0.25, np.nan, -0.5]
    producer.cycle(41)
    rows = reader.take()
    assert len(rows) == 1 and reader.lost == 0
    assert rows.tick.dtype == np.int64 and rows.tick.tolist() == [41]
    assert rows.t.tolist() == [41 * 0.002] and rows.wall.tolist() == [1.7e9 + 41 * 0.002]
    assert rows.period.tolist() == [0.002] and rows.duration.tolist() == [250e-6]
    assert rows.measured_position.tolist() == [[41.0, 41.1, 41.2]]
    assert rows.measured_velocity.tolist() == [[1.0, 2.0, 3.0]] and rows.measured_effort.tolist() == [[4.0, 5.0, 6.0]]
    assert rows.fresh.dtype == np.bool_ and rows.fresh.tolist() == [[True, False, True]]
    assert rows.fault.dtype == np.int16 and rows.fault.tolist() == [[0, int(Fault.STALE_FEEDBACK), 0]]
    assert rows.position.tolist() == [[-41.0, -41.1, -41.2]]
    assert rows.velocity.tolist() == [[0.5, 0.6, 0.7]] and rows.effort.tolist() == [[7.0, 8.0, 9.0]]
    assert rows.kp.tolist() == [[100.0, 0.0, 100.0]] and rows.kd.tolist() == [[5.0, 1.0, 5.0]]
    assert rows.mode.dtype == np.int8 and rows.mode.tolist() == [[1, 2, 0]]
    # the claimed owner of the faulted joint does not command it: OWNER_NONE
    assert rows.owner.dtype == np.int16 and rows.owner.tolist() == [[2, OWNER_NONE, OWNER_NONE]]
    assert rows.tau_ext[0, 0] == 0.25 and np.isnan(rows.tau_ext[0, 1]) and rows.tau_ext[0, 2] == -0.5
    assert all(getattr(rows, f).base is None for f in rows.__dataclass_fields__)  # each owns its memory


def test_a_reader_takes_each_row_once_in_order() -> None:
    log = CycleLog.private(JOINTS, 16)
    producer = Producer(log)
    producer.run(1, 3)
    reader = log.reader()  # from the next row committed
    assert len(reader.take()) == 0
    producer.run(4, 5)
    expect_ticks(reader.take(), 4, 5)
    producer.run(9, 10)
    expect_ticks(reader.take(), 9, 10)
    assert len(reader.take()) == 0 and reader.lost == 0 and log.head == 18


def test_a_reader_that_falls_behind_loses_and_counts_rows_while_another_reader_is_unaffected() -> None:
    log = CycleLog.private(JOINTS, 8)
    producer = Producer(log)
    keeping_up, behind = log.reader(), log.reader()
    taken = []
    for first in range(1, 31, 3):
        producer.run(first, 3)
        taken.append(keeping_up.take())
    expect_ticks(CycleRows.concat(taken, JOINTS), 1, 30)
    assert keeping_up.lost == 0
    late = behind.take()
    expect_ticks(late, 24, 7)  # the newest capacity - 1 rows: the slot being filled is never read
    assert behind.lost == 23
    producer.run(31, 2)
    expect_ticks(behind.take(), 31, 2)  # caught up: nothing more lost
    assert behind.lost == 23
    expect_ticks(keeping_up.take(), 31, 2)


def test_rows_the_producer_overwrites_while_a_take_copies_them_are_dropped_and_counted(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The reader read head, then the producer wrote three more rows into the oldest slots of the range being
    copied before the copy got there: those slots now hold newer cycles, and must not come out as the old ones."""
    log = CycleLog.private(JOINTS, 8)
    producer = Producer(log)
    reader = log.reader()
    producer.run(1, 6)
    gather = log._gather

    def overtaken(start: int, stop: int) -> np.ndarray:
        producer.run(7, 4)  # seq 6…9 land in slots 6, 7, 0, 1: rows 1 and 2 (slots 0, 1) are overwritten
        return gather(start, stop)

    monkeypatch.setattr(log, "_gather", overtaken)
    rows = reader.take()
    monkeypatch.undo()
    # rows 1 and 2 overwritten, row 3's slot the next the producer fills: dropped, no newer cycle posing as an old one
    assert rows.tick.tolist() == [4, 5, 6]
    expect_ticks(rows, 4, 3)
    assert reader.lost == 3
    expect_ticks(reader.take(), 7, 4)
    assert reader.lost == 3


def test_last_gives_the_newest_rows_oldest_first() -> None:
    log = CycleLog.private(JOINTS, 8)
    producer = Producer(log)
    assert len(log.last(5)) == 0
    producer.run(1, 3)
    expect_ticks(log.last(5), 1, 3)  # fewer were ever written
    producer.run(4, 20)
    expect_ticks(log.last(4), 20, 4)
    expect_ticks(log.last(100), 17, 7)  # at most capacity - 1
    assert len(log.last(0)) == 0
    assert log.last(3).measured_position.shape == (3, JOINTS)


def test_a_reader_from_a_start_tick() -> None:
    log = CycleLog.private(JOINTS, 8)
    producer = Producer(log)
    producer.run(101, 5)  # ticks 101…105, seq 0…4
    from_103 = log.reader(start_tick=103)
    expect_ticks(from_103.take(), 103, 3)
    assert from_103.lost == 0
    future = log.reader(start_tick=108)
    producer.run(106, 4)  # 106…109
    expect_ticks(future.take(), 108, 2)
    assert future.lost == 0
    expect_ticks(from_103.take(), 106, 4)
    gone = log.reader(start_tick=101)  # the ring holds 103…109 now: 101 and 102 were overwritten
    expect_ticks(gone.take(), 103, 7)
    assert gone.lost == 2


def test_record_allocates_nothing_that_outlives_it() -> None:
    log = CycleLog.private(6, cycle_log_capacity(1000, 1))
    stats = LoopStats()
    stats.record(300_000, 0, False)
    producer = Producer(log, stats)
    producer.run(1, 1000)  # warm
    tap = producer.tap
    tracemalloc.start()
    try:
        before, _ = tracemalloc.get_traced_memory()
        for k in range(1001, 21001):
            tap.record(k, 0.1, 1.7e9, 0.001)
        after, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert after - before < 1024  # 20 000 rows: nothing grows
    assert peak - before < 4096  # and nothing but a transient view or two per call


def test_a_ring_laid_out_otherwise_is_refused() -> None:
    log = CycleLog.private(JOINTS, 8)
    with pytest.raises(CycleLogError, match="this side expects"):
        CycleLog(log._raw[: cycle_log_bytes(JOINTS + 1, 6)].copy(), JOINTS + 1, 6)
    with pytest.raises(CycleLogError, match="this side expects"):
        CycleLog(np.zeros(cycle_log_bytes(JOINTS, 8), np.uint8), JOINTS, 8)  # never laid out


def test_the_capacity_keeps_the_black_box_seconds_and_a_margin(write_config: Callable[..., Path]) -> None:
    assert cycle_log_capacity(1000, 10) == 12_000
    assert cycle_log_capacity(500, 0) == cycle_log_capacity(500, 1) == 2000  # at least 2 s, plus 2 s
    loaded = load_config(write_config(mock_robot()))
    assert capacity_of(loaded.config) == 6000  # 500 Hz, blackbox_seconds 10 by default
    off = load_config(write_config(merge(mock_robot(), {"recording": {"enabled": False}}), "off.yaml"))
    assert capacity_of(off.config) == 0


# ---- another process maps it --------------------------------------------------------------------------------------


def _read_in_child(conn: Connection, place: CycleLogPlace) -> None:
    fd = recv_handle(conn)
    log = CycleLog.attach(fd, place)
    os.close(fd)  # the mapping keeps the memory
    reader = log.reader(start_tick=1)
    rows = reader.take()
    try:
        log._rows[0, 0] = 1.0
        writable = True
    except ValueError:
        writable = False
    conn.send((rows.tick.tolist(), rows.measured_position.tolist(), reader.lost, log.head, writable))
    conn.send(log.last(2).tick.tolist())
    conn.close()


def test_a_spawned_process_maps_the_fd_and_reads_the_rows_this_one_wrote() -> None:
    log, fd, place = CycleLog.memfd(JOINTS, 64)
    try:
        producer = Producer(log)
        producer.run(1, 10)
        context = multiprocessing.get_context("spawn")
        ours, theirs = context.Pipe()
        child = context.Process(target=_read_in_child, args=(theirs, place))
        child.start()
        send_handle(ours, fd, child.pid)
        ticks, positions, lost, head, writable = ours.recv()
        last = ours.recv()
        child.join(30)
        assert child.exitcode == 0
    finally:
        os.close(fd)
    assert ticks == list(range(1, 11)) and head == 10 and lost == 0
    assert positions == log.last(10).measured_position.tolist()
    assert last == [9, 10]
    assert not writable  # a reader maps the ring read-only: it can never disturb the cycle's rows


def test_attaching_with_a_place_that_does_not_fit_the_file_is_refused() -> None:
    log, fd, place = CycleLog.memfd(JOINTS, 64)
    try:
        with pytest.raises(CycleLogError, match="bytes; its place says"):
            CycleLog.attach(fd, CycleLogPlace(place.size + 4096, 0, place.nbytes, JOINTS, 64))
        with pytest.raises(CycleLogError, match="this side expects"):
            CycleLog.attach(fd, CycleLogPlace(place.size, 0, cycle_log_bytes(JOINTS, 32), JOINTS, 32))
        attached = CycleLog.attach(fd, place)
        Producer(log).run(5, 2)
        assert attached.head == 2 and attached.last(2).tick.tolist() == [5, 6]
        attached.close()
    finally:
        os.close(fd)


# ---- the engine writes it ---------------------------------------------------------------------------------------


def expected_row(engine: Engine, codes: np.ndarray) -> dict[str, Any]:
    """What the engine's arrays hold after a step: what that cycle's row must hold."""
    sup, state, final = engine.supervisor, engine.state, engine.final
    controlled = sup.mode == JointMode.CONTROLLED
    tau = engine.contact.tau_ext if engine.contact is not None else np.full(len(engine.joints), np.nan)
    return {
        "tick": engine.cycle,
        "t": engine.t,
        "wall": engine.wall,
        "period": engine.period,
        "measured_position": state.position.copy(),
        "measured_velocity": state.velocity.copy(),
        "measured_effort": state.effort.copy(),
        "fresh": state.fresh.copy(),
        "fault": sup.fault.copy(),
        "position": final.position.copy(),
        "velocity": final.velocity.copy(),
        "effort": final.effort.copy(),
        "kp": final.kp.copy(),
        "kd": final.kd.copy(),
        "mode": sup.mode.copy(),
        "owner": np.where(controlled, codes, OWNER_NONE),
        "tau_ext": tau.copy(),
    }


def owner_codes(engine: Engine) -> np.ndarray:
    """Each joint's claiming controller's code, from the snapshot's names and codes (not the engine's array)."""
    by_name = {name: code for code, name in engine.snapshot().controller_codes.items()}
    return np.array([by_name[j["owner"]] if j["owner"] else OWNER_NONE for j in engine.snapshot().joints])


def run_and_compare(engine: Engine, log: CycleLog, cycles: int, act: Callable[[int], None]) -> CycleRows:
    """Step ``cycles`` cycles (``act(k)`` before each), comparing every row the reader takes with the engine."""
    reader = log.reader()
    taken = []
    for k in range(cycles):
        act(k)
        engine.run_cycles(1)
        want = expected_row(engine, owner_codes(engine))
        rows = reader.take()
        assert len(rows) == 1
        for name, value in want.items():
            got = getattr(rows, name)[0]
            assert np.array_equal(got, value, equal_nan=True), (name, k, got, value)
        taken.append(rows)
    assert reader.lost == 0
    return CycleRows.concat(taken, len(engine.joints))


def test_every_row_equals_the_twins_cycle_with_contact_torques_a_fault_and_an_estop(tmp_path: Path) -> None:
    """Six joints on the lockstep twin, the contact observer on (tau_ext estimated every cycle)."""
    loaded = load_config(contact_config(tmp_path, {"enabled": True, **THRESHOLDS}, scale=1.0))
    log = CycleLog.private(6, capacity_of(loaded.config))
    engine = Engine(loaded, cycle_log=log)
    engine.start()
    engine.switch(["forward_position"], [])
    target = (engine.state.position + 0.05).tolist()

    def act(k: int) -> None:
        if k < 250:
            send(engine, "forward_position", target)
        if k == 150:
            engine.supervisor.trip(5, Fault.DRIVE, "test: wrist_3's drive")
        if k == 250:
            engine.request_estop()

    rows = run_and_compare(engine, log, 300, act)
    code = {name: c for c, name in engine.controller_codes.items()}["forward_position"]
    assert (rows.owner[100] == code).all() and (rows.mode[100] == JointMode.CONTROLLED).all()
    assert rows.owner[200].tolist() == [code] * 5 + [OWNER_NONE] and rows.fault[200, 5] == Fault.DRIVE
    assert (rows.owner[-1] == OWNER_NONE).all() and (rows.mode[-1] == JointMode.ESTOP).all()
    assert np.isfinite(rows.tau_ext[100]).all()  # the observer ran (its estimate, not NaN)
    assert (np.diff(rows.tick) == 1).all() and (np.diff(rows.wall) >= 0).all()


def test_every_row_equals_the_mock_engines_cycle_and_tau_ext_is_nan_without_an_observer(
    write_config: Callable[..., Path],
) -> None:
    loaded = load_config(write_config(mock_robot()))
    log = CycleLog.private(JOINTS, capacity_of(loaded.config))
    engine = Engine(loaded, cycle_log=log)
    engine.start()
    engine.switch(["fwd"], [])

    def act(k: int) -> None:
        if k < 40:
            send(engine, "fwd", [0.2, -0.1, 0.25])  # then silent: it times out after 0.2 s and the joints hold

    rows = run_and_compare(engine, log, 200, act)
    assert np.isnan(rows.tau_ext).all()
    fwd = {name: c for c, name in engine.controller_codes.items()}["fwd"]
    assert (rows.owner[:40] == fwd).all() and (rows.owner[-1] == OWNER_NONE).all()


def test_owner_codes_follow_a_switch_and_a_reload_after_an_unload_gets_a_new_code(
    write_config: Callable[..., Path],
) -> None:
    loaded = load_config(write_config(mock_robot()))
    log = CycleLog.private(JOINTS, 64)
    engine = Engine(loaded, cycle_log=log)
    engine.start()
    reader = log.reader()
    first = {name: c for c, name in engine.controller_codes.items()}["fwd"]
    assert engine.snapshot().controller_codes == engine.controller_codes

    def cycle_with(name: str | None) -> CycleRows:
        if name:
            send(engine, name, [0.1, -0.2, 0.3])
        engine.run_cycles(1)
        return reader.take()

    assert cycle_with(None).owner.tolist() == [[OWNER_NONE] * 3]
    engine.switch(["fwd"], [])
    assert cycle_with("fwd").owner.tolist() == [[first] * 3]
    engine.switch([], ["fwd"])
    assert cycle_with(None).owner.tolist() == [[OWNER_NONE] * 3]

    unloaded = engine.request(Unload("fwd"))
    engine.run_cycles(1)  # applied after this cycle's write
    assert unloaded.result(timeout=0) == {"name": "fwd"}
    params = loaded.controller_params["fwd"]
    reloaded = engine.request(Load("fwd", "forward_command", params))
    engine.run_cycles(1)
    assert reloaded.result(timeout=0)["state"] == "unconfigured"
    engine.manager.configure("fwd")
    second = {name: c for c, name in engine.controller_codes.items() if c != first}["fwd"]
    assert second not in (first, OWNER_NONE)
    codes = engine.snapshot().controller_codes
    assert codes[first] == codes[second] == "fwd"  # the old code still names what it wrote; never given again
    reader.take()
    engine.switch(["fwd"], [])
    assert cycle_with("fwd").owner.tolist() == [[second] * 3]


def test_an_engine_without_a_cycle_log_writes_none(make_engine: Callable[..., Engine]) -> None:
    engine = make_engine()
    assert engine.cycle_log is None
    engine.run_cycles(3)  # nothing to write to, nothing fails


# ---- the links hand it over ---------------------------------------------------------------------------------------


def test_local_cycle_hands_over_a_memfd_the_recorder_maps(write_config: Callable[..., Path]) -> None:
    link = LocalCycle(load_config(write_config(mock_robot())))
    handed = link.cycle_log()
    assert handed is not None
    fd, place = handed
    assert place == CycleLogPlace(place.nbytes, 0, cycle_log_bytes(JOINTS, 6000), JOINTS, 6000)
    recorder_fd = os.dup(fd)  # what send_handle gives the recorder process: an fd of its own
    try:
        attached = CycleLog.attach(recorder_fd, place)
        reader = attached.reader()
        link.engine.start()
        link.engine.run_cycles(5)
        rows = reader.take()
        assert rows.tick.tolist() == [1, 2, 3, 4, 5]
        assert rows.measured_position[-1].tolist() == link.engine.state.position.tolist()
        link.close()
        with pytest.raises(OSError):
            os.fstat(fd)  # the link's fd is closed with it …
        link.engine.run_cycles(1)
        assert reader.take().tick.tolist() == [6]  # … and the recorder's mapping still reads the cycle's rows
    finally:
        os.close(recorder_fd)


def test_with_recording_off_no_link_hands_over_a_cycle_log_and_the_engine_writes_none(
    write_config: Callable[..., Path],
) -> None:
    loaded = load_config(write_config(merge(mock_robot(), {"recording": {"enabled": False}})))
    local = LocalCycle(loaded)
    assert local.cycle_log() is None and local.engine.cycle_log is None
    local.close()
    spawned = SpawnedCycle(loaded)
    try:
        assert spawned.cycle_log() is None
        assert "engine/cycle_log" not in [name for name, _, _ in spawned.region.cells()]
    finally:
        spawned.close()


def test_spawned_cycle_carves_the_ring_in_the_region_and_hands_over_its_place(
    write_config: Callable[..., Path],
) -> None:
    loaded = load_config(write_config(mock_robot()))
    spawned = SpawnedCycle(loaded)
    try:
        handed = spawned.cycle_log()
        assert handed is not None
        fd, place = handed
        assert fd == spawned.region.fd and place.size == spawned.region.size
        assert (place.joints, place.capacity) == (JOINTS, 6000)
        cells = {name: (offset, size) for name, offset, size in spawned.region.cells()}
        assert cells["engine/cycle_log"] == (place.offset, place.nbytes)
        attached = CycleLog.attach(fd, place)  # the layout the creator laid down, found through the place
        assert attached.head == 0 and attached.capacity == 6000
        attached.close()
    finally:
        spawned.close()


def test_a_client_domain_attached_later_finds_the_same_place_and_a_different_capacity_fails_at_once() -> None:
    """Under ``hild run`` the main process carves; the client domain (a restarted one too) and the cycle process
    find the cell by name, and code or config that disagree on its size fail at start-up."""
    carved = Crossing.carve(JOINTS, 200)
    try:
        at = carved.attachment(os.getpid())
        found = Crossing.attach(JOINTS, at, 200)
        assert found.cells.cycle_log_place == carved.cells.cycle_log_place
        assert found.cells.cycle_log is not None and found.cells.cycle_log.capacity == 200
        with pytest.raises(RegionError, match="engine/cycle_log"):
            Crossing.attach(JOINTS, at, 300)
    finally:
        os.close(carved.wakeup_fd)
        os.close(carved.region.fd)  # the mappings keep the memory until they go
