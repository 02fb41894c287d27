"""``hild identify``: slow sweeps of each joint in turn, a friction fit per joint, written to the config.

The robot runs in this process on an engine of its config, supervisor and all (docs/architecture.md): on the
lockstep twin (``clock.source: sim``) as fast as the machine goes, on a real arm paced on the wall clock; never
while a daemon drives the same arm (the engine opens its bus itself). Each joint in turn gets a velocity command
(a ``forward_command`` on its velocity interface, loaded here; the other joints hold): at each speed it goes out,
back through its start and out the other way, back to its start, within ``--window`` of it and never nearer its soft
limits than ``--edge``. The samples of each segment after ``--settle`` are steady: the drive's effort minus the
model's gravity at the sample's pose is the joint's friction there, and :func:`hild.dynamics.identification.
fit_friction` fits ``viscous·v + coulomb·tanh(v/band) + offset`` to them. The report gives each fit and its
quality; the config's ``joints.<j>.friction`` are written to a copy (``<config>.identified.yaml`` beside it, so
its relative paths still resolve) or, with ``--write``, to the file itself, comments and everything else kept.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hild.config import ConfigError, load_config
from hild.config.loader import LoadedConfig
from hild.config.tuned import friction_copy
from hild.cycle.engine import Engine
from hild.dynamics.identification import FrictionFit, fit_friction

PREFIX = "identify_"  # the sweep's own controllers: identify_<joint>
DEFAULT_SPEEDS = (0.05, 0.1, 0.2)  # of each joint's velocity limit
GOOD_R2 = 0.9  # a fit explaining less of the torque is reported as doubtful


@dataclass
class SweepSettings:
    joints: Sequence[str] = ()  # default: every joint
    speeds: Sequence[float] = DEFAULT_SPEEDS  # fractions of the joint's velocity limit
    window: float = 0.3  # rad (m) each way from where the joint starts
    edge: float = 0.05  # rad (m) kept from the soft limits
    settle: float = 0.3  # s dropped at the start of each segment
    real_time: bool = False  # pace on the wall clock (a real arm); the lockstep twin runs as fast as it can


@dataclass
class JointSweep:
    """One joint's steady samples: velocity, effort minus gravity; ``note`` when it could not be swept."""

    velocity: list[float] = field(default_factory=list)
    torque: list[float] = field(default_factory=list)
    note: str = ""


class Sweeper:
    """An engine of the config, with a velocity controller per joint; sweeps one joint at a time."""

    def __init__(self, loaded: LoadedConfig, settings: SweepSettings) -> None:
        self.settings = settings
        self.engine = engine = Engine(loaded)
        self.joints = list(settings.joints) or list(engine.joints)
        unknown = [j for j in self.joints if j not in engine.joints]
        if unknown:
            raise ValueError(f"unknown joints {unknown} (robot joints: {list(engine.joints)})")
        for joint in self.joints:
            params = {"joints": [joint], "interface": "velocity", "command_timeout": 1e6}
            engine.load_controller(PREFIX + joint, "forward_command", params)
        self.gravity: Any = None
        cfg = loaded.config
        if cfg.robot.model:
            from hild.dynamics.gravity import GravityModel  # mujoco stays behind this seam

            self.gravity = GravityModel(loaded.directory / cfg.robot.model, engine.joints).compute
        self._g = np.zeros(len(engine.joints))
        self._next = 0.0

    def __enter__(self) -> Sweeper:
        engine = self.engine
        engine.start()
        busy = [c["name"] for c in engine.snapshot().controllers if c["state"] == "active" and c["claimed"]]
        if busy:
            engine.switch([], busy)
        self._next = time.perf_counter()
        return self

    def __exit__(self, *exc: object) -> None:
        self.engine.stop()

    def cycle(self) -> None:
        engine = self.engine
        if self.settings.real_time:
            self._next += engine.period
            delay = self._next - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
        engine.run_cycles(1)

    def sweep(self, joint: str) -> JointSweep:
        engine, s = self.engine, self.settings
        i = engine.joints.index(joint)
        result = JointSweep()
        lim = engine.limits
        start = float(engine.state.position[i])
        low = max(start - s.window, float(lim.soft_lower[i]) + s.edge)
        high = min(start + s.window, float(lim.soft_upper[i]) - s.edge)
        if high - low < 0.02:
            result.note = f"no room to sweep between its soft limits at {start:.3f}"
            return result
        name = PREFIX + joint
        switched = engine.switch([name], [])
        if not switched.ok:
            result.note = f"not switched: {switched.error}"
            return result
        controller = engine.controllers()[name]
        try:
            for fraction in s.speeds:
                speed = fraction * float(lim.velocity[i])
                for target in (high, low, start):  # out, back through the start, out the other way, home
                    if not self._segment(i, controller, target, speed, result):
                        return result
        finally:
            controller.accept({"values": [0.0]})
            for _ in range(max(1, round(s.settle / engine.period))):
                self.cycle()
            engine.switch([], [name])
        return result

    def _segment(self, i: int, controller: Any, target: float, speed: float, out: JointSweep) -> bool:
        """Drive joint ``i`` toward ``target`` at ``speed``, keeping the steady samples; False if it never got
        there (stuck, or a fault): the sweep of this joint ends."""
        engine, s = self.engine, self.settings
        state = engine.state
        here = float(state.position[i])
        direction = 1.0 if target > here else -1.0
        controller.accept({"values": [direction * speed]})
        settle_cycles = round(s.settle / engine.period)
        nominal = abs(target - here) / speed
        budget = round((3.0 * nominal + s.settle) / engine.period)
        for k in range(budget):
            self.cycle()
            if engine.supervisor.fault.any() or engine.supervisor.estop:
                out.note = "a fault ended the sweep: " + "; ".join(t for t in engine.supervisor.fault_text if t)
                return False
            q = float(state.position[i])
            if (q - target) * direction >= 0.0:
                return True
            if k >= settle_cycles:
                torque = float(state.effort[i])
                if self.gravity is not None:
                    self.gravity(state.position, self._g)
                    torque -= float(self._g[i])
                out.velocity.append(float(state.velocity[i]))
                out.torque.append(torque)
        out.note = f"did not reach {target:.3f} at {speed:.3g}/s within {budget * engine.period:.1f} s (stuck?)"
        return False


