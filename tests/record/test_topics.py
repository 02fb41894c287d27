"""A row's messages: the templates write the face's bytes for any joints and values, stamps are the nearest
nanosecond, and the hand-written metadata.yaml is YAML that says what it was given."""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest
import yaml
from hypothesis import example, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from hild.api.ros2.face import JOINT_STATES_FRAME
from hild.api.ros2.types import decode, encode, message
from hild.crossing.cyclelog import CycleRows
from hild.record import topics
from hild.record.bag_metadata import QOS_FIELDS, QOS_PROFILES, dump
from hild.record.model import RecordedEvent
from tests.record.rows import assert_rows_equal

any_float = st.floats(allow_nan=True, allow_infinity=True, width=64)
names = st.text(st.characters(codec="utf-8", exclude_characters="\x00"), max_size=12)


@st.composite
def cycle_rows(draw: st.DrawFn) -> tuple[CycleRows, tuple[str, ...]]:
    k, n = draw(st.integers(1, 6)), draw(st.integers(1, 7))
    joints = tuple(draw(st.lists(names, min_size=n, max_size=n)))

    def per_joint(dtype: type, elements: st.SearchStrategy) -> np.ndarray:
        return draw(hnp.arrays(dtype, (k, n), elements=elements))

    rows = CycleRows(
        tick=draw(hnp.arrays(np.int64, k, elements=st.integers(0, 2**53))),
        t=draw(hnp.arrays(np.float64, k, elements=any_float)),
        wall=draw(hnp.arrays(np.float64, k, elements=st.floats(0, 2**31 - 1))),
        period=draw(hnp.arrays(np.float64, k, elements=any_float)),
        duration=draw(hnp.arrays(np.float64, k, elements=any_float)),
        measured_position=per_joint(np.float64, any_float),
        measured_velocity=per_joint(np.float64, any_float),
        measured_effort=per_joint(np.float64, any_float),
        fresh=per_joint(np.bool_, st.booleans()),
        fault=per_joint(np.int16, st.integers(-(2**15), 2**15 - 1)),
        position=per_joint(np.float64, any_float),
        velocity=per_joint(np.float64, any_float),
        effort=per_joint(np.float64, any_float),
        kp=per_joint(np.float64, any_float),
        kd=per_joint(np.float64, any_float),
        mode=per_joint(np.int8, st.integers(-128, 127)),
        owner=per_joint(np.int16, st.integers(0, 3)),
        tau_ext=per_joint(np.float64, any_float),
        source=per_joint(np.int8, st.integers(-1, 5)),
    )
    return rows, joints


