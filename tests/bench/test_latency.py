"""Matching commands to CAN frames and joint_states samples to CAN replies, on synthetic timelines."""

from __future__ import annotations

from hild.bench.latency import SampleLog, hop_latencies, match_commands, match_replies

MS = 1_000_000  # ns
LSB = 0.0004


def frames_every_ms(until_ms: int, value_at: dict[int, float], start_value: float) -> list[list[float]]:
    """One frame per ms; from each key (ms) on, frames carry its value."""
    frames, value = [], start_value
    for k in range(until_ms):
        value = value_at.get(k, value)
        frames.append([k * MS + 300_000, value])  # the cycle's write lands 0.3 ms into its period
    return frames


def test_each_probe_is_timed_to_the_first_frame_carrying_its_value() -> None:
    a, b = 0.0, 3 * LSB
    # probe 0 (b) published at 2.5 ms, applied by the cycle at 4 ms; probe 1 (a) published at 10.2 ms, applied at 11 ms
    frames = frames_every_ms(20, {4: b, 11: a}, a)
    probes = [(2_500_000, b), (10_200_000, a)]
    latencies, ambiguous = match_commands(probes, frames, 1.5 * LSB)
    assert ambiguous == 0
    assert latencies == [4 * MS + 300_000 - 2_500_000, 11 * MS + 300_000 - 10_200_000]


def test_a_probe_the_frames_already_carried_is_ambiguous_not_matched() -> None:
    a = 0.0
    frames = frames_every_ms(10, {}, a)
    latencies, ambiguous = match_commands([(5_000_000, a)], frames, 1.5 * LSB)
    assert latencies == [] and ambiguous == 1


def test_a_probe_never_carried_is_not_matched() -> None:
    frames = frames_every_ms(10, {}, 0.0)
    latencies, ambiguous = match_commands([(5_000_000, 10 * LSB)], frames, 1.5 * LSB)
    assert latencies == [] and ambiguous == 0


def test_a_sample_is_timed_from_the_last_reply_before_its_cycle_woke() -> None:
    start_ns = 7 * MS
    replies = [[start_ns + k * MS + 500_000, k * 10 * LSB] for k in range(10)]  # reply k: 0.5 ms after wake k
    # the cycle at t = 4 ms (wake = start + 4 ms) read reply 3 (sent at start + 3.5 ms); the sample arrived 2 ms later
    samples = [(start_ns + 6 * MS, 0.004, 3 * 10 * LSB)]
    latencies, unmatched = match_replies(samples, replies, start_ns, 1.5 * LSB)
    assert unmatched == 0
    assert latencies == [6 * MS - 3 * MS - 500_000]


def test_a_reply_in_the_instant_between_wake_and_read_is_taken_when_only_it_matches() -> None:
    start_ns = 0
    replies = [[3 * MS - 1000, 0.0], [3 * MS + 20_000, 5 * LSB]]  # the second lands 20 µs after the wake at 3 ms
    latencies, unmatched = match_replies([(4 * MS, 0.003, 5 * LSB)], replies, start_ns, 1.5 * LSB)
    assert unmatched == 0 and latencies == [4 * MS - (3 * MS + 20_000)]


def test_a_sample_no_reply_explains_is_counted_unmatched() -> None:
    replies = [[1 * MS, 0.0], [2 * MS, 0.0]]
    latencies, unmatched = match_replies([(5 * MS, 0.003, 1.0)], replies, 0, 1.5 * LSB)
    assert latencies == [] and unmatched == 1


def test_the_sample_log_keeps_arrival_stamp_and_first_position() -> None:
    log = SampleLog()
    log({"stamp": 1.25, "position": [0.5, 0.7], "name": ["a", "b"]})
    ((arrived, stamp, position),) = log.samples
    assert arrived > 0 and stamp == 1.25 and position == 0.5


def _every_ms(start_ms: int, end_ms: int, value: float, offset_us: int = 0) -> list[tuple[int, float]]:
    return [(ms * 1_000_000 + offset_us * 1000, value) for ms in range(start_ms, end_ms)]


def test_hops_follow_one_probe_through_each_stamp() -> None:
    a, b = 0.0, 1.0
    probes = [(10_000_000, b), (20_000_000, a), (30_000_000, b), (40_000_000, a)]  # the last two: not judged
    accept = [(11_000_000, b), (21_000_000, a)]
    adopt = [(11_400_000, b), (21_300_000, a)]
    send = _every_ms(0, 12, a, 20) + _every_ms(12, 22, b, 20) + _every_ms(22, 40, a, 20)  # every cycle
    frame = [(t + 200_000, v) for t, v in send]
    hops, lost = hop_latencies(probes, [accept, adopt, send, frame], 0.1)
    assert lost == 0
    assert hops["put → accept"] == [1_000_000, 1_000_000]
    assert hops["accept → adopt"] == [400_000, 300_000]
    assert hops["adopt → send"] == [620_000, 720_000]  # the next cycle's frame, not the earlier ones carrying a
    assert hops["send → frame"] == [200_000, 200_000]
    assert hops["put → frame"] == [2_220_000, 2_220_000]


def test_a_frame_queued_past_the_probe_after_next_is_not_taken_for_that_one() -> None:
    a, b = 0.0, 1.0
    probes = [(10_000_000, b), (20_000_000, a), (30_000_000, b), (40_000_000, a)]
    accept = [(p + 500_000, v) for p, v in probes]
    adopt = [(p + 900_000, v) for p, v in probes]
    sends = [(p + 1_000_000, v) for p, v in probes]
    frames = [(t + 25_000_000, v) for t, v in sends]  # a bridge 25 ms behind: each frame arrives after two more puts
    hops, lost = hop_latencies(probes, [accept, adopt, sends, frames], 0.1)
    assert lost == 2 and hops["put → frame"] == []  # neither matched to another probe's frame
    quick = [(t + 5_000_000, v) for t, v in sends]
    hops, lost = hop_latencies(probes, [accept, adopt, sends, quick], 0.1)
    assert lost == 0 and hops["send → frame"] == [5_000_000] * 2
