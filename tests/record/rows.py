"""Synthetic cycle rows for the recording tests: every field distinct and awkward (NaN, negative zero, extreme
ints), so a round trip that loses a bit, a sign or a column shows."""

from __future__ import annotations

import numpy as np

from hild.crossing.cyclelog import OWNER_NONE, CycleRows
from hild.record.model import EpisodeMeta, RecordedEvent

JOINTS = ("shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3")
CODES = {1: "arm_trajectory", 2: "gripper_servo"}
WALL0 = 1_767_225_600.123456789  # 2026-01-01, a wall time whose float64 has 238 ns steps


def make_rows(count: int, joints: int = len(JOINTS), *, start_tick: int = 1000, seed: int = 0, rate: float = 1000.0):
    """``count`` rows at ``rate`` Hz: controller 1 owns the first joints, 2 the last one on even ticks only."""
    rng = np.random.default_rng(seed)
    tick = np.arange(start_tick, start_tick + count, dtype=np.int64)
    t = tick / rate
    wall = WALL0 + (tick - start_tick) / rate + rng.normal(0, 2e-6, count)

    def floats() -> np.ndarray:
        return rng.normal(0, 1, (count, joints))

    owner = np.full((count, joints), 1, np.int16)
    owner[:, -1] = np.where(tick % 2 == 0, 2, OWNER_NONE)
    if count:
        owner[0, :] = OWNER_NONE  # a cycle nobody commanded
    tau_ext = floats()
    tau_ext[::7] = np.nan
    position = floats()
    position[::5, 0] = -0.0
    return CycleRows(
        tick=tick,
        t=t,
        wall=wall,
        period=np.full(count, 1 / rate) + rng.normal(0, 1e-7, count),
        duration=rng.uniform(1e-5, 2e-4, count),
        measured_position=floats(),
        measured_velocity=floats(),
        measured_effort=floats() * 1e-300,
        fresh=rng.random((count, joints)) > 0.1,
        fault=rng.integers(-(2**15), 2**15, (count, joints)).astype(np.int16),
        position=position,
        velocity=floats(),
        effort=floats(),
        kp=rng.uniform(0, 500, (count, joints)),
        kd=rng.uniform(0, 50, (count, joints)),
        mode=rng.integers(-128, 128, (count, joints)).astype(np.int8),
        owner=owner,
        tau_ext=tau_ext,
        source=np.where(owner == OWNER_NONE, 0, rng.integers(1, 6, (count, joints))).astype(np.int8),
    )


def make_meta(episode_id: str = "20260101-000000-arm6", joints: tuple[str, ...] = JOINTS) -> EpisodeMeta:
    return EpisodeMeta(
        id=episode_id,
        robot="arm6",
        joints=list(joints),
        state="recording",
        task="pick the cube",
        note=None,
        fps=30.0,
        update_rate=1000.0,
        config_path="/etc/hild/arm6.yaml",
        config_sha256="0" * 64,
        versions={"hild": "test"},
        started_wall=WALL0,
        start_tick=1000,
        controller_codes=dict(CODES),
    )


def make_event(wall: float, kind: str = "event", **data: object) -> RecordedEvent:
    return RecordedEvent(wall=wall, t=wall - WALL0, kind=kind, data=dict(data))


def assert_rows_equal(got: CycleRows, want: CycleRows) -> None:
    """Every field bit-identical (NaN payloads and -0.0 included) and of the same dtype."""
    from dataclasses import fields

    for f in fields(CycleRows):
        a, b = getattr(got, f.name), getattr(want, f.name)
        assert a.dtype == b.dtype, f"{f.name}: {a.dtype} != {b.dtype}"
        assert a.shape == b.shape, f"{f.name}: {a.shape} != {b.shape}"
        assert a.tobytes() == b.tobytes(), f"{f.name} differs"
