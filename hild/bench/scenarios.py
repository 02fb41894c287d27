"""The scenarios: which robot, at which rate, doing what — each run as the real daemon in a process of its own.

Every scenario carries the same work: a joint_trajectory controller repeating the standard trajectory on every
joint, the joint_state_broadcaster at 100 Hz, and telemetry recording to a file in a temporary directory.

* ``mock6`` — configs/arm6_twin.yaml with its hardware swapped for the mock driver (same joints, controllers and
  gravity model): hild's own cost without physics.
* ``twin6`` — configs/arm6_twin.yaml, ``substeps`` set so the physics step stays 1 ms at either rate.
* ``can3``, ``can6`` — Damiao motors emulated in the daemon's process by the ``mit_can`` bench rig
  (``hild.bench.rigs``), on a python-can virtual channel (served to the cycle process over loopback when the cycle
  runs there: the drives then run in a process of their own, ``hild.bench.rigs.can_process``, or with
  ``--stock-can-bridge`` as before behind python-can-remote's stock server, ``hild.bench.rigs.can_bridge``); these
  also measure the command → frame and reply → sample latencies.
* ``cia402_6@500`` — six CANopen CiA 402 drives in CSP (``hild.bench.rigs.cia402``, the emulated drive of
  ``hild emulate``) on one 1 Mbit/s bus at 500 Hz, hild producing SYNC: the cycle and the bus figures (the load
  ``hild check`` computes from the PDO layout beside the frames that crossed), plus the same latencies as can6.
* ``can6@1000-virtual`` — can6 at 1 kHz with the cycle a thread of the daemon and the emulated drives on the
  in-process virtual bus (no loopback bridge, whatever the layout of the others): the command → frame figure of
  hild's own path, reported beside can6@1000's across the bridge (docs/performance.md, "The command path: the
  195 ms finding").
* ``twin6@500-nospin``, ``can6@500-nospin`` — the same at 500 Hz with ``spin_us: 0`` (the cycle sleeps to its
  deadline): the whole daemon's CPU when the cycle does not spin.
* ``interference`` — twin6 at 1 kHz with ``joint_trajectory_arm`` (the first three joints, trajectory) and
  ``servo_wrist`` (the last three, streamed targets) active together, windows interleaved between no extra clients,
  two pollers (``srv/status`` and ``srv/list_controllers`` at 200 Hz each), the pollers plus a 1 kHz servo
  stream, and the servo stream alone (what a target every cycle costs the cycle); then the same three loads aimed
  at a decoy daemon in another process
  (``hild.bench.probes.zenoh_loopback.Decoy``), which load the machine alike while nothing reaches the daemon, so a
  rise can be split into the machine's part and hild's; and an observer flooding ``srv/status`` with 1 MiB queries
  as fast as they are answered (``flood``), while the trajectory's goals keep coming (their acceptance time is the
  operator's view). The servo gets joints of its own so the trajectory keeps running in every window.

Every scenario runs with ``realtime.cycle_process: true`` unless ``Settings.cycle_process`` is off
(``hild bench --one-process``): the same scenarios, the cycle a thread of the daemon as before [rt-split].

The bench process is the Zenoh client (trajectories, probes, pollers, the stream); the daemon's process answers
its control requests (``hild.bench.host``).
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import random
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hild.api.client import HildClient, HildError, HildUnreachable
from hild.bench.children import LoggedChild, end_child, free_endpoint
from hild.bench.daemon import CONFIGS, START_TIMEOUT
from hild.bench.latency import SampleLog, match_commands, match_replies, send_probes
from hild.bench.load import (
    FLOOD_BYTES,
    FLOOD_IN_FLIGHT,
    Counter,
    Flooder,
    Paced,
    Poller,
    ServoStreamer,
    TrajectoryKeeper,
)
from hild.bench.probes.zenoh_loopback import Decoy
from hild.bench.report import loop_figures, rise_pct, summarize_ns
from hild.bench.rigs import rig_class
from hild.config.documents import load_document
from hild.config.loader import load_config
from hild.crossing.stats import percentiles

ARM6 = CONFIGS / "arm6_twin.yaml"
PHYSICS_STEP = 0.001  # s: the twin's physics step at every rate
BROADCASTER = "joint_state_broadcaster"
JTC = "joint_trajectory"
FORWARD = "forward_position"
JTC_ARM = "joint_trajectory_arm"
SERVO_WRIST = "servo_wrist"
CAN_RIGS = {"can": "mit_can", "cia402": "cia402"}  # a scenario's kind → the rig emulating its drives
REQUEST_TIMEOUT = 30.0  # s for one host request
PROBE_DELTA_LSB = 3  # the command probe's step in position LSBs: clear of quantization, far below one cycle's slew
PROBE_TOL_LSB = 1.5
SETTLE_S = 0.3  # s between starting interference clients and opening the window
POLL_RATE = 200.0
SERVO_RATE = 1000.0
NOSPIN = "-nospin"
VIRTUAL = "-virtual"


@dataclass(frozen=True)
class Scenario:
    base: str  # mock6, twin6, can3, can6, cia402_6
    kind: str  # mock, twin, can (MIT drives), cia402 (CANopen CiA 402 drives)
    joints: int
    rate: float
    spin_us: int | None = None  # realtime.spin_us for this scenario (None: the config's or --spin-us)
    virtual_bus: bool = False  # the cycle a thread of the daemon, the drives on its in-process virtual bus

    @property
    def rig(self) -> str | None:
        """The bench rig that emulates this scenario's drives (``hild.bench.rigs``), None without CAN."""
        return CAN_RIGS.get(self.kind)

    @property
    def name(self) -> str:
        return (
            f"{self.base}@{self.rate:g}" + (NOSPIN if self.spin_us == 0 else "") + (VIRTUAL if self.virtual_bus else "")
        )


