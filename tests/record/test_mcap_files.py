"""Episode files: what goes in comes back bit-exact, and the independent readers (the ``mcap`` library's own
reader, rosbags' rosbag2 reader, rclpy) see a rosbag2 bag with the ROS 2 face's types, hashes and bytes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Message
from mcap.stream_reader import StreamReader, breakup_chunk
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader

from hild.api.ros2.types import decode, encode, message, type_hash, typestore
from hild.crossing.cyclelog import OWNER_NONE
from hild.record import mcap_files, topics
from hild.record.mcap_files import EpisodeWriter, read_blackbox, read_episode, write_blackbox
from hild.record.model import EPISODE_JSON, ROSBAG_METADATA, EpisodeMeta, RecordError, mcap_name
from tests.record.conftest import CHUNKS, ROWS_PER_CHUNK, Written
from tests.record.rows import CODES, JOINTS, assert_rows_equal, make_event, make_meta, make_rows


def expected_counts(written: Written) -> dict[str, int]:
    rows = written.rows
    counts = {topics.JOINT_STATES: len(rows), topics.COMMAND: len(rows), topics.CYCLE: len(rows)}
    counts[topics.EVENTS] = len(written.events)
    for code, name in CODES.items():
        counts[topics.controller_topic(name)] = int((rows.owner == code).any(axis=1).sum())
    return counts


def test_rows_and_events_come_back_bit_exact(episode: Written) -> None:
    back = read_episode(episode.directory)
    assert_rows_equal(back.rows, episode.rows)
    assert back.events == episode.events
    assert back.meta.state == "complete"
    assert (back.meta.cycles, back.meta.dropped) == (len(episode.rows), 3)
    assert back.meta.stop_tick == int(episode.rows.tick[-1])
    assert back.meta.stopped_wall == float(episode.rows.wall[-1])
    assert back.meta.controller_codes == CODES
    assert back.meta.versions["mcap"] == mcap_files.MCAP_VERSION


def test_close_answers_the_files_it_wrote(episode: Written) -> None:
    mcap, metadata, meta = episode.paths
    assert mcap == episode.directory.absolute() / mcap_name(make_meta().id)
    assert (metadata.name, meta.name) == (ROSBAG_METADATA, EPISODE_JSON)
    assert all(p.is_absolute() and p.stat().st_size > 0 for p in episode.paths)


def test_episode_json_says_recording_from_the_start(tmp_path: Path) -> None:
    writer = EpisodeWriter(tmp_path / "ep", make_meta(), fsync=True)
    assert EpisodeMeta.read(tmp_path / "ep").state == "recording"
    assert writer.path.read_bytes()[:8] == b"\x89MCAP0\r\n"
    writer.write_rows(make_rows(10), CODES)
    writer.end_chunk()
    assert read_episode(tmp_path / "ep").meta.state == "recording"
    assert len(read_episode(tmp_path / "ep").rows) == 10  # readable while still open


def test_an_existing_episode_is_never_overwritten(episode: Written) -> None:
    with pytest.raises(FileExistsError):
        EpisodeWriter(episode.directory, make_meta(), fsync=False)


def test_rows_of_other_joints_and_a_closed_writer_are_refused(tmp_path: Path) -> None:
    writer = EpisodeWriter(tmp_path / "ep", make_meta(), fsync=False)
    with pytest.raises(ValueError, match="joints"):
        writer.write_rows(make_rows(5, joints=3), CODES)
    writer.close()
    with pytest.raises(RecordError, match="closed"):
        writer.write_rows(make_rows(5), CODES)


def test_an_empty_episode_is_a_valid_bag(tmp_path: Path) -> None:
    EpisodeWriter(tmp_path / "ep", make_meta(), fsync=False).close()
    back = read_episode(tmp_path / "ep")
    assert len(back.rows) == 0 and back.rows.position.shape == (0, len(JOINTS))
    with Reader(tmp_path / "ep") as reader:
        assert reader.message_count == 0
        assert {c.topic for c in reader.connections} == set(topics.TOPIC_TYPES)


def test_rosbags_opens_the_episode_with_the_face_s_types_and_hashes(episode: Written) -> None:
    with Reader(episode.directory) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        assert counts == expected_counts(episode)
        for connection in reader.connections:
            assert connection.digest == type_hash(connection.msgtype)
            assert connection.msgdef.data == typestore().generate_msgdef(connection.msgtype, ros_version=2)[0]
            assert connection.ext.serialization_format == "cdr"
            (qos,) = connection.ext.offered_qos_profiles
            assert (qos.history.name, qos.depth, qos.reliability.name, qos.durability.name) == (
                "KEEP_LAST",
                10,
                "RELIABLE",
                "VOLATILE",
            )
        assert reader.message_count == sum(expected_counts(episode).values())
        assert reader.start_time == topics.stamps_ns(episode.rows.wall).min()


def test_rosbags_deserializes_what_hild_reads(episode: Written) -> None:
    rows = episode.rows
    with AnyReader([episode.directory], default_typestore=typestore()) as reader:
        states = [c for c in reader.connections if c.topic == topics.JOINT_STATES]
        for i, (connection, timestamp, raw) in enumerate(reader.messages(connections=states)):
            msg = reader.deserialize(raw, connection.msgtype)
            assert list(msg.name) == list(JOINTS)
            assert timestamp == msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
            assert np.array_equal(msg.position, rows.measured_position[i])
        assert i == len(rows) - 1


def test_metadata_yaml_is_rosbag2_jazzy_s(episode: Written) -> None:
    info = yaml.safe_load((episode.directory / ROSBAG_METADATA).read_text())["rosbag2_bagfile_information"]
    name = mcap_name(make_meta().id)
    assert (info["version"], info["storage_identifier"], info["ros_distro"]) == (9, "mcap", "jazzy")
    assert info["relative_file_paths"] == [name] and info["files"][0]["path"] == name
    stamps = topics.stamps_ns(episode.rows.wall)
    assert info["starting_time"]["nanoseconds_since_epoch"] == stamps.min()
    assert info["duration"]["nanoseconds"] == stamps.max() - stamps.min()
    assert info["message_count"] == sum(expected_counts(episode).values()) == info["files"][0]["message_count"]
    by_topic = {t["topic_metadata"]["name"]: t for t in info["topics_with_message_count"]}
    assert {k: v["message_count"] for k, v in by_topic.items()} == expected_counts(episode)
    state = by_topic[topics.JOINT_STATES]["topic_metadata"]
    assert state["type_description_hash"] == type_hash(topics.JOINT_STATE)
    assert state["offered_qos_profiles"][0]["history"] == "keep_last"  # version 9: names, a list


def test_the_mcap_reader_s_summary(episode: Written) -> None:
    with (episode.directory / mcap_name(make_meta().id)).open("rb") as stream:
        reader = make_reader(stream)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        assert summary is not None
        topic_of = {c.id: c.topic for c in summary.channels.values()}
        counts = {topic_of[cid]: n for cid, n in summary.statistics.channel_message_counts.items()}
        assert counts == expected_counts(episode)
        assert summary.statistics.chunk_count == len(summary.chunk_indexes) == CHUNKS
        for channel in summary.channels.values():
            schema = summary.schemas[channel.schema_id]
            assert (channel.message_encoding, schema.encoding) == ("cdr", "ros2msg")
            assert channel.metadata["topic_type_hash"] == type_hash(schema.name)
            assert yaml.safe_load(channel.metadata["offered_qos_profiles"])[0]["reliability"] == "reliable"
        stored = {m.name: m.metadata for m in reader.iter_metadata()}
        assert json.loads(stored["hild"]["episode"])["id"] == make_meta().id
        rosbag2 = stored["rosbag2"]
        assert yaml.safe_load(rosbag2["serialized_metadata"])["message_count"] == summary.statistics.message_count
        for _, _, msg in reader.iter_messages(topics=[topics.COMMAND]):
            stamp = decode(msg.data, topics.JOINT_STATE).header.stamp
            assert msg.log_time == msg.publish_time == stamp.sec * 10**9 + stamp.nanosec


def test_each_chunk_holds_whole_rows_one_batch_each(episode: Written) -> None:
    channels: dict[int, str] = {}
    per_chunk = []
    with (episode.directory / mcap_name(make_meta().id)).open("rb") as stream:
        for record in StreamReader(stream, emit_chunks=True).records:
            if isinstance(record, Chunk):
                counts = {topics.JOINT_STATES: 0, topics.COMMAND: 0, topics.CYCLE: 0}
                for item in breakup_chunk(record):
                    if isinstance(item, Channel):
                        channels[item.id] = item.topic
                    elif isinstance(item, Message) and channels[item.channel_id] in counts:
                        counts[channels[item.channel_id]] += 1
                per_chunk.append(counts)
    assert per_chunk == [dict.fromkeys(per_chunk[0], ROWS_PER_CHUNK)] * CHUNKS


def test_joint_states_carry_the_face_s_bytes(episode: Written) -> None:
    rows, path = episode.rows, episode.directory / mcap_name(make_meta().id)
    with path.open("rb") as stream:
        recorded = [msg.data for _, _, msg in make_reader(stream).iter_messages(topics=[topics.JOINT_STATES])]
    for i in (0, 1, len(rows) // 2, len(rows) - 1):
        ns = int(topics.stamps_ns(rows.wall[i : i + 1])[0])
        stamp = message("builtin_interfaces/msg/Time", sec=ns // 10**9, nanosec=ns % 10**9)
        face = message(
            topics.JOINT_STATE,
            header=message("std_msgs/msg/Header", stamp=stamp, frame_id=""),
            name=list(JOINTS),
            position=rows.measured_position[i],
            velocity=rows.measured_velocity[i],
            effort=rows.measured_effort[i],
        )
        assert recorded[i] == encode(face, topics.JOINT_STATE)


def test_a_controller_topic_holds_the_joints_it_commanded(episode: Written) -> None:
    rows, path = episode.rows, episode.directory / mcap_name(make_meta().id)
    topic = topics.controller_topic(CODES[2])
    with path.open("rb") as stream:
        got = [decode(m.data, topics.JOINT_STATE) for _, _, m in make_reader(stream).iter_messages(topics=[topic])]
    which = np.flatnonzero((rows.owner == 2).any(axis=1))
    assert len(got) == len(which) > 0
    for msg, i in zip(got, which, strict=True):
        assert list(msg.name) == [JOINTS[-1]]
        assert msg.position.tolist() == [rows.position[i, -1]]
        assert msg.effort.tolist() == [rows.effort[i, -1]]


def test_a_code_without_a_name_has_no_topic_but_its_rows_stay_exact(tmp_path: Path) -> None:
    rows = make_rows(40)
    rows.owner[:, 2] = np.where(rows.owner[:, 2] == OWNER_NONE, OWNER_NONE, 9)
    meta = make_meta()
    meta.controller_codes = {}
    writer = EpisodeWriter(tmp_path / "ep", meta, fsync=False)
    writer.write_rows(rows, {1: CODES[1]})
    writer.close()
    assert_rows_equal(read_episode(tmp_path / "ep").rows, rows)
    with Reader(tmp_path / "ep") as reader:
        assert {c.topic for c in reader.connections} == {*topics.TOPIC_TYPES, topics.controller_topic(CODES[1])}


def test_a_controller_loaded_mid_episode_gets_its_channel_then(tmp_path: Path) -> None:
    rows = make_rows(60)
    meta = make_meta()
    meta.controller_codes = {}
    writer = EpisodeWriter(tmp_path / "ep", meta, fsync=False)
    writer.write_rows(rows.select(slice(0, 30)), {})
    writer.end_chunk()
    writer.write_rows(rows.select(slice(30, 60)), CODES)
    writer.close()
    with Reader(tmp_path / "ep") as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert counts[topics.controller_topic(CODES[1])] == int((rows.owner[30:] == 1).any(axis=1).sum())
    assert_rows_equal(read_episode(tmp_path / "ep").rows, rows)


def test_rclpy_reads_the_recorded_bytes(episode: Written) -> None:
    pytest.importorskip("rclpy", reason="the ros2-verify extra (real ROS 2 Jazzy from PyPI) is not installed")
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray

    rows, path = episode.rows, episode.directory / mcap_name(make_meta().id)
    with path.open("rb") as stream:
        reader = make_reader(stream)
        state = next(m for _, _, m in reader.iter_messages(topics=[topics.JOINT_STATES]))
    with path.open("rb") as stream:
        cycle = next(m for _, _, m in make_reader(stream).iter_messages(topics=[topics.CYCLE]))
    msg = deserialize_message(state.data, JointState)
    assert list(msg.name) == list(JOINTS)
    assert list(msg.position) == rows.measured_position[0].tolist()
    assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == state.log_time
    array = deserialize_message(cycle.data, Float64MultiArray)
    labels = [d.label for d in array.layout.dim]
    assert labels == [*topics.SCALARS, *topics.PER_JOINT]
    assert array.data[labels.index("tick")] == rows.tick[0]
    assert array.data[labels.index("wall")] == rows.wall[0]


def test_a_black_box_is_one_mcap_and_a_json(tmp_path: Path) -> None:
    rows = make_rows(700)
    events = [make_event(float(rows.wall[100]), reason="fault"), make_event(float(rows.wall[-1]), kind="request")]
    meta = {"reason": "fault", "robot": "arm6", "joints": list(JOINTS), "controller_codes": CODES}
    path = write_blackbox(tmp_path / "blackbox" / "20260101-000000-fault.mcap", rows, events, meta)
    info = json.loads(path.with_suffix(".json").read_text())
    assert (info["reason"], info["robot"], info["cycles"], info["events"]) == ("fault", "arm6", 700, 2)
    assert (info["start_wall"], info["stop_wall"]) == (float(rows.wall[0]), float(rows.wall[-1]))
    assert (info["first_tick"], info["last_tick"]) == (int(rows.tick[0]), int(rows.tick[-1]))
    assert not list(path.parent.glob("*.tmp"))
    back_rows, back_events, back_info = read_blackbox(path)
    assert_rows_equal(back_rows, rows)
    assert back_events == events and back_info == info
    with Reader(path) as reader:  # rosbags opens a bare MCAP file too
        assert {c.topic: c.msgcount for c in reader.connections}[topics.JOINT_STATES] == 700
    with path.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None and summary.statistics.chunk_count == 8  # 0.7 s of 0.1 s chunks, and the events'