def identify(loaded: LoadedConfig, settings: SweepSettings) -> dict[str, FrictionFit | str]:
    """Sweep and fit every joint of ``settings`` (all by default): each joint's fit, or why it has none."""
    fits: dict[str, FrictionFit | str] = {}
    bands = {name: (j.friction.band if j.friction else 0.02) for name, j in loaded.config.joints.items()}
    with Sweeper(loaded, settings) as sweeper:
        for joint in sweeper.joints:
            sweep = sweeper.sweep(joint)
            try:
                fits[joint] = fit_friction(np.array(sweep.velocity), np.array(sweep.torque), bands[joint])
            except ValueError as exc:
                fits[joint] = f"{sweep.note or 'no fit'}: {exc}" if sweep.note else str(exc)
    return fits


def report(fits: dict[str, FrictionFit | str]) -> str:
    lines = [f"{'JOINT':<16}{'VISCOUS':>10}{'COULOMB':>10}{'OFFSET':>10}{'RMS':>9}{'R²':>7}{'N':>7}  SPEEDS"]
    for joint, fit in fits.items():
        if isinstance(fit, str):
            lines.append(f"{joint:<16}not identified: {fit}")
            continue
        doubt = "  (doubtful: the model explains little of the torque)" if fit.r2 < GOOD_R2 else ""
        lines.append(
            f"{joint:<16}{fit.viscous:>10.4f}{fit.coulomb:>10.4f}{fit.offset:>10.4f}{fit.rms:>9.4f}{fit.r2:>7.3f}"
            f"{fit.samples:>7}  {fit.speeds[0]:.3g}–{fit.speeds[1]:.3g}{doubt}"
        )
    return "\n".join(lines)


def identified_path(config: Path) -> Path:
    """Beside the config, so the copy's relative paths (the model) still resolve."""
    return config.with_name(f"{config.stem}.identified.yaml")


def _cmd_identify(args: argparse.Namespace) -> int:
    path = Path(args.config)
    try:
        loaded = load_config(path)
    except ConfigError as exc:
        print(exc, file=sys.stderr)
        return 1
    speeds = tuple(args.speeds)
    numbers = (args.window, args.edge, args.settle)
    if not all(0.0 < f <= 1.0 for f in speeds) or not all(math.isfinite(v) and v >= 0.0 for v in numbers):
        print("hild identify: --speeds are fractions in (0, 1]; --window, --edge, --settle ≥ 0", file=sys.stderr)
        return 2
    real_time = args.real_time or loaded.config.clock.source != "sim"
    settings = SweepSettings(args.joints or (), speeds, args.window, args.edge, args.settle, real_time)
    try:
        fits = identify(loaded, settings)
    except ValueError as exc:
        print(f"hild identify: {exc}", file=sys.stderr)
        return 2
    print(report(fits))
    found = {j: f.as_config() for j, f in fits.items() if not isinstance(f, str)}
    if not found:
        print("hild identify: nothing identified; the config is left as it is", file=sys.stderr)
        return 1
    target = path if args.write else Path(args.output) if args.output else identified_path(path)
    text, changed = friction_copy(path, found)
    target.write_text(text, encoding="utf-8")
    print(f"wrote {', '.join(changed)} to {target}")
    return 0 if len(found) == len(fits) else 1


def register(subparsers: Any) -> None:
    """``hild identify`` (the ``hild.commands`` entry point)."""
    cmd = subparsers.add_parser(
        "identify",
        help="sweep each joint slowly, fit its friction (viscous, Coulomb, offset), write joints.<j>.friction",
        description=__doc__.split("\n\n")[1] if __doc__ else None,
    )
    cmd.add_argument("config", help="the robot's config (no daemon may be running this arm)")
    cmd.add_argument("--joints", nargs="+", metavar="JOINT", help="default: every joint")
    cmd.add_argument(
        "--speeds",
        nargs="+",
        type=float,
        default=list(DEFAULT_SPEEDS),
        metavar="FRACTION",
        help=f"sweep speeds as fractions of each joint's velocity limit (default {' '.join(map(str, DEFAULT_SPEEDS))})",
    )
    cmd.add_argument("--window", type=float, default=0.3, help="rad (m) each way from the start pose (default 0.3)")
    cmd.add_argument("--edge", type=float, default=0.05, help="rad (m) kept from the soft limits (default 0.05)")
    cmd.add_argument("--settle", type=float, default=0.3, help="s dropped at each segment's start (default 0.3)")
    cmd.add_argument(
        "--real-time",
        action="store_true",
        help="pace on the wall clock even on a sim-clock config (default: sim"
        " clock configs run as fast as they can, others in real time)",
    )
    where = cmd.add_mutually_exclusive_group()
    where.add_argument("--write", action="store_true", help="write the config file itself (default: a copy)")
    where.add_argument("--output", metavar="FILE", help="write the copy here (default: <config>.identified.yaml)")
    cmd.set_defaults(func=_cmd_identify)