ARMS = (("mock6", "mock", 6), ("twin6", "twin", 6), ("can3", "can", 3), ("can6", "can", 6))
SCENARIOS = (
    *(Scenario(base, kind, joints, rate) for base, kind, joints in ARMS for rate in (500.0, 1000.0)),
    Scenario("twin6", "twin", 6, 500.0, spin_us=0),
    Scenario("can6", "can", 6, 500.0, spin_us=0),
    Scenario("can6", "can", 6, 1000.0, virtual_bus=True),
    Scenario("cia402_6", "cia402", 6, 500.0),
)
INTERFERENCE = Scenario("twin6", "twin", 6, 1000.0)


@dataclass
class Settings:
    """How long and how much; ``quick`` shortens everything (results are then indicative only)."""

    seconds: float = 10.0
    warmup: float = 1.0
    latency_probes: int = 300
    probe_gap: tuple[float, float] = (0.004, 0.012)
    interference_rounds: int = 2
    interference_seconds: float = 5.0
    floor_seconds: float = 5.0
    zenoh_pings: int = 2000
    zenoh_puts: int = 2000
    can_frames: int = 20_000
    mj_steps: int = 5000
    priority: int | None = None
    spin_us: int | None = None
    cpu_dma_latency_us: int | None = None
    seed: int = 1
    quick: bool = False
    cycle_process: bool = True  # realtime.cycle_process for every scenario (False: hild bench --one-process)
    can_remote: bool = False  # serve the emulated CAN channels over loopback even with the cycle in the daemon
    stock_bridge: bool = False  # bridged CAN drives in the daemon's process behind the stock server (before [teleop])
    cycle_cpu: int | None = None  # the cycle (and the floor's empty thread) on this CPU, everything else off it
    soak_seconds: float | None = None  # the soak's length when --seconds gives it (hild.bench.cli)

    @classmethod
    def make(
        cls,
        quick: bool,
        seconds: float | None,
        priority: int | None,
        spin_us: int | None = None,
        cpu_dma_latency_us: int | None = None,
        *,
        cycle_process: bool = True,
        can_remote: bool = False,
        cycle_cpu: int | None = None,
        stock_bridge: bool = False,
    ) -> Settings:
        if quick:
            s = cls(
                seconds=1.5,
                warmup=0.5,
                latency_probes=40,
                interference_rounds=1,
                interference_seconds=1.5,
                floor_seconds=1.0,
                zenoh_pings=300,
                zenoh_puts=300,
                can_frames=3000,
                mj_steps=1000,
                quick=True,
            )
        else:
            s = cls()
        if seconds is not None:
            s.seconds = s.soak_seconds = seconds
            s.interference_seconds = seconds if quick else max(0.5, seconds / 2)
            s.floor_seconds = min(s.floor_seconds, max(0.5, seconds))
        s.priority = priority
        s.spin_us = spin_us
        s.cpu_dma_latency_us = cpu_dma_latency_us
        s.cycle_process = cycle_process
        s.can_remote = can_remote
        s.stock_bridge = stock_bridge
        s.cycle_cpu = cycle_cpu
        return s

    @property
    def bridged(self) -> bool:
        """Whether CAN scenarios serve their emulated channels over loopback (a virtual channel stays in its
        process, so always when the cycle has a process of its own)."""
        return self.cycle_process or self.can_remote

    def realtime(self) -> dict[str, Any]:
        """The ``realtime:`` settings given on the command line, for every cycle thread, floor included."""
        given: dict[str, Any] = {
            "priority": self.priority,
            "spin_us": self.spin_us,
            "cpu_dma_latency_us": self.cpu_dma_latency_us,
        }
        if self.cycle_cpu is not None:
            given["cpu_affinity"] = [self.cycle_cpu]
            given["client_cpu_affinity"] = other_cpus(self.cycle_cpu)
        return {k: v for k, v in given.items() if v is not None}


