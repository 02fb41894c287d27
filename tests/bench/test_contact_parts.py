"""``python -m hild.bench.contact --parts …``: some parts of the contact group, as JSON."""

from __future__ import annotations

import json

import pytest

from hild.bench import contact


def test_an_unknown_part_is_refused_with_the_known_ones(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        contact.main(["--parts", "cost,bogus"])
    assert "unknown parts bogus (known: detection, quiet, obstacle, walls, guiding, cost)" in capsys.readouterr().err


def test_the_cost_part_alone_prints_its_figures(capsys: pytest.CaptureFixture[str]) -> None:
    contact.main(["--parts", "cost", "--quick", "--cost-cycles", "200"])
    report = json.loads(capsys.readouterr().out)
    assert set(report) == {"settings", "cost"}
    assert report["settings"]["cost_cycles"] == 200
    cost = report["cost"]
    assert cost["cycles"] == 200 and "p99_rise_pct" in cost
    for mode in ("off", "on", "only"):
        assert cost[f"observer_{mode}"]["n"] == 200
