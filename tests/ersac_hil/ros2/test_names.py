"""rmw_zenoh 1.x names against the examples of ros2/rmw_zenoh docs/design.md."""
from __future__ import annotations

import pytest
from hypothesis import given, strategies as st

from ersac_hil.ros2 import messages, names
from ersac_hil.ros2.options import Ros2Options

# docs/design.md, "Topic and Service name mapping to Zenoh key expressions" and "Graph Cache"
STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
CHATTER_KEY = f"0/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"
CHATTER_NS_KEY = f"0/robot1/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"
LISTENER_NODE = "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"
LISTENER_SUB = ("@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/10/MS/%/%/listener/%chatter/"
                f"std_msgs::msg::dds_::String_/{STRING_HASH}/::,10:,:,:,,")
TALKER_PUB = ("@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/"
              f"std_msgs::msg::dds_::String_/{STRING_HASH}/::,7:,:,:,,")


def test_the_type_hash_of_rosbags_is_the_design_docs():
    assert messages.type_hash("std_msgs/msg/String") == STRING_HASH


def test_data_keys_as_in_the_design_doc():
    assert names.Node(0, "/", "talker", "z").data_key("chatter", "std_msgs/msg/String", STRING_HASH) == CHATTER_KEY
    assert names.Node(0, "/robot1", "talker", "z").data_key("chatter", "std_msgs/msg/String", STRING_HASH) == CHATTER_NS_KEY


def test_tokens_as_in_the_design_doc():
    listener = names.Node(2, "/", "listener", "aac3178e146ba6f1fc6e6a4085e77f21")
    assert listener.node_token() == LISTENER_NODE
    talker = names.Node(2, "/", "talker", "8b20917502ee955ac4476e0266340d5c")
    assert talker.publisher_token(10, "chatter", "std_msgs/msg/String", STRING_HASH, "::,7:,:,:,,") == TALKER_PUB


def test_the_design_docs_tokens_parse():
    node = names.parse_token(LISTENER_NODE)
    assert (node.domain, node.zid, node.node_id, node.entity_id, node.kind, node.namespace, node.node) == (
        2, "aac3178e146ba6f1fc6e6a4085e77f21", 0, 0, "NN", "", "listener")
    sub, pub = names.parse_token(LISTENER_SUB), names.parse_token(TALKER_PUB)
    assert (sub.kind, sub.topic, sub.type_name, sub.type_hash, sub.qos) == (
        "MS", "/chatter", "std_msgs::msg::dds_::String_", STRING_HASH, "::,10:,:,:,,")
    assert (pub.kind, pub.entity_id, pub.node, names.ros_type(pub.type_name)) == (
        "MP", 10, "talker", "std_msgs/msg/String")


def test_a_namespaced_token_round_trips():
    node = names.Node(7, "/fleet/ubot1", "ersac_agent", "abc", node_id=3)
    token = names.parse_token(node.publisher_token(4, "joint_states", messages.JOINT_STATE, "RIHS01_x"))
    assert (token.domain, token.namespace, token.topic, token.node_id, token.entity_id) == (
        7, "/fleet/ubot1", "/fleet/ubot1/joint_states", 3, 4)
    assert node.node_token().split("/")[7] == "%fleet%ubot1"


@pytest.mark.parametrize("bad", ["ubot1", "/ubot1/", "/1bot", "/u bot", "//x"])
def test_bad_namespaces_are_refused_with_the_cause(bad):
    with pytest.raises(names.RosNameError, match="namespace"):
        Ros2Options(namespace=bad)


def test_bad_domain_and_decimation_are_refused():
    with pytest.raises(names.RosNameError, match="domain"):
        Ros2Options(domain=233)
    with pytest.raises(names.RosNameError, match="decimation"):
        Ros2Options(decimation=0)
    assert Ros2Options().namespace_for("ubot-trace") == "/ubot_trace"


@given(st.integers(-(1 << 63), (1 << 63) - 1), st.integers(0, (1 << 63) - 1), st.binary(min_size=16, max_size=16))
def test_attachments_are_33_bytes_and_round_trip(seq, stamp, gid):
    data = names.attachment(seq, stamp, gid)
    assert len(data) == 33 and data[16] == 16
    assert names.parse_attachment(data) == (seq, stamp, gid)
    assert int.from_bytes(data[:8], "little", signed=True) == seq
