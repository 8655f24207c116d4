"""rmw_zenoh's wire format: golden values from its design document, and round trips."""

from __future__ import annotations

import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from omnican.zenoh import rmw

STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
ADD_TWO_INTS_HASH = "RIHS01_e118de6bf5eeb66a2491b5bda11202e7b68f198d6f67922cf30364858239c81a"


def test_the_design_documents_string_hash() -> None:
    assert rmw.type_hash("std_msgs/msg/String") == STRING_HASH


def test_service_hashes_are_the_published_ones() -> None:
    """AddTwoInts' from the design document; Trigger's as ROS 2 Jazzy publishes it."""
    assert rmw.service_type_hash("example_interfaces/srv/AddTwoInts", "int64 a\nint64 b",
                                 "int64 sum") == ADD_TWO_INTS_HASH
    assert rmw.service_type_hash("std_srvs/srv/Trigger", "", "bool success\nstring message") \
        == "RIHS01_eeff2cd6fa5ad9d27cdf4dec64818317839b62f212a91e6b5304b634b2062c5f"
    with pytest.raises(ValueError):
        rmw.service_type_hash("std_srvs/msg/Trigger", "", "")


def test_the_design_documents_key_expressions() -> None:
    assert rmw.data_key(0, "/chatter", "std_msgs/msg/String", STRING_HASH) == \
        f"0/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"
    assert rmw.data_key(0, rmw.fully_qualified("/robot1", "chatter"), "std_msgs/msg/String",
                        STRING_HASH) == f"0/robot1/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"


def test_the_design_documents_liveliness_tokens() -> None:
    listener = rmw.RosNode(2, "aac3178e146ba6f1fc6e6a4085e77f21", 0, "listener")
    assert listener.token() == "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"
    assert listener.endpoint_token(10, rmw.Kind.SUBSCRIPTION, "/chatter", "std_msgs/msg/String",
                                   STRING_HASH, rmw.Qos(depth=10)) == (
        "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/10/MS/%/%/listener/%chatter/"
        f"std_msgs::msg::dds_::String_/{STRING_HASH}/::,10:,:,:,,")
    talker = rmw.RosNode(2, "8b20917502ee955ac4476e0266340d5c", 0, "talker")
    assert talker.endpoint_token(10, rmw.Kind.PUBLISHER, "/chatter", "std_msgs/msg/String",
                                 STRING_HASH, rmw.Qos(depth=7)) == (
        "@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/"
        f"std_msgs::msg::dds_::String_/{STRING_HASH}/::,7:,:,:,,")
    server = rmw.RosNode(2, "f9980ee0495eaafb3e38f0d19e2eae12", 0, "add_two_ints_server")
    assert server.endpoint_token(10, rmw.Kind.SERVICE, "/add_two_ints",
                                 "example_interfaces/srv/AddTwoInts", ADD_TWO_INTS_HASH,
                                 rmw.Qos(depth=10)) == (
        "@ros2_lv/2/f9980ee0495eaafb3e38f0d19e2eae12/0/10/SS/%/%/add_two_ints_server/"
        f"%add_two_ints/example_interfaces::srv::dds_::AddTwoInts_/{ADD_TWO_INTS_HASH}/"
        "::,10:,:,:,,")


def test_a_namespaced_node_and_other_qos() -> None:
    node = rmw.RosNode(0, "ab", 3, "base", namespace="/robot1")
    assert node.token() == "@ros2_lv/0/ab/3/3/NN/%/%robot1/base"
    qos = rmw.Qos(rmw.Reliability.BEST_EFFORT, rmw.Durability.TRANSIENT_LOCAL, 1)
    assert qos.encode() == "2:1:,1:,:,:,,"
    assert rmw.Qos(depth=rmw.DEFAULT_DEPTH).encode() == "::,:,:,:,,"


def test_an_attachments_bytes() -> None:
    """Sequence 1 at 1.5 s, GID 0x00..0x0f: 33 bytes, as a router carries rmw_zenoh's."""
    gid = bytes(range(16))
    data = rmw.Attachment(1, 1_500_000_000, gid).encode()
    assert data == (b"\x01\x00\x00\x00\x00\x00\x00\x00" + struct.pack("<q", 1_500_000_000)
                    + b"\x10" + gid)
    assert len(data) == 33
    with pytest.raises(ValueError):
        rmw.Attachment(1, 0, b"short").encode()
    for bad in (data[:-1], data + b"\x00", data[:16] + b"\x0f" + gid):
        with pytest.raises(ValueError):
            rmw.Attachment.decode(bad)


