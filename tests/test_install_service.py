"""tools/install-service.sh --dry-run: the plan it prints, and that it changes nothing."""

from __future__ import annotations

import subprocess
from pathlib import Path

from tests.conftest import REPO


def dry_run(*args: str) -> str:
    result = subprocess.run(
        ["bash", str(REPO / "tools" / "install-service.sh"), "--dry-run", *args],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert result.returncode == 0, result.stderr
    return result.stdout


def test_dry_run_prints_every_step_for_the_default_arm() -> None:
    out = dry_run()
    commands = [line[2:] for line in out.splitlines() if line.startswith("+ ")]
    assert "python3 -m venv /opt/hild/venv" in commands
    assert f"/opt/hild/venv/bin/pip install --quiet {REPO}" in commands
    assert f"install -m 0640 -o root -g hild {REPO}/configs/arm6_twin.yaml /etc/hild/arm6.yaml" in commands
    assert f"install -D -m 0644 {REPO}/configs/arm6.xml /etc/hild/arm6.xml" in commands  # the model, resolved
    assert f"install -m 0644 {REPO}/systemd/hild@.service /etc/systemd/system/hild@.service" in commands
    assert "journalctl -u hild@arm6" in out and "systemctl enable --now hild@arm6" in out
    assert "BitRate" in out and "can0.conf" in out  # CAN bring-up is documented
    assert "dry run: nothing was changed" in out


def test_dry_run_with_another_config_name_and_prefix(tmp_path: Path) -> None:
    out = dry_run("--config", str(REPO / "configs" / "rrbot_twin.yaml"), "--prefix", str(tmp_path / "hild"), "rrbot")
    assert "/etc/hild/rrbot.yaml" in out and f"{REPO}/configs/rrbot.urdf /etc/hild/rrbot.urdf" in out
    assert f"s|/opt/hild/venv/bin/hild|{tmp_path}/hild/venv/bin/hild|" in out  # ExecStart follows the prefix
    assert not (tmp_path / "hild").exists()  # a dry run creates nothing
    assert "journalctl -u hild@rrbot" in out


def test_bad_instance_name_is_refused() -> None:
    result = subprocess.run(
        ["bash", str(REPO / "tools" / "install-service.sh"), "--dry-run", "../etc/passwd"],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert result.returncode == 2 and "plain instance name" in result.stderr