def other_cpus(cpu: int) -> list[int]:
    """The CPUs this process may use, but ``cpu``: where the client domain and the bench's own load go."""
    return sorted(os.sched_getaffinity(0) - {cpu})


# ---- configs -----------------------------------------------------------------------------------------------------
def arm6_config(kind: str, rate: float, *, interference: bool = False) -> dict[str, Any]:
    """configs/arm6_twin.yaml at ``rate``: the twin (physics step 1 ms) or the same arm on the mock driver."""
    data: dict[str, Any] = load_document(ARM6)
    data["update_rate"] = rate
    data["robot"]["model"] = str(CONFIGS / data["robot"]["model"])
    twin = data["hardware"]["twin"]
    if kind == "twin":
        twin["params"]["model"] = str(CONFIGS / twin["params"]["model"])
        twin["params"]["substeps"] = max(1, round(1.0 / (rate * PHYSICS_STEP)))
    elif kind == "mock":
        data["hardware"] = {"arm": {"driver": "mock", "params": {}, "joints": twin["joints"]}}
    else:
        raise ValueError(f"arm6 comes as twin or mock, not {kind!r}")
    data.pop("zenoh", None)  # the endpoint comes from the command line
    if interference:
        joints = list(data["joints"])
        data["controllers"][JTC_ARM] = {
            "type": "joint_trajectory",
            "params": {"joints": joints[:3], "command_interfaces": ["position", "velocity"]},
        }
        data["controllers"][SERVO_WRIST] = {"type": "servo", "params": {"joints": joints[3:], "command_timeout": 0.25}}
    return data


def scenario_config(
    scenario: Scenario,
    workdir: Path,
    settings: Settings,
    *,
    interference: bool = False,
    overrides: dict[str, Any] | None = None,
) -> tuple[dict[str, Any], str | None, float]:
    """(config document, rig name or None, trajectory scale) with telemetry to a file in ``workdir``; ``overrides``
    replace top-level sections (e.g. ``recording``)."""
    rig: str | None = None
    scale = 1.0
    if scenario.rig is not None:
        rig = scenario.rig
        cls = rig_class(rig)
        data = cls.robot_config(scenario.joints, scenario.rate)
        scale = float(cls.trajectory_scale)
    else:
        data = arm6_config(scenario.kind, scenario.rate, interference=interference)
    tag = scenario.name.replace("@", "_") + ("_interference" if interference else "")
    data["telemetry"] = {"enabled": True, "sinks": [{"kind": "file", "path": str(workdir / f"{tag}.rrd")}]}
    realtime = data.setdefault("realtime", {})
    realtime.update(settings.realtime())
    if scenario.spin_us is not None:
        realtime["spin_us"] = scenario.spin_us
    realtime["cycle_process"] = settings.cycle_process and not scenario.virtual_bus
    data.update(overrides or {})
    return data, rig, scale


