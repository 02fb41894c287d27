"""The contact bench's rig: the emulated Damiao arm6 behind the real engine, stepped in lockstep on the sim clock.

configs/arm6_can.yaml at 1 kHz on a private python-can ``virtual`` CAN-FD channel (6 Damiao drives at 1 kHz need
more than a classic 1 Mbit/s bus; the MIT frames are the same), with `hild emulate`'s own runtime behind it
(`drivers.can.emulator.runtime`): firmware-faithful drives (12-bit torque replies) and the twin plant with the
model mismatch, obstacles and pushes of ``drivers.can.emulator.disturbances``. hild computes gravity (and the
contact observer) from configs/arm6.xml as written; the plant is ×``mismatch`` away from it.

A cycle is ``engine.step(t)`` (read the replies the drives sent, supervise, control, write) then
``runtime.service(t)`` (the drives apply the new command while the plant advances to ``t``, then reply), so a
push that starts at plant time ``s`` is first read by the cycle after the one at ``s + period``, as on a real bus.
Nothing runs on wall time: the same seed gives the same run.
"""

from __future__ import annotations

import tempfile
import time
import uuid
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import yaml

from drivers.can.emulator.disturbances import Obstacle, PlantMismatch, Push
from drivers.can.emulator.runtime import EmulatorRuntime, RuntimeOptions, build_runtime
from drivers.mujoco.plant import TwinPlant
from hild.api.goals import GoalEndpoint
from hild.bench.daemon import CONFIGS
from hild.config import load_config
from hild.config.documents import load_document
from hild.cycle.engine import Engine

ARM6_CAN = CONFIGS / "arm6_can.yaml"
ARM6_MODEL = CONFIGS / "arm6.xml"
JTC = "joint_trajectory"
RATE = 1000.0
PLANT_STEP = 0.0005  # s: the drives' law and the physics, twice per cycle
JOINTS = ("shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3")
HOME = {"shoulder_lift": 1.0, "elbow": -1.6, "wrist_1": -0.9708, "wrist_2": 1.5708}
DEFAULT_MISMATCH = PlantMismatch(mass=1.1, friction=1.3, spread=0.0)


@dataclass(frozen=True)
class RigSpec:
    """What one rig is: its mismatch, obstacles, extra ``safety`` keys and controllers, its start pose."""

    mismatch: PlantMismatch = DEFAULT_MISMATCH
    obstacles: Sequence[Obstacle] = ()
    safety: Mapping[str, Any] = field(default_factory=dict)
    controllers: Mapping[str, Any] = field(default_factory=dict)
    initial_positions: Mapping[str, float] = field(default_factory=lambda: dict(HOME))
    rate: float = RATE


def rig_config(spec: RigSpec, channel: str) -> dict[str, Any]:
    """configs/arm6_can.yaml as the rig runs it: sim clock, ``spec.rate``, a virtual CAN-FD bus, spec's extras."""
    data: dict[str, Any] = load_document(ARM6_CAN)
    data["robot"]["model"] = str(ARM6_MODEL)
    data["update_rate"] = spec.rate
    data["clock"] = {"source": "sim", "real_time_factor": 0}
    data["hardware"]["arm"]["params"]["bus"] = {
        "interface": "virtual",
        "channel": channel,
        "fd": True,
        "data_bitrate": 5_000_000,
    }
    data["hardware"]["arm"]["params"]["timeout_ms"] = 100
    data.pop("zenoh", None)
    data["safety"] = merged(data.get("safety", {}), spec.safety)
    data["controllers"] = {**data["controllers"], **spec.controllers}
    return data


def merged(base: Mapping[str, Any], extra: Mapping[str, Any]) -> dict[str, Any]:
    """``base`` with ``extra``'s keys, sections merged key by key (``{"contact": {"enabled": True}}`` switches the
    observer on and keeps the config's thresholds)."""
    out = dict(base)
    for key, value in extra.items():
        old = out.get(key)
        out[key] = merged(old, value) if isinstance(old, Mapping) and isinstance(value, Mapping) else value
    return out


_probe: list[TwinPlant] = []


def tool_at(positions: Sequence[float]) -> np.ndarray:
    """Where arm6's tool site is at joint ``positions`` (world, m; a mismatch changes no length)."""
    return _probe_at(positions).tool_position()


def _probe_at(positions: Sequence[float], mismatch: PlantMismatch | None = None) -> TwinPlant:
    if not _probe:
        _probe.append(TwinPlant(ARM6_MODEL, JOINTS, gravity=False, mismatch=DEFAULT_MISMATCH))
    probe = _probe[0]
    probe.reset(None, dict(zip(JOINTS, (float(p) for p in positions), strict=True)))
    return probe


def tool_mass(positions: Sequence[float], direction: Sequence[float]) -> float:
    """The plant's (``DEFAULT_MISMATCH``) effective mass at the tool site along ``direction`` (kg):
    ``1 / (nᵀ J M⁻¹ Jᵀ n)``, what a contact there pushes against. MuJoCo's direct ``solref`` is a stiffness and a
    damping per unit of that mass, so an obstacle of ``k`` N/m at the tool is ``k / tool_mass`` in it."""
    probe = _probe_at(positions)
    m, d = probe.model, probe.data
    mujoco.mj_forward(m, d)
    site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "tool")
    jac = np.zeros((3, m.nv))
    mujoco.mj_jacSite(m, d, jac, None, site)
    n = np.asarray(direction, dtype=float) / np.linalg.norm(direction)
    row = (n @ jac).reshape(1, -1)
    solved = np.zeros_like(row)
    mujoco.mj_solveM(m, d, solved, row)
    return 1.0 / float((row @ solved.T)[0, 0])


