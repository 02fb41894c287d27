"""``hild ctl`` through run_ctl against the test daemon: output, --json, exit codes."""

from __future__ import annotations

import argparse
import json

import pytest

from hild.api.ctl import EXIT_OK, EXIT_SERVICE, EXIT_UNREACHABLE, add_ctl_parser, run_ctl
from tests.api.conftest import ROBOT, Daemon
from tests.helpers import free_endpoint


def parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="hild")
    add_ctl_parser(parser.add_subparsers(dest="command", required=True))
    return parser.parse_args(["ctl", *argv])


def ctl(daemon: Daemon, *argv: str) -> int:
    return run_ctl(parse("--connect", daemon.endpoint, *argv))


def test_status_human(daemon: Daemon, capsys: pytest.CaptureFixture[str]) -> None:
    assert ctl(daemon, "status") == EXIT_OK
    out = capsys.readouterr().out
    assert out.startswith(f"{ROBOT}: HOLD")
    assert "JOINT" in out and "CONTROLLER" in out and "HARDWARE" in out and "fwd_a" in out


def test_status_json_after_the_subcommand(daemon: Daemon, capsys: pytest.CaptureFixture[str]) -> None:
    assert ctl(daemon, "status", "--json", "--robot", ROBOT) == EXIT_OK
    reply = json.loads(capsys.readouterr().out)
    assert reply["ok"] is True and reply["mode"] == "hold"


def test_controllers_interfaces_hardware(daemon: Daemon, capsys: pytest.CaptureFixture[str]) -> None:
    assert ctl(daemon, "controllers") == EXIT_OK
    out = capsys.readouterr().out
    assert "forward_command" in out and "a/position,b/position,c/position" in out
    assert ctl(daemon, "interfaces") == EXIT_OK
    assert "c/effort" in capsys.readouterr().out
    assert ctl(daemon, "--json", "hardware") == EXIT_OK
    assert json.loads(capsys.readouterr().out)["hardware"][0]["driver"] == "mock"


def test_switch_success_and_failure(daemon: Daemon, capsys: pytest.CaptureFixture[str]) -> None:
    assert ctl(daemon, "switch", "--activate", "fwd") == EXIT_OK
    assert "activated ['fwd']" in capsys.readouterr().out
    assert ctl(daemon, "switch", "--activate", "fwd_a") == EXIT_SERVICE
    assert "a/position is claimed by both fwd and fwd_a" in capsys.readouterr().err
    assert ctl(daemon, "--json", "switch", "--activate", "nope") == EXIT_SERVICE
    assert "unknown controller(s) 'nope'" in json.loads(capsys.readouterr().out)["error"]
    assert ctl(daemon, "switch", "--deactivate", "fwd", "--activate", "fwd_a", "nope", "--best-effort") == EXIT_OK
    out = capsys.readouterr().out
    assert "activated ['fwd_a'], deactivated ['fwd']" in out and "nope" in out


def test_estop_and_reset(daemon: Daemon, capsys: pytest.CaptureFixture[str]) -> None:
    assert ctl(daemon, "estop") == EXIT_OK
    assert "e-stop engaged" in capsys.readouterr().out
    assert ctl(daemon, "--json", "status") == EXIT_OK
    assert json.loads(capsys.readouterr().out)["mode"] == "estop"
    assert ctl(daemon, "reset") == EXIT_OK
    assert "cleared ['e-stop']" in capsys.readouterr().out


def test_watch_once_table(daemon: Daemon, capsys: pytest.CaptureFixture[str]) -> None:
    assert ctl(daemon, "watch", "--once") == EXIT_OK
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith(f"{ROBOT}: HOLD") and "cycles" in lines[0]
    header = next(i for i, line in enumerate(lines) if line.startswith("JOINT"))
    assert lines[header].split() == ["JOINT", "MODE", "OWNER", "POSITION", "VELOCITY", "EFFORT", "FAULT"]
    rows = {line.split()[0]: line.split() for line in lines[header + 1 :]}
    assert rows["a"][:4] == ["a", "hold", "-", "+0.1000"]
    assert rows["b"][3] == "-0.1000"


def test_watch_once_json(daemon: Daemon, capsys: pytest.CaptureFixture[str]) -> None:
    assert ctl(daemon, "--json", "watch", "--once") == EXIT_OK
    doc = json.loads(capsys.readouterr().out)
    assert doc["status"]["robot"] == ROBOT and doc["joint_states"]["name"] == ["a", "b", "c"]


def test_unreachable_daemon_exits_2(capsys: pytest.CaptureFixture[str]) -> None:
    assert run_ctl(parse("--connect", free_endpoint(), "status")) == EXIT_UNREACHABLE
    assert "cannot reach a hild daemon" in capsys.readouterr().err
    assert run_ctl(parse("--connect", free_endpoint(), "--json", "estop")) == EXIT_UNREACHABLE
    assert json.loads(capsys.readouterr().out)["ok"] is False


def test_wrong_robot_exits_2(daemon: Daemon, capsys: pytest.CaptureFixture[str]) -> None:
    assert run_ctl(parse("--connect", daemon.endpoint, "--robot", "other", "--timeout", "0.3", "status")) == 2
    assert "no reply from hild/other/srv/status" in capsys.readouterr().err