def test_the_sdks_attachment_reads_ours() -> None:
    sdk = pytest.importorskip("zenoh_ros2_sdk.attachment", reason="zenoh-ros2-sdk is not "
                              "installed (pip install zenoh-ros2-sdk)")
    ours = rmw.Attachment(42, 123, bytes(range(16, 32)))
    theirs = sdk.Attachment.from_bytes(ours.encode())
    assert (theirs.sequence_id, theirs.timestamp_ns, theirs.gid) == (42, 123, ours.gid)
    assert sdk.Attachment(42, 123, ours.gid).to_bytes() == ours.encode()


def test_bad_type_names_are_refused() -> None:
    for bad in ("Odometry", "nav_msgs/Odometry", "nav_msgs/msg/", "a/b/c/d"):
        with pytest.raises(ValueError):
            rmw.dds_type_name(bad)
    with pytest.raises(ValueError):
        rmw.ros_type_name("nav_msgs::msg::Odometry")
    with pytest.raises(ValueError):
        rmw.data_key(0, "odom", "nav_msgs/msg/Odometry", "RIHS01_x")


_ident = st.from_regex(r"[A-Za-z][A-Za-z0-9_]{0,12}", fullmatch=True)


@given(_ident, st.sampled_from(["msg", "srv"]), _ident)
def test_type_names_round_trip(package: str, kind: str, name: str) -> None:
    ros = f"{package}/{kind}/{name}"
    assert rmw.ros_type_name(rmw.dds_type_name(ros)) == ros


@given(st.lists(_ident, min_size=1, max_size=4))
def test_names_round_trip_through_mangling(chunks: list[str]) -> None:
    name = "/" + "/".join(chunks)
    mangled = rmw.mangle(name)
    assert "/" not in mangled and rmw.unmangle(mangled) == name


@given(st.sampled_from(list(rmw.Reliability)), st.sampled_from(list(rmw.Durability)),
       st.integers(0, 10_000))
def test_qos_round_trips(rel: rmw.Reliability, dur: rmw.Durability, depth: int) -> None:
    qos = rmw.Qos(rel, dur, depth)
    text = qos.encode()
    assert rmw.Qos.decode(text) == qos
    assert text.count(":") == 5 and "/" not in text


@given(st.integers(-(2**63), 2**63 - 1), st.integers(-(2**63), 2**63 - 1),
       st.binary(min_size=16, max_size=16))
def test_attachments_round_trip(seq: int, stamp: int, gid: bytes) -> None:
    a = rmw.Attachment(seq, stamp, gid)
    assert rmw.Attachment.decode(a.encode()) == a


@given(st.binary(max_size=64))
def test_any_bytes_decode_or_raise_value_error(data: bytes) -> None:
    try:
        a = rmw.Attachment.decode(data)
    except ValueError:
        return
    assert a.encode() == data


@given(st.lists(_ident, min_size=1, max_size=3), _ident, st.integers(0, 232))
def test_tokens_have_no_empty_chunk_and_name_the_endpoint(ns: list[str], node: str,
                                                          domain: int) -> None:
    n = rmw.RosNode(domain, "0123abcd", 0, node, namespace="/" + "/".join(ns))
    token = n.endpoint_token(1, rmw.Kind.PUBLISHER, rmw.fully_qualified(n.namespace, "odom"),
                             "nav_msgs/msg/Odometry", "RIHS01_x", rmw.Qos())
    chunks = token.split("/")
    assert "" not in chunks[:-1]  # the QoS string ends the key; it holds no '/'
    assert chunks[:6] == ["@ros2_lv", str(domain), "0123abcd", "0", "1", "MP"]
    assert rmw.unmangle(chunks[9]) == n.namespace + "/odom"
    assert rmw.gid_of(token) == rmw.gid_of(token) and len(rmw.gid_of(token)) == 16


@given(st.integers(0, 232), st.lists(_ident, min_size=1, max_size=4), _ident, _ident)
def test_a_data_key_gives_its_topic_back(domain: int, chunks: list[str], package: str,
                                          name: str) -> None:
    fq = "/" + "/".join(chunks)
    key = rmw.data_key(domain, fq, f"{package}/msg/{name}", "RIHS01_" + "0" * 64)
    assert rmw.topic_of(key) == fq


def test_a_key_without_a_name_is_not_a_data_key() -> None:
    with pytest.raises(ValueError, match="not an rmw_zenoh data key"):
        rmw.topic_of("0/std_msgs::msg::dds_::String_/RIHS01_x")
