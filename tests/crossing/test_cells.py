"""The shared-memory cells: queues, latest-value cells, rings and the region's directory, in one process and
across two (a spawned process maps the same memfd, as the cycle process does)."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import time
import tracemalloc
from collections.abc import Callable

import numpy as np
import pytest

from hild.crossing.latest import LatestCell, NumbersCell, latest_bytes, numbers_bytes
from hild.crossing.mailboxes import InProcess, LatestNumbers, Shared
from hild.crossing.queue import ByteQueue, queue_bytes
from hild.crossing.region import PAGE, Region, RegionError
from hild.crossing.ring import RingReader

SIZE = 4 << 20  # the directory alone takes 1 MiB (virtual, like the rest)


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


# ---- numeric latest-value cells -------------------------------------------------------------------------------
def in_process(region: Region, width: int) -> tuple[LatestNumbers, LatestNumbers]:
    door = InProcess().latest_numbers("n", width)
    return door, door


def shared(region: Region, width: int) -> tuple[LatestNumbers, LatestNumbers]:
    writer = Shared(region, create=True).latest_numbers("n", width)
    return writer, Shared(Region.attach(region.fd, SIZE), create=False).latest_numbers("n", width)


Layout = Callable[[Region, int], tuple[LatestNumbers, LatestNumbers]]
LAYOUTS = pytest.mark.parametrize("layout", [in_process, shared], ids=["in_process", "shared"])


@LAYOUTS
def test_a_numbers_door_gives_the_newest_record_once_into_its_own_array(region: Region, layout: Layout) -> None:
    writer, reader = layout(region, 3)
    assert reader.take() is None
    mine = np.array([1.0, 2.0, 3.0])
    writer.put(mine)
    mine[:] = -1.0  # the door copied: the caller may reuse its array
    writer.put([4, 5, 6])  # any number sequence
    got = reader.take()
    assert got is reader.values and got.dtype == np.float64 and got.tolist() == [4.0, 5.0, 6.0]
    assert reader.take() is None
    writer.put([7.0, 8.0, 9.0])
    reader.clear()
    assert reader.take() is None
    writer.put(np.array([0.5, -0.5, 1e300]))
    assert reader.take() is reader.values and reader.values.tolist() == [0.5, -0.5, 1e300]


@LAYOUTS
@pytest.mark.parametrize("values", [[1.0, 2.0], [1.0, 2.0, 3.0, 4.0], np.zeros((1, 3)), 5.0])
def test_a_numbers_door_refuses_a_record_of_the_wrong_width(region: Region, layout: Layout, values: object) -> None:
    writer, reader = layout(region, 3)
    with pytest.raises(ValueError, match="expected 3 numbers"):
        writer.put(values)  # type: ignore[arg-type]
    assert reader.take() is None


def test_a_numbers_cell_drops_a_copy_torn_by_a_writer_and_takes_the_newest_next_time(region: Region) -> None:
    cell = region.carve("c", numbers_bytes(4))
    writer, reader = NumbersCell(cell, 4), NumbersCell(cell, 4)
    writer.put([1.0] * 4)
    copy = reader._copy

    def overtaken(k: int) -> np.ndarray:
        writer.put([2.0] * 4)  # the writer publishes twice while the reader copies: it rewrites buffer k
        writer.put([3.0] * 4)
        return copy(k)

    reader._copy = overtaken  # type: ignore[method-assign]
    assert reader.take() is None
    reader._copy = copy  # type: ignore[method-assign]
    assert reader.take() is reader.values and reader.values.tolist() == [3.0] * 4
    assert reader.take() is None


def test_a_numbers_cell_writer_that_died_mid_write_costs_its_successor_nothing(region: Region) -> None:
    cell = region.carve("c", numbers_bytes(2))
    reader = NumbersCell(cell, 2)
    NumbersCell(cell, 2).put([1.0, -1.0])
    assert reader.take() is not None
    published = int(np.frombuffer(cell, dtype=np.int64, count=1)[0])
    NumbersCell(cell, 2)._seqs[(published + 1) % 2][0] += 1  # the dead writer's first step, and nothing after it
    successor = NumbersCell(cell, 2)
    for k in range(2, 6):
        successor.put([float(k), -float(k)])
        got = reader.take()
        assert got is not None and got.tolist() == [k, -k]


@LAYOUTS
def test_a_numbers_door_takes_without_allocating(region: Region, layout: Layout) -> None:
    """Wide records, so a copy into any new object (bytes, an array) would show as kilobytes."""
    width = 1024
    writer, reader = layout(region, width)
    records = [np.full(width, float(k)) for k in range(200)]
    peaks = []
    tracemalloc.start()
    try:
        for record in records:
            writer.put(record)
            tracemalloc.reset_peak()
            before = tracemalloc.get_traced_memory()[0]
            got = reader.take()
            peaks.append(tracemalloc.get_traced_memory()[1] - before)
            assert got is reader.values and got[0] == record[0]
    finally:
        tracemalloc.stop()
    assert max(peaks) < 512, peaks
    blocks = sys.getallocatedblocks()
    for _ in range(10_000):
        reader.take()  # nothing new: the quick way out
    assert sys.getallocatedblocks() - blocks < 10


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


def test_a_later_carver_appends_cells_the_first_side_finds(region: Region) -> None:
    """A client domain carves a loaded controller's cells while the cycle process, which attached earlier, finds
    them afterwards: the directory only grows, and each side reads the entries added since it last looked."""
    region.carve("engine/x", 64)
    cycle_side = Region.attach(region.fd, SIZE)
    client_side = Region.attach(region.fd, SIZE)
    client_side.find("engine/x", 64)
    late = client_side.carve("late@1/active", 8)
    late[:1] = b"\x01"
    assert bytes(cycle_side.find("late@1/active", 8)) == b"\x01" + bytes(7)
    fresh = region.carve("more", 8)  # the creator, carving again, lands after the client's cell: no overlap
    assert len(fresh) == 8 and _offset(region, "more") >= _offset(region, "late@1/active") + 8


def _offset(region: Region, name: str) -> int:
    return next(offset for cell, offset, _ in region.cells() if cell == name)


def test_released_cells_read_as_zeros_and_give_their_pages_back(region: Region) -> None:
    cell = region.carve("gone@3/queue", 4 * PAGE)
    kept = region.carve("gone@30/queue", PAGE)  # another prefix that starts alike: not released
    cell[:] = b"\xff" * len(cell)
    kept[:] = b"\xee" * len(kept)
    assert region.release("gone@3/") >= 3 * PAGE  # the whole pages inside the cell
    assert bytes(cell[PAGE : 3 * PAGE]) == bytes(2 * PAGE)
    assert bytes(kept) == b"\xee" * PAGE


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


NUMBERS_CHILD = textwrap.dedent(
    """
    import sys
    import numpy as np
    from hild.crossing.region import Region
    from hild.crossing.mailboxes import Shared
    fd, size, width, n = (int(a) for a in sys.argv[1:5])
    door = Shared(Region.attach(fd, size), create=False).latest_numbers("stream", width)
    ramp = np.arange(width, dtype=np.float64)
    taken, k = 0, -1.0
    while taken < n:
        got = door.take()
        if got is None:
            continue
        assert (got == got[0] + ramp).all(), got  # never torn
        assert got[0] > k, (got[0], k)  # never older than one taken before, never the same twice
        k = got[0]
        taken += 1
    print("child took", taken, "up to", int(k))
    """
)


def test_two_processes_stream_numeric_records_without_tearing(region: Region) -> None:
    """The parent publishes ever newer wide records for as long as the child reads: the child takes each one
    whole, newer than the last, while the writes go on."""
    width, n = 256, 2000
    door = Shared(region, create=True).latest_numbers("stream", width)
    child = subprocess.Popen(
        [sys.executable, "-c", NUMBERS_CHILD, str(region.fd), str(SIZE), str(width), str(n)],
        pass_fds=(region.fd,),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    ramp = np.arange(width, dtype=np.float64)
    k = 0
    deadline = time.monotonic() + 60.0
    while child.poll() is None and time.monotonic() < deadline:
        door.put(k + ramp)
        k += 1
    out, err = child.communicate(timeout=10)
    assert child.returncode == 0, err
    assert f"child took {n} up to" in out and int(out.split()[-1]) < k


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
