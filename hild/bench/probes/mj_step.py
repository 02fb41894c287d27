"""The physics floor for ``hild bench``: raw ``mj_step`` of a config's model, with nothing of hild around it.

The model is the config's ``mujoco`` hardware component's, at the twin's physics step
(``period / substeps``) and start keyframe, so the figure is the part of the twin's cycle time that is MuJoCo's.
"""

from __future__ import annotations

import sys
import threading
import time
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from drivers.mujoco.twin import MujocoTwinParams
from hild.config import load_config
from hild.crossing.stats import percentiles
from hild.dynamics.model import load_model

WARMUP_STEPS = 200


def mj_step(count: int = 5000, config: str | Path | None = None, **_: Any) -> dict[str, Any]:
    """µs per ``mj_step`` (p50/p99/p99.9/max and mean) over ``count`` steps of the config's twin model."""
    if config is None:
        raise ValueError("the mj_step probe needs a robot config with a mujoco hardware component")
    if count < 1:
        raise ValueError("count must be positive")
    loaded = load_config(config)
    cfg = loaded.config
    found = [(n, p) for n, p in loaded.driver_params.items() if isinstance(p, MujocoTwinParams)]
    if not found:
        raise ValueError(f"{config}: no hardware component uses the mujoco driver")
    name, params = found[0]
    model = load_model(loaded.directory / params.model, params.exclude_contacts)
    model.opt.timestep = 1.0 / cfg.update_rate / params.substeps
    data = mujoco.MjData(model)
    if params.keyframe is not None:
        key = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, params.keyframe)
        if key >= 0:
            mujoco.mj_resetDataKeyframe(model, data, key)
    clock = time.perf_counter_ns
    times = np.empty(count, dtype=np.int64)
    for k in range(count + WARMUP_STEPS):
        start = clock()
        mujoco.mj_step(model, data)
        if k >= WARMUP_STEPS:
            times[k - WARMUP_STEPS] = clock() - start
    return {
        "model": Path(params.model).name,
        "component": name,
        "timestep_ms": round(model.opt.timestep * 1e3, 4),
        "substeps": params.substeps,
        "steps": count,
        "step_us": {**percentiles(times, "ns"), "mean": round(float(times.mean()) / 1e3, 1)},
    }


def gil_release(model: mujoco.MjModel, data: mujoco.MjData, seconds: float = 1.0) -> dict[str, int]:
    """Increments a pure-Python thread makes while this thread loops for ``seconds`` over ``mj_step``, and over a
    pure-Python loop, with no forced GIL switch (switch interval 1 s): nonzero only where the call releases the
    GIL. Every release is a point where another thread may take the GIL and make the caller wait for it back."""
    previous = sys.getswitchinterval()
    sys.setswitchinterval(1.0)
    counts: dict[str, int] = {}
    try:
        for label, work in (("mj_step", lambda: mujoco.mj_step(model, data)), ("pure Python", lambda: sum(range(200)))):
            count, stop = [0], threading.Event()

            def counter(count: list[int] = count, stop: threading.Event = stop) -> None:
                while not stop.is_set():
                    count[0] += 1

            thread = threading.Thread(target=counter)
            thread.start()
            time.sleep(0.01)
            before, end = count[0], time.perf_counter() + seconds
            while time.perf_counter() < end:
                work()
            counts[label] = count[0] - before
            stop.set()
            thread.join()
    finally:
        sys.setswitchinterval(previous)
    return counts
