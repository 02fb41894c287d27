"""The soak in CI: ~20 s of a real daemon at 1 kHz under random goals, servo streams, e-stops and vanishing clients
(tools/soak.py runs the long version)."""

from __future__ import annotations

import importlib.util
import sys
from types import ModuleType

from tests.conftest import REPO

MEMORY_GROWTH_MB = 20.0  # after the warm-up; the 3-minute run grows far less (docs/safety.md)


def soak_tool() -> ModuleType:
    spec = importlib.util.spec_from_file_location("hild_soak_tool", REPO / "tools" / "soak.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up by name
    spec.loader.exec_module(module)
    return module


def test_a_short_soak_loses_nothing_and_the_daemon_survives() -> None:
    report = soak_tool().run_soak(seconds=20.0, rate=1000.0, backend="twin", seed=3)
    print(report.text())
    assert report.lost_goals == [], report.text()
    assert report.missed_replies == 0, report.text()
    assert report.alive_at_end and report.exit_code == 0, report.text()
    assert report.rss_growth_mb < MEMORY_GROWTH_MB, report.text()
    assert report.cycles > 15_000  # it really ran at 1 kHz for the whole time
    assert report.goals_accepted >= 5
    assert sum(report.results.values()) == report.goals_accepted  # one result per accepted goal, none lost
    assert report.estops + report.client_losses >= 1, report.text()  # faults were injected and recovered from
    assert not [p for p in report.problems if not p.startswith("daemon log")], report.text()