# ---- the daemon process ------------------------------------------------------------------------------------------
class HostError(RuntimeError):
    pass


class HostProcess(LoggedChild):
    """A ``hild.bench.host`` child: the daemon of one scenario, plus its JSON-lines control channel."""

    def __init__(self, config: Path, log: Path, rig: str | None, bridge: bool = False, stock: bool = False) -> None:
        self.endpoint = free_endpoint()
        self.config = config
        self.cycle_pid: int | None = None
        self.bridged = bool(rig and bridge)
        self.stock_bridge = self.bridged and stock
        command = [sys.executable, "-m", "hild.bench.host", str(config), "--listen", self.endpoint]
        command += (["--rig", rig] if rig else []) + (["--can-bridge"] if self.bridged else [])
        command += ["--stock-bridge"] if self.stock_bridge else []
        super().__init__(command, log, control=True)
        self._lines: queue.Queue[str | None] = queue.Queue()
        threading.Thread(target=self._read, name="bench-host-reader", daemon=True).start()

    def _read(self) -> None:
        assert self.process.stdout is not None
        for line in self.process.stdout:
            self._lines.put(line)
        self._lines.put(None)

    def _next(self, timeout: float) -> dict[str, Any]:
        try:
            line = self._lines.get(timeout=timeout)
        except queue.Empty:
            raise HostError(f"no answer from the daemon process within {timeout:g} s{self.log_tail()}") from None
        if line is None:
            raise HostError(f"the daemon process ended (exit {self.process.poll()}){self.log_tail()}")
        message: dict[str, Any] = json.loads(line)
        return message

    def wait_ready(self) -> dict[str, Any]:
        message = self._next(START_TIMEOUT)
        if message.get("event") != "ready":
            raise HostError(f"the daemon did not start: {message.get('error', message)}{self.log_tail()}")
        self.cycle_pid = message.get("cycle_pid")
        return message

    def request(self, op: str, timeout: float = REQUEST_TIMEOUT, **fields: Any) -> dict[str, Any]:
        assert self.process.stdin is not None
        try:
            self.process.stdin.write(json.dumps({"op": op, **fields}) + "\n")
            self.process.stdin.flush()
        except (BrokenPipeError, OSError) as exc:
            raise HostError(f"the daemon process is gone ({exc}){self.log_tail()}") from None
        reply = self._next(timeout)
        if not reply.get("ok"):
            raise HostError(f"{op}: {reply.get('error', reply)}")
        return reply

    def close(self) -> int | None:
        """Ask the host to stop the daemon, wait for it (kill it after 30 s); its exit code."""
        if self.process.poll() is None:
            with contextlib.suppress(HostError):
                self.request("stop", timeout=5.0)
        end_child(self.process, 30.0)
        return self.process.returncode


def connect(endpoint: str, robot: str) -> HildClient:
    deadline = time.monotonic() + 10.0
    while True:
        try:
            client = HildClient(robot, [endpoint], timeout=5.0)
            client.wait_alive(10.0)
            return client
        except HildUnreachable:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)


@dataclass
class Session:
    """One scenario's daemon process and the bench's client of it."""

    scenario: Scenario
    host: HostProcess
    client: HildClient
    robot: str
    joints: list[str]
    home: list[float]
    scale: float
    events: Counter = field(default_factory=lambda: Counter(lambda m: str(m.get("level"))))
    cleanups: list[Callable[[], Any]] = field(default_factory=list)

    def window(self, seconds: float) -> dict[str, Any]:
        self.host.request("window")
        time.sleep(seconds)
        return self.host.request("collect")

    def keeper(self, controller: str, joints: list[str], start: list[float]) -> TrajectoryKeeper:
        keeper = TrajectoryKeeper([self.host.endpoint], self.robot, controller, joints, start, self.scale)
        keeper.start()
        self.cleanups.append(keeper.stop)
        return keeper


