"""The soak in CI: ~20 s of a real daemon at 1 kHz under random goals, servo streams, e-stops and vanishing clients
(``hild bench --only soak`` and ``python -m hild.bench.soak`` run the long version)."""

from __future__ import annotations

from hild.bench.soak import run_soak

MEMORY_GROWTH_MB = 20.0  # after the warm-up; the 3-minute run grows far less (docs/safety.md)


def test_a_short_soak_loses_nothing_and_the_daemon_survives() -> None:
    report = run_soak(seconds=20.0, rate=1000.0, backend="twin", seed=3)
    print(report.text())
    assert report.passed, report.text()
    assert report.rss_growth_mb < MEMORY_GROWTH_MB, report.text()
    assert report.cycles > 15_000  # it really ran at 1 kHz for the whole time
    assert report.goals_accepted >= 5
    assert sum(report.results.values()) == report.goals_accepted  # one result per accepted goal, none lost
    assert report.estops + report.client_losses >= 1, report.text()  # faults were injected and recovered from
    assert not [p for p in report.problems if not p.startswith("daemon log")], report.text()