@settings(max_examples=60, deadline=None)
@given(cycle_rows())
def test_the_templates_write_the_face_s_bytes_and_read_back_bit_exact(drawn: tuple[CycleRows, tuple[str, ...]]) -> None:
    rows, joints = drawn
    codes = {1: "one", 2: "two"}
    encoded = topics.encode_rows(rows, joints, codes)
    for i in range(len(rows)):
        ns = int(encoded.log_times[i])
        stamp = message("builtin_interfaces/msg/Time", sec=ns // 10**9, nanosec=ns % 10**9)
        face = message(
            topics.JOINT_STATE,
            header=message("std_msgs/msg/Header", stamp=stamp, frame_id=""),
            name=list(joints),
            position=rows.position[i],
            velocity=rows.velocity[i],
            effort=rows.effort[i],
        )
        assert encoded.command[i] == encode(face, topics.JOINT_STATE)
        face.header.frame_id = JOINT_STATES_FRAME
        face.position, face.velocity, face.effort = (
            rows.measured_position[i],
            rows.measured_velocity[i],
            rows.measured_effort[i],
        )
        assert encoded.joint_states[i] == encode(face, topics.JOINT_STATE)
    for code, name in codes.items():
        which, messages = encoded.controllers.get(topics.controller_topic(name), (np.array([], int), []))
        assert which.tolist() == np.flatnonzero((rows.owner == code).any(axis=1)).tolist()
        for i, raw in zip(which, messages, strict=True):
            cols = np.flatnonzero(rows.owner[i] == code)
            msg = decode(raw, topics.JOINT_STATE)
            assert list(msg.name) == [joints[c] for c in cols]
            assert msg.velocity.tobytes() == rows.velocity[i, cols].tobytes()
    states = topics.decode_joint_states(encoded.joint_states)
    command = topics.decode_joint_states(encoded.command)
    cycle = topics.decode_cycles(encoded.cycle, len(joints))
    assert states is not None and command is not None and states.names == joints
    by_decode = [decode(raw, topics.JOINT_STATE) for raw in encoded.joint_states]  # the face's decoder, one by one
    assert states.position.tobytes() == np.stack([m.position for m in by_decode]).tobytes()
    assert states.effort.tobytes() == np.stack([m.effort for m in by_decode]).tobytes()
    assert states.stamps.tolist() == [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in by_decode]
    data = np.stack([decode(raw, topics.FLOAT64_ARRAY).data for raw in encoded.cycle])
    n = len(joints)  # the last two per-joint fields: tau_ext, then source
    assert cycle["tau_ext"].tobytes() == data[:, -2 * n : -n].tobytes()
    assert cycle["source"].tolist() == data[:, -n:].astype(np.int8).tolist()
    back = CycleRows(
        **cycle,
        measured_position=states.position,
        measured_velocity=states.velocity,
        measured_effort=states.effort,
        position=command.position,
        velocity=command.velocity,
        effort=command.effort,
    )
    assert_rows_equal(back, rows)


@given(st.floats(0, 2**31 - 1))
def test_a_stamp_is_the_nearest_nanosecond(wall: float) -> None:
    exact = Fraction(wall) * 10**9
    ns = int(topics.stamps_ns(np.array([wall]))[0])
    assert abs(Fraction(ns) - exact) <= Fraction(1, 2)


@pytest.mark.parametrize("wall", [-1.0, float("nan"), float("inf")])
def test_a_wall_time_before_the_epoch_or_not_finite_is_refused(wall: float) -> None:
    with pytest.raises(ValueError, match="wall"):
        topics.stamps_ns(np.array([1.0, wall]))


def test_joint_states_are_in_the_face_s_frame() -> None:
    assert topics.JOINT_STATES_FRAME == JOINT_STATES_FRAME


def test_controller_names_become_ros_topic_names() -> None:
    assert topics.controller_topic("arm_trajectory") == "/arm_trajectory/joint_commands"
    assert topics.controller_topic("grip-per.2") == "/grip_per_2/joint_commands"
    assert topics.controller_topic("2nd") == "/_2nd/joint_commands"
    assert topics.controller_topic("") == "/_/joint_commands"


def test_the_cycle_layout_is_labelled_in_order() -> None:
    msg = decode(topics.cycle_template(2).data, topics.FLOAT64_ARRAY)
    labelled = [(d.label, d.size) for d in msg.layout.dim]
    assert labelled == [(name, 1) for name in topics.SCALARS] + [(name, 2) for name in topics.PER_JOINT]


def test_messages_not_from_the_template_are_decoded_one_by_one() -> None:
    def state(frame_id: str, names: list[str], value: float) -> bytes:
        stamp = message("builtin_interfaces/msg/Time", sec=3, nanosec=4)
        header = message("std_msgs/msg/Header", stamp=stamp, frame_id=frame_id)
        array = np.array([value] * len(names))
        msg = message(topics.JOINT_STATE, header=header, name=names, position=array, velocity=array, effort=array)
        return encode(msg, topics.JOINT_STATE)

    other = topics.decode_joint_states([state("base", ["a", "b"], 1.5), state("", ["a", "b"], -2.0)])
    assert other is not None and other.position.tolist() == [[1.5, 1.5], [-2.0, -2.0]]
    assert other.stamps.tolist() == [3_000_000_004] * 2
    with pytest.raises(ValueError, match="different joints"):
        topics.decode_joint_states([state("", ["a", "b"], 1.0), state("", ["a", "c"], 1.0)])
    dims = [("t", 1), ("tick", 1), ("wall", 1), ("period", 1), ("duration", 1)] + [(n, 1) for n in topics.PER_JOINT]
    layout = message(
        "std_msgs/msg/MultiArrayLayout",
        dim=[message("std_msgs/msg/MultiArrayDimension", label=lb, size=n, stride=n) for lb, n in dims],
        data_offset=0,
    )
    data = np.arange(len(dims), dtype=np.float64)
    raw = encode(message(topics.FLOAT64_ARRAY, layout=layout, data=data), topics.FLOAT64_ARRAY)
    fields = topics.decode_cycles([raw], 1)  # found by label, in another order
    assert (fields["t"][0], fields["tick"][0], fields["tau_ext"][0, 0]) == (0.0, 1, len(dims) - 2)
    assert fields["source"][0, 0] == len(dims) - 1


def test_a_cycle_message_from_before_provenance_reads_with_source_not_recorded() -> None:
    """Episodes written before the ``source`` field (stop 37's) still read: their source is -1, "not recorded"."""
    old = [name for name in topics.PER_JOINT if name != "source"]
    dims = [(name, 1) for name in topics.SCALARS] + [(name, 2) for name in old]
    layout = message(
        "std_msgs/msg/MultiArrayLayout",
        dim=[message("std_msgs/msg/MultiArrayDimension", label=lb, size=n, stride=n) for lb, n in dims],
        data_offset=0,
    )
    data = np.arange(len(topics.SCALARS) + 2 * len(old), dtype=np.float64)
    raw = encode(message(topics.FLOAT64_ARRAY, layout=layout, data=data), topics.FLOAT64_ARRAY)
    fields = topics.decode_cycles([raw, raw], 2)
    assert fields["source"].dtype == np.int8 and fields["source"].tolist() == [[-1, -1], [-1, -1]]
    assert fields["tau_ext"][0].tolist() == data[-2:].tolist()


def test_a_cycle_message_without_a_field_is_refused() -> None:
    dim = message("std_msgs/msg/MultiArrayDimension", label="tick", size=1, stride=1)
    layout = message("std_msgs/msg/MultiArrayLayout", dim=[dim], data_offset=0)
    raw = encode(message(topics.FLOAT64_ARRAY, layout=layout, data=np.zeros(1)), topics.FLOAT64_ARRAY)
    with pytest.raises(ValueError, match="no field 't'"):
        topics.decode_cycles([raw], 1)


def test_events_are_json_lines_with_an_unknown_time_as_null() -> None:
    event = RecordedEvent(wall=12.5, t=float("nan"), kind="marker", data={"task": 'pick\n"it"'})
    raw = topics.encode_event(event)
    assert decode(raw, topics.STRING).data == '{"wall":12.5,"t":null,"kind":"marker","data":{"task":"pick\\n\\"it\\""}}'
    (back,) = topics.decode_events(raw)
    assert (back.wall, back.kind, back.data) == (12.5, "marker", event.data) and np.isnan(back.t)


@given(st.dictionaries(st.text(st.characters(codec="ascii", categories=["L"]), min_size=1), names | st.integers()))
@example({"A": "A\n"})  # found by the CI of stop 39: a trailing newline passed as a plain scalar and was lost
def test_the_yaml_writer_says_what_it_was_given(node: dict) -> None:
    assert yaml.safe_load(dump({"top": node, "list": list(node.values())})) == {
        "top": node,
        "list": list(node.values()),
    }


def test_the_channel_qos_text_is_the_metadata_s_profile() -> None:
    assert yaml.safe_load(QOS_PROFILES) == [QOS_FIELDS]
    assert not QOS_PROFILES.endswith("\n")  # yaml-cpp's Dump