@contextlib.contextmanager
def open_session(
    scenario: Scenario,
    workdir: Path,
    settings: Settings,
    *,
    interference: bool = False,
    overrides: dict[str, Any] | None = None,
) -> Any:
    data, rig, scale = scenario_config(scenario, workdir, settings, interference=interference, overrides=overrides)
    tag = scenario.name.replace("@", "_") + ("_interference" if interference else "")
    path = workdir / f"{tag}.yaml"
    path.write_text(json.dumps(data, indent=1))  # JSON is YAML
    bridged = settings.bridged and not scenario.virtual_bus
    host = HostProcess(path, workdir / f"{tag}.log", rig, bridged, settings.stock_bridge)
    client = None
    session = None
    try:
        ready = host.wait_ready()
        robot = str(ready["robot"])
        client = connect(host.endpoint, robot)
        state = client.next_message("joint_states", timeout=10.0)
        session = Session(scenario, host, client, robot, list(state["name"]), list(state["position"]), scale)
        subscription = client.subscribe("events", session.events)
        session.cleanups.append(subscription.close)
        yield session
    finally:
        if session is not None:
            for cleanup in reversed(session.cleanups):
                with contextlib.suppress(Exception):
                    cleanup()
        code = host.close()
        if client is not None:
            client.close()
        if code not in (0, None) and session is not None:
            raise HostError(f"{scenario.name}: the daemon exited with {code}{host.log_tail()}")


# ---- measurements ----------------------------------------------------------------------------------------------
def run_scenario(scenario: Scenario, workdir: Path, settings: Settings) -> tuple[dict[str, Any], dict[str, Any] | None]:
    """The scenario's cycle figures (and, for CAN, its latencies)."""
    with open_session(scenario, workdir, settings) as s:
        s.client.switch(activate=[JTC])
        keeper = s.keeper(JTC, s.joints, s.home)
        time.sleep(settings.warmup)
        window = s.window(settings.seconds)
        latency = None
        if scenario.rig is not None and settings.latency_probes > 0:
            keeper.stopping.set()
            s.client.switch(activate=[FORWARD], deactivate=[JTC])  # aborts the goal in flight
            keeper.stop()
            with contextlib.suppress(HildError):  # a fault latched after the window would hold the probed joint
                s.client.reset()
            latency = measure_latency(s, settings)
        keeper.stop()
        row = {
            "name": scenario.name,
            "base": scenario.base,
            "kind": scenario.kind,
            "joints": scenario.joints,
            "rate_hz": scenario.rate,
            **loop_figures(window["cycles"], window["overruns"], window["duration_ns"], window["period_error_ns"]),
            "seconds": window["seconds"],
            "lost": window["lost"],
            "cycle_process": window["cycle_process"],
            "cycle_python_threads": window["cycle_python_threads"],
            "can_bus": can_bus(s.host) if scenario.rig is not None else None,
            "can_bridge": can_bridge(s.host) if scenario.rig is not None else None,
            "bus": bus_figures(s.host.config, window["counters"], window["seconds"]) if scenario.rig else None,
            "cpu": window["cpu"],
            "goals": dict(keeper.results),
            "mode": window["mode"],
            "faults": window["faults"],
            "counters": window["counters"],
            "telemetry_dropped_rows": window["telemetry_dropped_rows"],
            "events": dict(s.events.counts),
            "realtime": window["realtime"],
            "notes": notes(scenario, window, keeper, s.events),
        }
    return row, latency


def notes(scenario: Scenario, window: dict[str, Any], keeper: TrajectoryKeeper, events: Counter) -> list[str]:
    out = list(window.get("window_notes", []))
    if window["faults"]:
        out.append(f"faults: {'; '.join(window['faults'])}")
    bad = {k: v for k, v in keeper.results.items() if k not in ("sent", "succeeded", "ended at stop")}
    if bad:
        out.append(f"trajectory results other than succeeded: {bad}" + (f" ({keeper.error})" if keeper.error else ""))
    for message in events.last[:3]:
        out.append(f"{message.get('level')} {message.get('source')}: {message.get('message')}")
    return out


