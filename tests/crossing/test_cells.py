"""The shared-memory cells: queues, latest-value cells, rings and the region's directory, in one process and
across two (a spawned process maps the same memfd, as the cycle process does)."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import numpy as np
import pytest

from hild.crossing.latest import LatestCell, latest_bytes
from hild.crossing.mailboxes import Shared
from hild.crossing.queue import ByteQueue, queue_bytes
from hild.crossing.region import Region, RegionError
from hild.ring import RingReader

SIZE = 1 << 20


@pytest.fixture
def region() -> Region:
    return Region(SIZE)


def test_queue_is_fifo_and_refuses_when_full_instead_of_waiting(region: Region) -> None:
    q = ByteQueue(region.carve("q", queue_bytes(256)))
    assert q.poll() is None
    accepted = 0
    while q.offer(bytes([accepted]) * 24):
        accepted += 1
    assert 0 < accepted <= 256 // 32 and len(q) == accepted
    assert [q.poll() for _ in range(accepted)] == [bytes([k]) * 24 for k in range(accepted)]
    assert q.poll() is None and len(q) == 0


def test_queue_wraps_records_of_every_length_in_order(region: Region) -> None:
    q = ByteQueue(region.carve("q", queue_bytes(200)))
    rng = np.random.default_rng(1)
    sent, got = [], []
    for k in range(2000):
        record = rng.integers(0, 256, int(rng.integers(0, q.max_record + 1)), dtype=np.uint8).tobytes()
        while not q.offer(record):
            got.append(q.poll())
        sent.append(record)
        if k % 3 == 0:
            got.append(q.poll())
    while (r := q.poll()) is not None:
        got.append(r)
    assert got == sent


def test_queue_refuses_a_record_larger_than_half_its_buffer(region: Region) -> None:
    q = ByteQueue(region.carve("q", queue_bytes(128)))
    with pytest.raises(ValueError, match="exceeds"):
        q.offer(b"x" * (q.max_record + 1))


def test_latest_cell_gives_the_newest_value_once(region: Region) -> None:
    cell = region.carve("c", latest_bytes(32))
    writer, reader = LatestCell(cell), LatestCell(cell)
    assert reader.take() is None
    writer.put(b"one")
    writer.put(b"two")
    assert reader.take() == b"two"
    assert reader.take() is None
    writer.put(b"three")
    reader.clear()
    assert reader.take() is None and not reader.pending()


def test_a_writer_that_died_mid_write_does_not_cost_its_successor_a_value(region: Region) -> None:
    """A restarted client domain writes the cell a dead one left half-written (its sequence odd): every value the
    new writer puts must still be taken, none read while it is being written."""
    cell = region.carve("c", latest_bytes(32))
    reader = LatestCell(cell)
    LatestCell(cell).put(b"before")
    assert reader.take() == b"before"
    published = int(np.frombuffer(cell, dtype=np.int64, count=1)[0])
    LatestCell(cell)._seqs[(published + 1) % 2][0] += 1  # the dead writer's first step, and nothing after it
    successor = LatestCell(cell)
    for value in (b"one", b"two", b"three", b"four"):
        successor.put(value)
        assert reader.take() == value


def test_region_directory_is_found_by_name_and_size_mismatches_are_refused(region: Region) -> None:
    view = region.carve("a/b", 100)
    view[:3] = b"abc"
    other = Region.attach(region.fd, SIZE)
    assert bytes(other.find("a/b", 100)[:3]) == b"abc"
    with pytest.raises(RegionError, match="expects 64"):
        other.find("a/b", 64)
    with pytest.raises(RegionError, match="did not carve"):
        other.find("nope", 8)
    with pytest.raises(RegionError, match="twice"):
        region.carve("a/b", 8)


def test_shared_ring_readers_drop_samples_the_producer_overwrote(region: Region) -> None:
    producer = Shared(region, create=True).ring("r", 2, ("position",), capacity=8)
    consumer = Shared(Region.attach(region.fd, SIZE), create=False).ring("r", 2, ("position",), capacity=8)
    reader = RingReader(consumer, start_at_head=False)
    for k in range(20):
        producer.data["position"][producer.slot()] = (k, -k)
        producer.commit(float(k))
    samples = reader.read()
    assert [s[0] for s in samples] == list(range(13, 20)) and reader.dropped == 13
    assert samples[-1][2]["position"] == [19.0, -19.0]


CHILD = textwrap.dedent(
    """
    import sys
    from hild.crossing.region import Region
    from hild.crossing.mailboxes import Shared
    fd, size, n = (int(a) for a in sys.argv[1:4])
    boxes = Shared(Region.attach(fd, size), create=False)
    requests, replies = boxes.queue("requests", 8), boxes.queue("replies", 8)
    latest = boxes.latest("target")
    done, last = 0, None
    while done < n:
        item = requests.poll()
        if item is not None:
            while not replies.offer(("ok", item)):
                pass
            done += 1
        value = latest.take()
        if value is not None:
            assert value[0] == -value[1], value  # never torn
            assert last is None or value[0] >= last, (value, last)  # never older than one taken before
            last = value[0]
    print("child done", last)
    """
)


def test_two_processes_exchange_requests_and_stream_values_without_tearing(region: Region) -> None:
    boxes = Shared(region, create=True)
    requests, replies, latest = boxes.queue("requests", 8), boxes.queue("replies", 8), boxes.latest("target")
    n = 300
    child = subprocess.Popen(
        [sys.executable, "-c", CHILD, str(region.fd), str(SIZE), str(n)],
        pass_fds=(region.fd,),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    sent = got = 0
    answers = []
    value = 0
    while got < n:
        if sent < n and requests.offer({"request": sent, "payload": np.arange(sent % 7)}):
            sent += 1
        for _ in range(20):
            value += 1
            latest.put((value, -value))
        while (reply := replies.poll()) is not None:
            answers.append(reply)
            got += 1
        if child.poll() is not None:
            break
    out, err = child.communicate(timeout=60)
    assert child.returncode == 0, err
    assert "child done" in out
    assert [a[1]["request"] for a in answers] == list(range(n))
    assert all(np.array_equal(a[1]["payload"], np.arange(k % 7)) for k, a in enumerate(answers))
