"""The bench's statistics, ratios and targets on synthetic data: no daemon, no timing."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from hild.bench.report import (
    busy,
    command_to_frame_limit,
    cpu_groups,
    cpu_percent,
    evaluate_targets,
    format_loop_table,
    format_report,
    judge,
    loop_figures,
    overrun_limit,
    per_10k,
    period_error_limit,
    rise_pct,
    rt_targets,
    summarize_ns,
)


def test_summarize_ns_gives_microsecond_percentiles_of_every_sample() -> None:
    values = np.arange(1, 1001) * 1000  # 1 … 1000 µs
    s = summarize_ns(values)
    assert s["n"] == 1000
    assert s["p50"] == pytest.approx(500.5)
    assert s["p99"] == pytest.approx(990.0, abs=0.1)
    assert s["p999"] == pytest.approx(999.0, abs=0.1)
    assert s["max"] == 1000.0
    assert s["mean"] == pytest.approx(500.5)


def test_summarize_ns_of_nothing_is_zeros() -> None:
    assert summarize_ns([]) == {"p50": 0.0, "p99": 0.0, "p999": 0.0, "max": 0.0, "mean": 0.0, "n": 0}


def test_ratios() -> None:
    assert per_10k(3, 30_000) == 1.0
    assert per_10k(1, 0) == 0.0
    assert rise_pct(110.0, 100.0) == 10.0
    assert rise_pct(90.0, 100.0) == -10.0
    assert cpu_percent({"process": 100, "cycle": 50}, {"process": 400, "cycle": 150}, 10.0, 100) == {
        "process": 30.0,
        "cycle": 10.0,
    }


def test_loop_figures_counts_overruns_per_10k_cycles() -> None:
    f = loop_figures(20_000, 4, [100_000] * 10, [5_000] * 10)
    assert f["overruns_per_10k"] == 2.0
    assert f["duration_us"]["p99"] == 100.0
    assert f["period_error_us"]["max"] == 5.0


def _us(p99: float) -> dict[str, float]:
    return {"p50": p99 / 2, "p99": p99, "p999": p99, "max": p99, "mean": p99 / 2, "n": 100}


def _scenario(base: str, rate: float, dur_p99: float, perr_p99: float, ovr: float, cpu: float) -> dict[str, Any]:
    return {
        "name": f"{base}@{rate:g}",
        "base": base,
        "rate_hz": rate,
        "cycles": 10_000,
        "duration_us": _us(dur_p99),
        "period_error_us": _us(perr_p99),
        "overruns_per_10k": ovr,
        "cpu": {"daemon": cpu},
    }


def _report() -> dict[str, Any]:
    return {
        "floor": {
            "empty_thread": [
                {
                    "rate_hz": 1000.0,
                    "period_error_us": _us(20.0),
                    "lateness_us": _us(5.0),
                    "cycles": 5000,
                    "overruns_per_10k": 0.0,
                }
            ],
            "zenoh": {"one_way_us": _us(150.0), "put_to_subscriber_us": _us(160.0), "pings": 10, "puts": 10},
        },
        "scenarios": [
            _scenario("twin6", 1000.0, 240.0, 39.0, 0.5, 50.0),  # passes the cycle targets
            _scenario("can6", 1000.0, 300.0, 41.0, 2.0, 60.0),  # misses all three
            _scenario("twin6", 500.0, 100.0, 10.0, 0.0, 30.0),
            _scenario("can6", 500.0, 100.0, 10.0, 0.0, 40.0),
        ],
        "latency": [
            {
                "scenario": "can6@1000",
                "base": "can6",
                "rate_hz": 1000.0,
                "probes": 100,
                "samples": 50,
                "command_to_frame_us": _us(1250.0),
                "reply_to_joint_states_us": _us(900.0),
            }
        ],
        "interference": {
            "scenario": "twin6@1000",
            "setup": "trajectory on 3 joints + servo on 3",
            "rounds": 2,
            "conditions": [
                {"name": "baseline", **loop_figures(10_000, 0, [80_000] * 100, [2_000] * 100), "p99_rise_pct": 0.0},
                {"name": "polling", **loop_figures(10_000, 1, [90_000] * 100, [2_000] * 100), "p99_rise_pct": 12.5},
            ],
        },
    }


def test_targets_pass_or_miss_against_limits_derived_from_the_same_runs_floor() -> None:
    earlier = [t for t in evaluate_targets(_report()) if t["group"] == "earlier"]
    targets = {(t["target"], t["scenario"]): t for t in earlier}
    assert targets[("cycle duration p99", "twin6@1000")]["status"] == "PASS"
    assert targets[("cycle duration p99", "can6@1000")]["status"] == "MISS"
    perr = targets[("period error p99", "twin6@1000")]
    assert perr["limit"] == 40.0 and perr["status"] == "PASS"  # 2 × the empty thread's 20 µs
    assert targets[("period error p99", "can6@1000")]["status"] == "MISS"
    assert targets[("overruns", "twin6@1000")]["status"] == "PASS"
    assert targets[("overruns", "can6@1000")]["status"] == "MISS"
    zenoh = targets[("Zenoh command → CAN frame p99", "can6@1000")]
    assert zenoh["limit"] == 1300.0 and zenoh["status"] == "PASS"  # 2 × 150 µs + one 1 ms cycle
    assert targets[("daemon CPU at 500 Hz", "twin6@500")]["status"] == "PASS"
    assert targets[("daemon CPU at 500 Hz", "can6@500")]["status"] == "MISS"
    assert targets[("polling raises cycle p99 by", "twin6@1000")]["status"] == "MISS"


def test_targets_without_their_measurement_are_not_applicable() -> None:
    targets = evaluate_targets({"floor": {}, "scenarios": [], "latency": [], "interference": {}})
    assert targets and all(t["status"] == "n/a" for t in targets)
    by_name = {(t["target"], t["scenario"]): t for t in targets}
    assert by_name[("cycle duration p99", "mock6@1000")]["limit"] == 250.0  # fixed limits are still stated
    assert by_name[("whole daemon CPU at 500 Hz", "twin6@500-nospin")]["limit"] == 35.0


def test_a_failed_scenario_is_not_used_for_a_target() -> None:
    report = _report()
    report["scenarios"][0] = {"name": "twin6@1000", "base": "twin6", "rate_hz": 1000.0, "error": "did not start"}
    targets = {(t["target"], t["scenario"], t["group"]): t for t in evaluate_targets(report)}
    assert targets[("cycle duration p99", "twin6@1000", "earlier")]["status"] == "n/a"
    assert targets[("period error p99", "twin6@1000", "rt-split")]["status"] == "n/a"


def test_the_table_shows_every_section_and_each_targets_status() -> None:
    report = _report()
    report["targets"] = evaluate_targets(report)
    report["cpu"] = [{"scenario": "twin6@500", "rate_hz": 500.0, "process": 30.0, "daemon": 30.0}]
    text = format_report(report)
    for heading in ("FLOOR", "CYCLE", "LATENCY", "CPU", "INTERFERENCE", "TARGETS"):
        assert heading in text
    assert "MISS" in text and "PASS" in text
    assert "can6@1000" in text


def test_a_busy_machine_is_flagged_in_the_table() -> None:
    idle = {"cpu_count": 2, "load_average": {"before": 0.1, "after": 1.2}}  # after: the bench's own load
    loaded = {"cpu_count": 2, "load_average": {"before": 1.5, "after": 1.9}}
    assert not busy(idle) and busy(loaded)
    assert "WARNING" not in format_report({"machine": idle})
    assert "WARNING: the machine was busy" in format_report({"machine": loaded})


# ---- [rt-split] -------------------------------------------------------------------------------------------------
def test_cpu_groups_in_one_process_keep_the_cycle_thread_inside_the_daemon() -> None:
    use = {"process": 60.0, "asyncio": 5.0, "cycle": 30.0, "emulator": 20.0, "telemetry": 3.0}
    g = cpu_groups(use, ["emulator"], cycle_process=False)
    assert g["daemon"] == 40.0 and g["other"] == 5.0 and g["hild"] == 40.0 and g["whole"] == 43.0


def test_cpu_groups_with_a_cycle_process_add_it_to_the_daemon() -> None:
    use = {"process": 50.0, "asyncio": 4.0, "cycle": 25.0, "emulator": 20.0, "bridge": 15.0, "telemetry": 3.0}
    g = cpu_groups(use, ["emulator", "bridge"], cycle_process=True)
    assert g["daemon"] == 15.0 and g["other"] == 11.0 and g["hild"] == 40.0 and g["whole"] == 43.0
    assert cpu_groups({"process": 1.0, "emulator": 1.3}, ["emulator"], cycle_process=True)["daemon"] == 0.0


def test_rt_limits() -> None:
    assert period_error_limit(20.0) == 60.0  # 3 × the floor
    assert period_error_limit(10.0) == 30.0
    assert period_error_limit(5.0) == 25.0  # below 10 µs: floor + 20 µs
    assert overrun_limit(0.0) == 1.0 and overrun_limit(2.5) == 3.5
    assert command_to_frame_limit(150.0, 1000.0, 300.0) == 1500.0  # one-way + period + cycle p99 + 50 µs
    assert judge(1.0, 1.0) == "PASS" and judge(1.1, 1.0) == "MISS"
    assert judge(None, 1.0) == judge(1.0, None) == "n/a"


def _condition(name: str, p99_us: float, overruns: int, rise: float, accepts: dict[str, float] | None = None):
    row = {"name": name, **loop_figures(10_000, overruns, [p99_us * 1000] * 100, [2_000] * 100)}
    row["p99_rise_pct"] = rise
    row["clients"] = "flood-status 700/s" if name == "flood" else ""
    row["goal_accept_ms"] = accepts or {"n": 0}
    return row


def _rt_report(floor_perr: float = 20.0, floor_ovr: float = 0.0) -> dict[str, Any]:
    report = _report()
    report["floor"]["empty_thread"][0]["period_error_us"] = _us(floor_perr)
    report["floor"]["empty_thread"][0]["overruns_per_10k"] = floor_ovr
    report["scenarios"] += [
        {**_scenario("twin6", 500.0, 100.0, 10.0, 0.0, 0.0), "name": "twin6@500-nospin", "cycle_process": True},
        {**_scenario("can6", 500.0, 100.0, 10.0, 0.0, 0.0), "name": "can6@500-nospin", "cycle_process": True},
    ]
    report["scenarios"][-2]["cpu"] = {"daemon": 12.0, "cycle": 15.0, "telemetry": 3.0, "whole": 30.0}
    report["scenarios"][-1]["cpu"] = {"daemon": 14.0, "cycle": 20.0, "telemetry": 3.0, "whole": 37.0}
    report["interference"]["conditions"] = [
        _condition("baseline", 80.0, 1, 0.0),
        _condition("polling+servo", 86.0, 1, 7.5),
        _condition("flood", 92.0, 4, 15.0, {"n": 3, "p50": 12.0, "max": 61.5}),
    ]
    return report


def _rt(report: dict[str, Any]) -> dict[tuple[str, str], dict[str, Any]]:
    return {(t["target"], t["scenario"]): t for t in rt_targets(report)}


def test_rt_targets_pass_or_miss_and_a_miss_names_its_numbers() -> None:
    t = _rt(_rt_report())
    perr = t[("period error p99", "can6@1000")]
    assert perr["limit"] == 60.0 and perr["status"] == "PASS"  # 41 µs ≤ 3 × 20 µs
    ovr = t[("overruns", "can6@1000")]
    assert ovr["limit"] == 1.0 and ovr["status"] == "MISS"
    assert ovr["detail"] == "can6@1000: overruns 2 /10k > limit 1 /10k (empty thread 0 /10k + 1 /10k)"
    assert t[("overruns", "twin6@1000")]["status"] == "PASS"
    assert t[("polling 200/s + servo 1 kHz: p99 rise", "twin6@1000")]["status"] == "PASS"
    rise = t[("1 MiB flood: p99 rise", "twin6@1000")]
    assert (
        rise["status"] == "MISS"
        and "15 % > limit 10 %" in rise["detail"]
        and "92 µs vs baseline 80 µs" in rise["detail"]
    )
    burst = t[("1 MiB flood: overruns (no burst)", "twin6@1000")]
    assert burst["limit"] == 2.0 and burst["measured"] == 4.0 and burst["status"] == "MISS"  # baseline 1/10k + 1
    goal = t[("1 MiB flood: operator goal accepted", "twin6@1000")]
    assert goal["measured"] == 61.5 and goal["status"] == "MISS" and "slowest of 3" in goal["detail"]
    frame = t[("Zenoh command → CAN frame p99", "can6@1000")]
    assert frame["limit"] == 1500.0 and frame["status"] == "PASS"  # 150 + 1000 + can6's cycle p99 300 + 50
    assert t[("whole daemon CPU at 500 Hz", "twin6@500-nospin")]["status"] == "PASS"
    cpu = t[("whole daemon CPU at 500 Hz", "can6@500-nospin")]
    assert cpu["status"] == "MISS" and "daemon 14 + cycle 20 (process) + telemetry 3 %" in cpu["detail"]


def test_the_servo_stream_alone_has_its_own_row_beside_polling_plus_servo() -> None:
    report = _rt_report()
    servo = _rt(report)[("servo stream 1 kHz: p99 rise", "twin6@1000")]
    assert servo["status"] == "n/a" and "interleaved baseline" in servo["detail"]  # a report from before the row
    report["interference"]["conditions"] += [
        _condition("servo", 90.0, 1, 12.5),
        _condition("decoy servo", 82.0, 1, 2.5),
    ]
    t = _rt(report)
    servo = t[("servo stream 1 kHz: p99 rise", "twin6@1000")]
    assert servo["group"] == "rt-split" and servo["limit"] == 10.0 and servo["status"] == "MISS"
    assert "90 µs vs baseline 80 µs; the same stream to a decoy +2.5 %" in servo["detail"]
    assert t[("polling 200/s + servo 1 kHz: p99 rise", "twin6@1000")]["status"] == "PASS"  # kept, decided apart


def test_a_floor_below_10_us_gives_floor_plus_20_and_the_floors_own_overruns_count() -> None:
    t = _rt(_rt_report(floor_perr=5.0, floor_ovr=1.5))
    perr = t[("period error p99", "twin6@1000")]
    assert perr["limit"] == 25.0 and perr["status"] == "MISS"  # 39 µs > 5 + 20
    assert "empty thread p99 5 µs + 20 µs" in perr["detail"]
    assert t[("overruns", "can6@1000")]["status"] == "PASS"  # 2 ≤ 1.5 + 1


def test_no_goal_during_the_flood_is_not_a_pass() -> None:
    report = _rt_report()
    report["interference"]["conditions"][-1]["goal_accept_ms"] = {"n": 0}
    goal = _rt(report)[("1 MiB flood: operator goal accepted", "twin6@1000")]
    assert goal["status"] == "n/a" and "no trajectory goal" in goal["detail"]


def test_the_table_prints_each_rt_miss_with_its_numbers() -> None:
    report = _rt_report()
    report["targets"] = evaluate_targets(report)
    report["bench"] = {"settings": {"cycle_process": True}}
    text = format_report(report)
    assert "TARGETS [rt-split]" in text and "EARLIER TARGETS" in text
    assert "MISS: can6@1000: overruns 2 /10k > limit 1 /10k" in text
    assert "mode: the cycle in a process of its own" in text
    assert "61.5 (3)" in text  # the flood's slowest goal acceptance, in the interference table


def test_a_cycle_cpu_gives_the_cycle_its_core_and_everything_else_the_others() -> None:
    import os

    from hild.bench.scenarios import Settings

    cpus = sorted(os.sched_getaffinity(0))
    if len(cpus) < 2:
        pytest.fail("this test needs two CPUs (the project's machines have them)")
    settings = Settings.make(True, None, None, cycle_cpu=cpus[-1])
    realtime = settings.realtime()
    assert realtime["cpu_affinity"] == [cpus[-1]]
    assert realtime["client_cpu_affinity"] == cpus[:-1]


def test_the_loop_table_has_a_row_per_rate_with_overruns_per_10k_cycles() -> None:
    row = {**loop_figures(20_000, 3, [50_000] * 10, [1_000] * 10), "rate_hz": 1000.0}
    lines = format_loop_table([row]).splitlines()
    assert lines[0].split()[:2] == ["rate", "cycles"]
    assert lines[1].split() == ["1000", "20000", "50.0", "50.0", "50.0", "50.0", "1.0", "1.0", "1.0", "1.0", "1.5"]


def test_goal_acceptance_counts_only_the_goals_sent_inside_a_window() -> None:
    from hild.bench.scenarios import accepts_during

    accepts = [(1.0, 0.010), (2.5, 0.030), (3.5, 0.020), (9.0, 5.0)]  # (sent at, seconds to accept)
    assert accepts_during(accepts, [(0.0, 3.0), (3.2, 4.0)]) == {"n": 3, "p50": 20.0, "max": 30.0}
    assert accepts_during(accepts, [(4.0, 5.0)]) == {"n": 0}


def test_command_to_frame_has_a_row_per_medium_and_unmatched_probes_are_a_miss() -> None:
    report = _rt_report()
    report["scenarios"].append({**_scenario("can6", 1000.0, 200.0, 30.0, 0.0, 50.0), "name": "can6@1000-virtual"})
    bridge = report["latency"][0]
    bridge.update({"ambiguous_probes": 2, "can_bus": "remote (loopback bridge)", "can_bridge": "rig process"})
    bridge["probes"] = 105  # 100 matched + 2 ambiguous: 3 probes never found their frame
    report["latency"].append(
        {**bridge, "scenario": "can6@1000-virtual", "probes": 100, "ambiguous_probes": 0, "can_bus": "virtual"}
    )
    report["latency"][1].pop("can_bridge")
    t = _rt(report)
    across = t[("Zenoh command → CAN frame p99", "can6@1000")]
    assert across["measured"] == 1250.0 and across["limit"] == 1500.0  # within the bound, but …
    assert across["status"] == "MISS" and "3 of 105 probes never matched a frame" in across["detail"]
    assert "remote (loopback bridge), rig process; probes 105: matched 100, ambiguous 2" in across["basis"]
    virtual = t[("Zenoh command → CAN frame p99", "can6@1000-virtual")]
    assert virtual["limit"] == 1400.0 and virtual["status"] == "PASS"  # 150 + 1000 + its own cycle p99 200 + 50
    assert "virtual; probes 100: matched 100, ambiguous 0, unmatched 0" in virtual["basis"]


def test_command_to_frame_without_the_virtual_scenario_is_not_applicable() -> None:
    t = _rt(_rt_report())
    assert t[("Zenoh command → CAN frame p99", "can6@1000-virtual")]["status"] == "n/a"


def test_command_to_frame_with_no_probe_matched_is_a_miss_not_a_gap() -> None:
    report = _rt_report()
    report["latency"][0].update({"probes": 300, "ambiguous_probes": 150, "command_to_frame_us": {"n": 0}})
    frame = _rt(report)[("Zenoh command → CAN frame p99", "can6@1000")]
    assert frame["measured"] is None and frame["status"] == "MISS"
    assert "150 of 300 probes never matched a frame" in frame["detail"]


def test_a_can_scenario_prints_its_bus_figures_beside_hild_checks() -> None:
    report = _report()
    row = _scenario("cia402_6", 500.0, 300.0, 40.0, 0.0, 30.0)
    row["bus"] = {"buses_bitrate": 1e6, "check_load_pct": 84.1, "measured_load_pct": 83.9, "frames_per_s": 6547}
    report["scenarios"].append(row)
    text = format_report(report)
    lines = [line for line in text.splitlines() if line.startswith("cia402_6@500")]
    assert any("84.1" in line and "83.9" in line and "6547" in line for line in lines), text
    assert "CAN BUS" in text
