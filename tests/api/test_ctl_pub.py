"""``hild ctl pub``: streams numbers and expressions of ``t`` to a controller input, refuses what the daemon would
drop before sending, stops on the daemon's drop warning, and leaves the joints to hold when it stops.

Assertions are on what was received (joint states, events, the summary's counts), with generous bounds; none on
how long anything took.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import threading
from typing import Any

import pytest

from hild.api.client import HildClient
from hild.api.ctl import EXIT_OK, EXIT_SERVICE
from hild.api.pub import check_rate
from hild.api.stream_inputs import StreamInputError, resolve
from tests.api.conftest import ROBOT, WAIT, Daemon
from tests.api.test_ctl import ctl, parse
from tests.conftest import REPO
from tests.helpers import wait_for

AMPLITUDE = 0.2
SINE = f"{AMPLITUDE}*sin(2*pi*0.5*t)"  # 0.63 rad/s at most: the 2 rad/s slew limit never shapes it, even if the
# lockstep clock ran at a third of wall time


def fwd(state: str = "active", kind: str = "forward_command") -> dict[str, Any]:
    return {"name": "fwd", "type": kind, "state": state, "claimed": ["a/position", "b/position", "c/position"]}


# ---- what the input takes (no daemon) -----------------------------------------------------------------------------
def test_resolve_finds_the_only_streamed_input_and_its_joints() -> None:
    target = resolve([fwd()], "fwd", None, 3)
    assert (target.input, target.field, target.joints) == ("commands", "values", ("a", "b", "c"))
    assert target.payload([1.0, 2.0, 3.0]) == {"values": [1.0, 2.0, 3.0]}
    servo = {"name": "servo", "type": "servo", "state": "active", "claimed": ["a/position", "a/velocity", "b/position"]}
    target = resolve([servo], "servo", "target", 2)
    assert (target.input, target.field, target.joints) == ("target", "positions", ("a", "b"))


@pytest.mark.parametrize(
    ("controllers", "name", "input_name", "count", "reason"),
    [
        ([fwd()], "nope", None, 3, "no controller 'nope' (controllers: fwd (forward_command))"),
        ([fwd("inactive")], "fwd", None, 3, "controller 'fwd' is inactive, not active"),
        ([fwd()], "fwd", None, 2, "controller 'fwd' takes 3 values on commands, one per joint (a, b, c); given 2"),
        ([fwd()], "fwd", "target", 3, "controller 'fwd' (forward_command) has no input 'target' (inputs: commands)"),
        ([fwd(kind="joint_trajectory")], "fwd", None, 3, "has no streamed input hild ctl pub knows"),
    ],
)
def test_resolve_refuses_what_the_daemon_would_drop(
    controllers: list[dict[str, Any]], name: str, input_name: str | None, count: int, reason: str
) -> None:
    with pytest.raises(StreamInputError) as refused:
        resolve(controllers, name, input_name, count)
    assert reason in str(refused.value)


@pytest.mark.parametrize(
    ("rate", "duration", "reason"),
    [
        (0.0, None, "--rate 0 Hz is outside"),
        (-50.0, None, "--rate -50 Hz is outside"),
        (math.nan, None, "--rate nan Hz is outside"),
        (1e6, None, "--rate 1e+06 Hz is outside"),
        (2.0, None, "--rate 2 Hz is outside"),  # slower than a 0.5 s command_timeout allows
        (50.0, 0.0, "--duration 0 must be"),
        (50.0, math.inf, "--duration inf must be"),
    ],
)
def test_silly_rates_and_durations_are_refused(rate: float, duration: float | None, reason: str) -> None:
    with pytest.raises(ValueError) as refused:
        check_rate(rate, duration)
    assert str(refused.value).startswith(reason)


def test_a_value_starting_with_a_minus_goes_after_double_dash() -> None:
    args = parse("pub", "fwd", "--rate", "100", "--", "-0.2*(t > 1)", "-1.6", "0")
    assert (args.controller, args.values, args.rate) == ("fwd", ["-0.2*(t > 1)", "-1.6", "0"], 100.0)


# ---- refusals before anything is sent ---------------------------------------------------------------------------
def dropped(daemon: Daemon) -> list[dict[str, Any]]:
    return daemon.events_with("dropped command on")


def test_an_inactive_controller_is_refused_and_nothing_is_sent(
    daemon: Daemon, capsys: pytest.CaptureFixture[str]
) -> None:
    assert ctl(daemon, "pub", "fwd", "0", "0", "0", "--duration", "1") == EXIT_SERVICE
    assert "controller 'fwd' is inactive, not active" in capsys.readouterr().err
    assert ctl(daemon, "--json", "pub", "fwd", "0", "0", "0") == EXIT_SERVICE
    reply = json.loads(capsys.readouterr().out)
    assert reply["ok"] is False and "hild ctl switch --activate fwd" in reply["error"]
    assert dropped(daemon) == []  # a sample sent to an inactive controller is dropped with this warning


@pytest.mark.parametrize(
    ("values", "reason"),
    [
        (["0", "0"], "takes 3 values on commands, one per joint (a, b, c); given 2"),
        (["__import__('os').system('true')", "0", "0"], "value 1: "),
        (["0", "t.__class__", "0"], "value 2: 't.__class__': attribute access not allowed"),
        (["0", "0", "9**9**9"], "value 3: '9**9**9' at t=0 overflows a float"),
        (["0", "0", "1/t"], "value 3: '1/t' at t=0: float division by zero"),
        (["0", "0", "speed*t"], "unknown name 'speed'"),
    ],
)
def test_bad_values_are_refused_before_sending(
    daemon: Daemon, client: HildClient, capsys: pytest.CaptureFixture[str], values: list[str], reason: str
) -> None:
    client.switch(activate=["fwd"])
    assert ctl(daemon, "pub", "fwd", *values) == EXIT_SERVICE
    err = capsys.readouterr().err
    assert err.startswith("hild ctl: pub: ") and reason in err
    assert dropped(daemon) == [] and client.status()["joints"][0]["mode"] == "hold"


def test_a_silly_rate_is_refused(daemon: Daemon, client: HildClient, capsys: pytest.CaptureFixture[str]) -> None:
    client.switch(activate=["fwd"])
    assert ctl(daemon, "pub", "fwd", "0", "0", "0", "--rate", "0") == EXIT_SERVICE
    assert "--rate 0 Hz is outside 5–1000 Hz" in capsys.readouterr().err


# ---- streaming --------------------------------------------------------------------------------------------------
class JointStates:
    """Every joint_states sample received, kept by joint name."""

    def __init__(self, client: HildClient) -> None:
        self.samples: list[dict[str, float]] = []
        self._lock = threading.Lock()
        self._subscription = client.subscribe("joint_states", self._keep)

    def _keep(self, message: dict[str, Any]) -> None:
        with self._lock:
            self.samples.append(dict(zip(message["name"], message["position"], strict=True)))

    def of(self, joint: str) -> list[float]:
        with self._lock:
            return [s[joint] for s in self.samples]

    def close(self) -> None:
        self._subscription.close()


def joint_modes(client: HildClient) -> dict[str, str]:
    return {j["name"]: j["mode"] for j in client.status()["joints"]}


def assert_holds_after_the_stream(daemon: Daemon, client: HildClient, last: dict[str, float]) -> None:
    """The controller times out, the supervisor holds every joint where it was, and it stays there."""
    wait_for(lambda: daemon.events_with("no command for 0.5 s: joints return to hold"), WAIT, "fwd's timeout")
    wait_for(lambda: set(joint_modes(client).values()) == {"hold"}, WAIT, "every joint in hold")
    held = client.next_message("joint_states")
    for joint, value in last.items():
        assert held["position"][held["name"].index(joint)] == pytest.approx(value, abs=0.02)
    states = JointStates(client)
    try:
        wait_for(lambda: len(states.samples) >= 20, WAIT, "20 joint states in hold")
        for joint, value in last.items():
            assert max(abs(p - value) for p in states.of(joint)) < 0.02
    finally:
        states.close()


def test_pub_streams_a_sine_that_the_joint_follows_then_the_joints_hold(
    daemon: Daemon, client: HildClient, capsys: pytest.CaptureFixture[str]
) -> None:
    client.switch(activate=["fwd"])
    states = JointStates(client)
    try:
        assert ctl(daemon, "--json", "pub", "fwd", SINE, "-0.1", "0.2", "--duration", "2", "--rate", "50") == EXIT_OK
    finally:
        states.close()
    summary = json.loads(capsys.readouterr().out)
    assert summary["ok"] is True and summary["error"] is None and summary["stopped"] == "duration"
    assert (summary["controller"], summary["input"]) == ("fwd", "commands")
    assert summary["sent"] + summary["skipped"] == 100 and summary["sent"] >= 50  # every due sample, or skipped late
    a = states.of("a")
    assert max(a) > 0.8 * AMPLITUDE and min(a) < -0.8 * AMPLITUDE  # a full period of the sine reached the joint
    assert all(abs(p) <= AMPLITUDE + 0.01 for p in a)  # and nothing else (0.1 at the start)
    assert states.of("b")[-1] == pytest.approx(-0.1, abs=1e-6) and states.of("c")[-1] == pytest.approx(0.2, abs=1e-6)
    assert dropped(daemon) == []
    last_a = AMPLITUDE * math.sin(2 * math.pi * 0.5 * 99 / 50)  # the last sample is always sent: t = 1.98
    assert_holds_after_the_stream(daemon, client, {"a": last_a, "b": -0.1, "c": 0.2})


def test_pub_stops_when_the_daemon_drops_a_sample_outside_the_limits(
    daemon: Daemon, client: HildClient, capsys: pytest.CaptureFixture[str]
) -> None:
    client.switch(activate=["fwd_a"])
    # joint a starts at 0.1 (tests/api/conftest.py), so the first samples hold it where it is
    assert ctl(daemon, "--json", "pub", "fwd_a", "0.1 if t < 0.5 else 1.5", "--duration", "30") == EXIT_SERVICE
    summary = json.loads(capsys.readouterr().out)
    assert summary["ok"] is False and summary["stopped"] == "refused"
    assert "dropped command on hild/mock3/ctrl/fwd_a/commands: position 1.5 for a is outside" in summary["error"]
    assert summary["sent"] >= 1
    assert_holds_after_the_stream(daemon, client, {"a": 0.1})


def test_pub_reports_a_controller_deactivated_under_it(
    daemon: Daemon, client: HildClient, capsys: pytest.CaptureFixture[str]
) -> None:
    client.switch(activate=["fwd_a"])
    codes: list[int] = []
    streaming = threading.Thread(target=lambda: codes.append(ctl(daemon, "pub", "fwd_a", "0.4", "--duration", "30")))
    streaming.start()
    try:
        wait_for(lambda: joint_modes(client)["a"] == "controlled", WAIT, "pub to take joint a")
        client.switch(deactivate=["fwd_a"])
    finally:
        streaming.join(WAIT)
    assert codes == [EXIT_SERVICE]
    captured = capsys.readouterr()
    assert "(refused)" in captured.out
    assert "hild ctl: pub: the daemon dropped a sample: dropped command on" in captured.err
    assert "controller fwd_a is not active" in captured.err


EXIT_WAIT = 60.0  # s for pub to close its Zenoh session and exit after SIGINT on a loaded machine
# `hild.cli` as a terminal's foreground command starts: SIGINT at Python's default handler. A test run started as a
# background job of a non-interactive shell inherits SIGINT ignored, and so did pub: it never saw its Ctrl-C (the
# "hang" of the loaded rounds: /proc/<pid>/status SigIgn had SIGINT set in pytest and in pub).
AS_IN_A_TERMINAL = (
    "import runpy, signal; signal.signal(signal.SIGINT, signal.default_int_handler); "
    "runpy.run_module('hild.cli', run_name='__main__')"
)


def test_ctrl_c_stops_pub_cleanly_and_the_joints_hold(daemon: Daemon, client: HildClient) -> None:
    """The real command in its own process, interrupted as a terminal does: SIGINT, exit 0, a summary."""
    client.switch(activate=["fwd"])
    command = [sys.executable, "-c", AS_IN_A_TERMINAL, "ctl", "--connect", daemon.endpoint, "--robot", ROBOT]
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    states = JointStates(client)
    process = subprocess.Popen(
        [*command, "pub", "fwd", "0.25", "0.1", "-0.3", "--rate", "100"],
        cwd=REPO,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        reached = lambda: any(abs(p - 0.25) < 1e-6 for p in states.of("a"))  # noqa: E731
        wait_for(lambda: reached() and joint_modes(client)["a"] == "controlled", 60, "pub's samples")
        process.send_signal(signal.SIGINT)
        out, err = process.communicate(timeout=EXIT_WAIT)
    finally:
        states.close()
        if process.poll() is None:
            process.kill()
            process.wait()
    assert process.returncode == EXIT_OK, err
    assert "(interrupted)" in out and "fwd's joints hold after its command_timeout" in out
    assert "Traceback" not in err and "streaming to hild/mock3/ctrl/fwd/commands at 100 Hz until Ctrl-C" in err
    assert dropped(daemon) == []
    assert_holds_after_the_stream(daemon, client, {"a": 0.25, "b": 0.1, "c": -0.3})
