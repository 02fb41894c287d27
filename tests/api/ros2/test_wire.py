"""rmw_zenoh's bytes checked against published vectors: ros2/rmw_zenoh docs/design.md (keys, tokens, QoS strings)
and REP-2016 hashes other implementations publish (AddTwoInts, String)."""

from __future__ import annotations

import pytest

from hild.api.ros2 import types, wire

STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
ADD_TWO_INTS_HASH = "RIHS01_e118de6bf5eeb66a2491b5bda11202e7b68f198d6f67922cf30364858239c81a"


def test_message_hashes_match_published_vectors() -> None:
    assert types.type_hash("std_msgs/msg/String") == STRING_HASH
    # computed with rosbags (ROS-free); equal to what rclpy reports: tests/api/ros2/test_against_rclpy.py
    assert types.type_hash("sensor_msgs/msg/JointState") == (
        "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e"
    )


def test_service_hash_algorithm_matches_add_two_ints() -> None:
    store = types.service_store("example_interfaces/srv/AddTwoInts", "int64 a\nint64 b", "int64 sum")
    assert store.hash_rihs01("example_interfaces/srv/AddTwoInts") == ADD_TWO_INTS_HASH


def test_controller_manager_services_are_known_and_differ() -> None:
    hashes = {
        types.type_hash(n)
        for n in ("controller_manager_msgs/srv/ListControllers", "controller_manager_msgs/srv/SwitchController")
    }
    assert len(hashes) == 2 and all(h.startswith("RIHS01_") and len(h) == 7 + 64 for h in hashes)


def test_data_keys_match_design_md() -> None:
    key = wire.data_key(0, "/chatter", "std_msgs/msg/String")
    assert key == f"0/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"
    assert wire.data_key(0, "/robot1/chatter", "std_msgs/msg/String").startswith("0/robot1/chatter/std_msgs::")


def test_tokens_match_design_md() -> None:
    node = wire.NodeInfo(2, "aac3178e146ba6f1fc6e6a4085e77f21", "/", "listener")
    assert node.node_token() == "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"
    subscription = node.entity_token(10, wire.SUBSCRIPTION, "/chatter", "std_msgs/msg/String")
    assert subscription == (
        "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/10/MS/%/%/listener/%chatter/std_msgs::msg::dds_::String_/"
        f"{STRING_HASH}/::,10:,:,:,,"
    )
    talker = wire.NodeInfo(2, "8b20917502ee955ac4476e0266340d5c", "/", "talker")
    assert talker.entity_token(10, wire.PUBLISHER, "/chatter", "std_msgs/msg/String", wire.Qos(depth=7)).endswith(
        "/MP/%/%/talker/%chatter/std_msgs::msg::dds_::String_/" + STRING_HASH + "/::,7:,:,:,,"
    )


def test_namespaced_node_token_mangles_the_namespace() -> None:
    assert wire.NodeInfo(0, "ab", "/arm/left", "cm").node_token() == "@ros2_lv/0/ab/0/0/NN/%/%arm%left/cm"


def test_latched_qos_says_transient_local_and_depth_one() -> None:
    assert wire.LATCHED_QOS.keyexpr() == ":1:,1:,:,:,,"


def test_attachment_layout() -> None:
    gid = bytes(range(16))
    raw = wire.attachment(7, gid, stamp_ns=123)
    assert raw == (7).to_bytes(8, "little") + (123).to_bytes(8, "little") + b"\x10" + gid
    parsed = wire.parse_attachment(raw)
    assert (parsed.sequence, parsed.stamp_ns, parsed.gid) == (7, 123, gid)
    with pytest.raises(ValueError):
        wire.parse_attachment(raw[:-1])


def test_cdr_has_the_encapsulation_header_and_round_trips() -> None:
    msg = types.message("std_msgs/msg/String", data="abc")
    raw = types.encode(msg, "std_msgs/msg/String")
    assert raw == bytes.fromhex("00010000") + (4).to_bytes(4, "little") + b"abc\x00"
    assert types.decode(raw, "std_msgs/msg/String").data == "abc"


@pytest.mark.parametrize("raw", [b"", b"\x00\x01\x00\x00", b"\x00\x01\x00\x00\xff\xff\xff\x7f", b"garbage!"])
def test_malformed_cdr_is_a_cdr_error(raw: bytes) -> None:
    with pytest.raises(types.CdrError):
        types.decode(raw, "std_msgs/msg/Float64MultiArray")


def test_gid_is_xxh3_128_of_the_token() -> None:
    token = "@ros2_lv/0/ab/0/1/MP/%/%/n/%t/std_msgs::msg::dds_::String_/" + STRING_HASH + "/::,10:,:,:,,"
    gid = wire.gid_of(token)
    assert len(gid) == 16 and gid != wire.gid_of(token + "x")


FIBONACCI = (
    "action_tutorials_interfaces/action/Fibonacci",
    "int32 order",
    "int32[] sequence",
    "int32[] partial_sequence",
)


def test_action_hash_algorithm_matches_published_fibonacci_vectors() -> None:
    """ros-z's locked Jazzy hashes (checked there against rmw_zenoh_cpp) for an action's three keyed types."""
    store = types.action_store(*FIBONACCI)
    name = FIBONACCI[0]
    assert store.hash_rihs01(f"{name}_SendGoal") == (
        "RIHS01_a0603060ed69fe2dfbd1a6f3b982a1749957ef346e4a4d2b311a05e305ec37bb"
    )
    assert store.hash_rihs01(f"{name}_GetResult") == (
        "RIHS01_8b47e383f1e31f6d8df6417ab54957e7d5ea24dad315646ad711ac3fdea81d58"
    )
    assert store.hash_rihs01(f"{name}_FeedbackMessage") == (
        "RIHS01_50fc26b9cac313652ecbeab3adf9b5414d59fd4d4d5f9058ddcc7525169927f1"
    )


def test_action_msgs_hashes_match_published_vectors() -> None:
    assert types.type_hash("action_msgs/srv/CancelGoal") == (
        "RIHS01_573d8b0a534451d7bc2ac8c5ffde8ac14b8593b7001175d0cd6516dcbeb8689a"
    )
    assert types.type_hash("action_msgs/msg/GoalStatusArray") == (
        "RIHS01_6c1684b00f177d37438febe6e709fc4e2b0d4248dca4854946f9ed8b30cda83e"
    )