def measure_latency(s: Session, settings: Settings) -> dict[str, Any]:
    """Command → frame and reply → sample on a CAN scenario, with forward_position active."""
    state = s.client.next_message("joint_states", timeout=5.0)
    base = list(state["position"])
    info = s.host.request("listen", on=True)
    lsb = float(info["lsb"])
    log = SampleLog()
    subscription = s.client.subscribe("joint_states", log)
    try:
        probes = send_probes(
            s.client,
            FORWARD,
            base,
            PROBE_DELTA_LSB * lsb,
            settings.latency_probes,
            settings.probe_gap,
            random.Random(settings.seed),
        )
        time.sleep(0.05)
    finally:
        subscription.close()
    clock = s.host.request("clock")
    frames = s.host.request("listen", on=False, timeout=120.0)
    tol = PROBE_TOL_LSB * lsb
    command, ambiguous = match_commands(probes, frames["command"], tol)
    history = clock.get("lag_history", [])
    reply, unmatched = match_replies(log.samples, frames["reply"], int(clock["start_ns"]), tol, history)
    return {
        "scenario": s.scenario.name,
        "base": s.scenario.base,
        "rate_hz": s.scenario.rate,
        "joint": frames["joint"],
        "probes": len(probes),
        "ambiguous_probes": ambiguous,
        "probe_step_rad": round(PROBE_DELTA_LSB * lsb, 6),
        "command_to_frame_us": summarize_ns(command),
        "samples": len(log.samples),
        "unmatched_samples": unmatched,
        "reply_to_joint_states_us": summarize_ns(reply),
        "broadcaster_rate_hz": 100.0,
        "clock_spread_us": round(clock["spread_ns"] / 1e3, 1),
        "clock_method": clock.get("method", "cycle"),
        "control_clock_lag_us": round(history[-1][1] / 1e3, 1) if history else 0.0,
        "can_bus": can_bus(s.host),
        "can_bridge": can_bridge(s.host),
    }


def bus_figures(config: Path, counters: dict[str, int], seconds: float) -> dict[str, Any]:
    """The CAN buses' load: what ``hild check`` computes from the drivers' frame layouts (worst case, bit stuffing
    included) beside what crossed the emulated buses in the window (the same worst-case bits, every frame both
    ways), each in % of the summed bitrates."""
    loaded = load_config(config)
    check, capacity = 0.0, 0.0
    for name, hw in loaded.config.hardware.items():
        cls, params = loaded.driver_classes[name], loaded.driver_params[name]
        for usage in cls.bus_usage(params, list(hw.joints), loaded.config.update_rate):
            check += usage.bits_per_second
            capacity += usage.capacity
    if capacity <= 0.0:
        return {}
    frames, bits = counters.get("bus frames", 0), counters.get("bus bits", 0)
    return {
        "buses_bitrate": capacity,
        "check_load_pct": round(100.0 * check / capacity, 1),
        "measured_load_pct": round(100.0 * bits / seconds / capacity, 1) if seconds > 0 else None,
        "frames_per_s": round(frames / seconds) if seconds > 0 else None,
    }


def can_bus(host: HostProcess) -> str:
    """Where the cycle's CAN frames go: the in-process virtual bus, or a loopback bridge to the emulated drives."""
    return "remote (loopback bridge)" if host.bridged else "virtual"


def can_bridge(host: HostProcess) -> str | None:
    """Who serves the loopback bridge: the drives' own loop in the rig process (``hild.bench.rigs.can_process``),
    or, with ``--stock-can-bridge``, python-can-remote's stock server beside the daemon (before [teleop])."""
    if not host.bridged:
        return None
    return "stock server in the daemon's process" if host.stock_bridge else "rig process"


INTERFERENCE_CONDITIONS = (
    "baseline",
    "polling",
    "polling+servo",
    "servo",
    "decoy polling",
    "decoy polling+servo",
    "decoy servo",
    "flood",
)
DECOY = "decoy "  # the condition's clients load the machine the same way but talk to a decoy daemon


def interference_clients(condition: str, s: Session, decoy: Decoy) -> list[Paced | Flooder]:
    endpoint = [decoy.endpoint if condition.startswith(DECOY) else s.host.endpoint]
    load = condition.removeprefix(DECOY)
    clients: list[Paced | Flooder] = []
    if load == "flood":
        clients.append(Flooder(endpoint, s.robot, "status"))
    if load in ("polling", "polling+servo"):
        clients += [
            Poller(endpoint, s.robot, "status", POLL_RATE),
            Poller(endpoint, s.robot, "list_controllers", POLL_RATE),
        ]
    if load in ("polling+servo", "servo"):
        clients.append(ServoStreamer(endpoint, s.robot, SERVO_WRIST, s.home[3:], SERVO_RATE))
    return clients