class ContactRig:
    """One engine and its emulated arm; `cycle` steps both. Close it (or use it as a context manager)."""

    def __init__(self, spec: RigSpec | None = None) -> None:
        self.spec = spec or RigSpec()
        self._dir = tempfile.TemporaryDirectory(prefix="hild-contact-")
        path = Path(self._dir.name) / "arm6_contact.yaml"
        channel = f"contact-{uuid.uuid4().hex[:10]}"
        path.write_text(yaml.safe_dump(rig_config(self.spec, channel), sort_keys=False))
        self.runtime: EmulatorRuntime | None = None
        self.engine: Engine | None = None
        try:
            loaded = load_config(path)
            options = RuntimeOptions(
                initial_positions=dict(self.spec.initial_positions),
                max_step=PLANT_STEP,
                mismatch=self.spec.mismatch,
                obstacles=self.spec.obstacles,
            )
            self.runtime = build_runtime(loaded, options)
            self.runtime.open()
            self.now = 0.0
            self.engine = Engine(loaded)
            for slot in self.engine.hardware:
                slot.component.serve_while_waiting = self._serve  # type: ignore[attr-defined]
            self.engine.start()
        except BaseException:
            self.close()
            raise
        assert self.runtime.twin is not None
        self.plant: TwinPlant = self.runtime.twin
        self.period = self.engine.period

    def _serve(self) -> None:
        assert self.runtime is not None
        self.runtime.service(self.now)

    # ---- running -------------------------------------------------------------------------------------------------
    def cycle(self, count: int = 1) -> None:
        """``count`` cycles: the engine steps, then the drives and the plant catch up to its time."""
        engine, runtime = self.engine, self.runtime
        assert engine is not None and runtime is not None
        for _ in range(count):
            engine.run_cycles(1)
            self.now = engine.t
            runtime.service(self.now)

    def timed_cycle(self) -> tuple[int, int, int]:
        """One cycle; returns, in ns: the cycle's duration as the daemon's loop statistics count it (from its start
        to its hardware writes done, ``engine.write_done_ns``: what can delay a command), and the wall and thread CPU
        time of the engine's whole step (work after the writes included). The emulator's service is excluded."""
        engine, runtime = self.engine, self.runtime
        assert engine is not None and runtime is not None
        wall, cpu = time.perf_counter_ns(), time.thread_time_ns()
        engine.run_cycles(1)
        cpu, done, end = time.thread_time_ns() - cpu, engine.write_done_ns, time.perf_counter_ns()
        self.now = engine.t
        runtime.service(self.now)
        return done - wall, end - wall, cpu

    def until(self, condition: Callable[[], bool], limit: float) -> bool:
        """Cycles until ``condition()`` (True) or ``limit`` s of sim time (False)."""
        for _ in range(max(1, round(limit / self.period))):
            self.cycle()
            if condition():
                return True
        return False

    def seconds(self, duration: float) -> None:
        self.cycle(max(0, round(duration / self.period)))

    def request(self, action: Callable[[], Any], limit: float = 1.0) -> Any:
        """An operator request through the engine's queue, answered between two cycles (a reset may wait)."""
        assert self.engine is not None
        future = self.engine.submit(action)
        for _ in range(round(limit / self.period)):
            self.cycle()
            if future.done():
                return future.result(timeout=0)
        raise TimeoutError(f"the engine did not answer within {limit:g} s")

    # ---- the arm -------------------------------------------------------------------------------------------------
    @property
    def joints(self) -> tuple[str, ...]:
        assert self.engine is not None
        return self.engine.joints

    def push(self, force: Sequence[float], duration: float, ramp: float = 0.0, delay: float = 0.0) -> Push:
        """Push the tool (N, world) from the plant's next step (+ ``delay``) on; returns the push (its start)."""
        push = Push((float(force[0]), float(force[1]), float(force[2])), self.plant.time + delay, duration, ramp)
        self.plant.pushes.append(push)
        return push

    def move(self, positions: Sequence[float], duration: float | None = None) -> str:
        """A move_to goal for joint_trajectory (time-optimal at the joints' limits when ``duration`` is None)."""
        goal: dict[str, Any] = {"positions": [float(p) for p in positions]}
        if duration is not None:
            goal["duration"] = float(duration)
        reply = self.goals().submit(goal)
        if not reply["ok"]:
            raise ValueError(f"move refused: {reply['error']}")
        return str(reply["goal_id"])

    def cancel(self, goal_id: str) -> None:
        self.goals().cancel({"goal_id": goal_id})

    def goals(self) -> GoalEndpoint[Any]:
        assert self.engine is not None
        return GoalEndpoint.of(self.engine.manager.records[JTC].instance.action)

    def activate(self, *controllers: str, deactivate: Sequence[str] = ()) -> None:
        """Make ``controllers`` active (those already active stay so)."""
        assert self.engine is not None
        engine = self.engine
        active = {record.name for record in engine.manager.active}
        controllers = tuple(c for c in controllers if c not in active)
        if not controllers and not deactivate:
            return
        result = self.request(lambda: engine.switch(list(controllers), list(deactivate), strict=False))
        if not result.ok:
            raise RuntimeError(f"cannot activate {controllers}: {result.error}")

    # ---- teardown ------------------------------------------------------------------------------------------------
    def close(self) -> None:
        if self.engine is not None and self.engine.started:
            self.engine.stop()
        if self.runtime is not None:
            self.runtime.close()
        self._dir.cleanup()

    def __enter__(self) -> ContactRig:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