def open_decoy(s: Session, workdir: Path) -> Decoy:
    """A decoy answering with what the daemon answers now (docs/performance.md, "Interference")."""
    replies = {name: json.dumps(s.client.call(name)) for name in ("status", "list_controllers")}
    return Decoy(s.robot, replies, [(SERVO_WRIST, "target")], str(workdir / "decoy.json"))


def run_interference(workdir: Path, settings: Settings) -> dict[str, Any]:
    """Interleaved windows of twin6 @ 1 kHz: no clients, clients on the daemon, the same clients on a decoy."""
    scenario = INTERFERENCE
    merged: dict[str, dict[str, Any]] = {
        c: {"cycles": 0, "overruns": 0, "lost": 0, "duration": [], "period_error": [], "rates": {}, "spans": []}
        for c in INTERFERENCE_CONDITIONS
    }
    with open_session(scenario, workdir, settings, interference=True) as s, open_decoy(s, workdir) as decoy:
        s.client.switch(activate=[JTC_ARM, SERVO_WRIST])
        keeper = s.keeper(JTC_ARM, s.joints[:3], s.home[:3])
        time.sleep(settings.warmup)
        for _ in range(settings.interference_rounds):
            for condition in INTERFERENCE_CONDITIONS:
                clients = interference_clients(condition, s, decoy)
                for c in clients:
                    c.start()
                try:
                    time.sleep(SETTLE_S)
                    opened = time.perf_counter()
                    window = s.window(settings.interference_seconds)
                    closed = time.perf_counter()
                finally:
                    for c in clients:
                        c.stop()
                m = merged[condition]
                m["spans"].append((opened, closed))
                m["cycles"] += window["cycles"]
                m["overruns"] += window["overruns"]
                m["lost"] += window["lost"]
                m["duration"].append(np.asarray(window["duration_ns"], dtype=np.int64))
                m["period_error"].append(np.asarray(window["period_error_ns"], dtype=np.int64))
                for c in clients:
                    m["rates"].setdefault(c.name, []).append(c.achieved_rate)
                    if c.failures:
                        m["rates"].setdefault(c.name + " failures", []).append(c.failures)
    rows = []
    for condition in INTERFERENCE_CONDITIONS:
        m = merged[condition]
        row = {
            "name": condition,
            **loop_figures(
                m["cycles"], m["overruns"], np.concatenate(m["duration"]), np.concatenate(m["period_error"])
            ),
            "lost": m["lost"],
            "clients": ", ".join(f"{k.removeprefix('bench-')} {np.mean(v):.0f}/s" for k, v in m["rates"].items()),
            "goal_accept_ms": accepts_during(keeper.accepts, m["spans"]),
        }
        rows.append(row)
    baseline = rows[0]["duration_us"]["p99"]
    for row in rows:
        row["p99_rise_pct"] = rise_pct(row["duration_us"]["p99"], baseline)
    return {
        "scenario": scenario.name,
        "setup": f"{JTC_ARM} on 3 joints + {SERVO_WRIST} on 3",
        "rounds": settings.interference_rounds,
        "window_s": settings.interference_seconds,
        "poll_rate_hz": POLL_RATE,
        "servo_rate_hz": SERVO_RATE,
        "flood": f"{FLOOD_IN_FLIGHT} × {FLOOD_BYTES >> 20} MiB status queries in flight, each resent when answered",
        "conditions": rows,
    }


def accepts_during(accepts: list[tuple[float, float]], spans: list[tuple[float, float]]) -> dict[str, float]:
    """Acceptance times (ms) of the goals sent inside any of ``spans`` (perf_counter intervals)."""
    inside = [seconds * 1e3 for sent, seconds in accepts if any(a <= sent <= b for a, b in spans)]
    if not inside:
        return {"n": 0}
    figures = percentiles(inside, "ms", to="ms")
    return {"n": len(inside), "p50": figures["p50"], "max": figures["max"]}
