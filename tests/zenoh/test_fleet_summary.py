"""The fleet's pure parts: a base's summary made, timed and read back; a liveliness token
read back into its fields; a Trigger response read back."""

from __future__ import annotations

import json
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from omnican.errors import printable
from omnican.zenoh import rmw, summary
from omnican.zenoh.services import read_trigger_response, trigger_response

NUM = st.floats(allow_nan=False, allow_infinity=False, width=64)
TEXT = st.text(max_size=40)
STATES = st.sampled_from(["RUNNING", "STOPPED", "STARTING"])


def _twist(vx: float, vy: float, wz: float) -> dict[str, float]:
    return {"vx": vx, "vy": vy, "wz": wz}


@st.composite
def samples(draw: Any) -> dict[str, dict[str, Any]]:
    """The JSON data of one sample's /status, /wheels, /pose2d and /twist, as the
    telemetry model makes them (the fields a summary reads)."""
    status = {"state": draw(STATES), "stopped_reason": draw(TEXT), "enabled": draw(st.booleans()),
              "estop": draw(st.booleans())}
    battery = draw(st.none() | NUM)
    if battery is not None:
        status["battery_v"] = battery
    wheels = [{"index": i, "fault": draw(st.sampled_from(["", "0x2310 over-current"])),
               "error": draw(st.sampled_from(["", "SDO timeout"]))} for i in (1, 2, 3)]
    twist: dict[str, Any] = {"command": _twist(0, 0, 0),
                             "measured": _twist(draw(NUM), draw(NUM), draw(NUM))}
    if draw(st.booleans()):
        twist["true"] = _twist(draw(NUM), draw(NUM), draw(NUM))
    return {"/status": status, "/wheels": {"wheels": wheels},
            "/pose2d": {"x": draw(NUM), "y": draw(NUM), "theta": draw(NUM)}, "/twist": twist}


@given(samples(), st.integers(0, 2**62), st.none() | TEXT)
def test_a_summary_reads_back_as_composed(data: dict[str, Any], stamp_ns: int,
                                          driver: str | None) -> None:
    made = summary.compose(data, stamp_ns, node="/robot1/omnican", driver=driver,
                           period_s=0.5)
    read = summary.parse(json.dumps(made).encode())
    assert read.as_json() == shown(made)
    assert read.state == data["/status"]["state"]
    assert (read.battery_v is None) == ("battery_v" not in data["/status"])
    assert (read.true_speed is None) == ("true" not in data["/twist"])
    troubled = [w for w in data["/wheels"]["wheels"] if w["fault"] or w["error"]]
    assert [f.split(":")[0] for f in read.faults] == [f"wheel {w['index']}" for w in troubled]


def shown(made: dict[str, Any]) -> dict[str, Any]:
    """A summary's fields as a fleet view reads them: each text printable."""
    out = dict(made)
    for key in ("node", "state", "stopped_reason", "driver"):
        if key in out:
            out[key] = printable(out[key], summary.MAX_TEXT)
    out["faults"] = [printable(f, summary.MAX_TEXT) for f in out["faults"]]
    return out


NUMBERS = ("pose.x", "pose.y", "pose.theta", "speed.vx", "speed.vy", "speed.wz", "stamp",
           "period_s", "battery_v", "true_speed.vx", "true_speed.wz")


@given(samples(), st.sampled_from(NUMBERS),
       st.sampled_from(["NaN", "Infinity", "-Infinity", "1e999", "-1e400", "9" * 400]))
def test_a_number_json_or_a_float_cannot_hold_is_refused(
        data: dict[str, Any], where: str, number: str) -> None:
    """NaN and Infinity are not JSON (Python's json writes them; jq and JSON.parse refuse
    them), and a number too large for a float is infinite once read: a summary that
    holds one is refused, saying why, so a view's --json never carries one."""
    made = summary.compose(data, 0, node="/r/omnican", driver=None, period_s=0.5)
    made.setdefault("true_speed", {"vx": 0.0, "vy": 0.0, "wz": 0.0})
    made.setdefault("battery_v", 24.0)
    outer, _, inner = where.partition(".")
    if inner:
        made[outer][inner] = "HERE"
    else:
        made[outer] = "HERE"
    with pytest.raises(ValueError, match=r"JSON number|not a finite number|too large|"
                                          r"positive") as err:
        summary.parse(json.dumps(made).replace('"HERE"', number))
    assert str(err.value).isprintable()


@given(st.text(max_size=300))
def test_text_from_the_network_is_read_printable(text: str) -> None:
    made = summary.compose({"/status": {"state": text, "stopped_reason": text,
                                        "enabled": False, "estop": False},
                            "/wheels": {"wheels": [{"index": 1, "fault": text, "error": ""}]},
                            "/pose2d": {"x": 0, "y": 0, "theta": 0},
                            "/twist": {"measured": _twist(0, 0, 0)}},
                           0, node=text, driver=text or None, period_s=0.5)
    read = summary.parse(json.dumps(made))
    texts = [read.node, read.state, read.stopped_reason, read.driver or "", *read.faults]
    assert all(t.isprintable() for t in texts)
    assert read.stopped_reason == printable(text, summary.MAX_TEXT)


@given(st.text())
def test_a_string_cdr_reads_back(text: str) -> None:
    from omnican.zenoh.bridge import string_cdr

    data = string_cdr(text.encode())
    if len(data) <= summary.MAX_BYTES:
        assert summary.text_of(data) == text
    else:
        with pytest.raises(ValueError, match="more than a summary's"):
            summary.text_of(data)
    big_endian = b"\x00\x00" + data[2:4] + (len(text.encode()) + 1).to_bytes(4, "big") + \
        data[8:]
    if len(data) <= summary.MAX_BYTES:
        assert summary.text_of(big_endian) == text


@pytest.mark.parametrize("data", [b"", b"\x00\x01\x00\x00", b"\x00\x01\x00\x00\x05\x00\x00\x00ab",
                                  b"\x00\x01\x00\x00\x03\x00\x00\x00abc",
                                  b"\x00\x01\x00\x00\x02\x00\x00\x00\xff\x00",
                                  b"\x01\x01\x00\x00\x02\x00\x00\x00a\x00"])
def test_what_is_not_a_string_cdr_is_refused(data: bytes) -> None:
    with pytest.raises(ValueError):
        summary.text_of(data)


def test_a_summary_nested_too_deeply_is_refused_not_raised() -> None:
    with pytest.raises(ValueError, match="nested too deeply"):
        summary.parse("[" * 100_000 + "]" * 100_000)


def test_faults_name_the_wheel_and_its_trouble() -> None:
    wheels = {"wheels": [{"index": 1, "fault": "", "error": ""},
                         {"index": 2, "fault": "0x2310 continuous over-current", "error": ""},
                         {"index": 3, "fault": "", "error": "heartbeat lost"}]}
    assert summary.faults(wheels) == ["wheel 2: 0x2310 continuous over-current",
                                      "wheel 3: heartbeat lost"]


@given(samples(), samples())
def test_one_a_period_and_at_once_on_a_change(first: dict[str, Any],
                                              second: dict[str, Any]) -> None:
    period_ns = 500_000_000
    s = summary.Summarizer("/robot1/omnican", 0.5)
    assert s.offer(first, 10**9, None) is not None  # the first goes at once
    changed = summary.signature(summary.compose(first, 0, node="", driver=None, period_s=1)) \
        != summary.signature(summary.compose(second, 0, node="", driver=None, period_s=1))
    got = s.offer(second, 10**9 + period_ns // 2, None)
    assert (got is not None) == changed
    assert s.offer(second, 10**9 + 2 * period_ns, None) is not None  # a period later


def test_no_summary_without_the_bases_state() -> None:
    s = summary.Summarizer("/n", 0.5)
    assert s.offer({"/pose2d": {"x": 0, "y": 0, "theta": 0}}, 0, None) is None
    with pytest.raises(ValueError):
        summary.Summarizer("/n", 0.0)


@pytest.mark.parametrize(("text", "why"), [
    (b"\xff", "not JSON"), (b"[1]", "not a JSON object"), (b"{}", "faults is not a list"),
    (b'{"faults": [], "period_s": -1}', "period_s is not a positive number"),
    (b'{"faults": [], "period_s": NaN}', "not JSON: NaN is not a JSON number"),
    (b'{"faults": [], "period_s": 1e999}', "period_s is not a finite number: inf"),
    (b'{"faults": [], "period_s": 1, "node": 3}', "node is not text"),
])
def test_a_malformed_summary_says_what_is_wrong(text: bytes, why: str) -> None:
    with pytest.raises(ValueError, match=why):
        summary.parse(text)


def test_long_text_from_the_network_is_cut() -> None:
    made = summary.compose({"/status": {"state": "STOPPED", "stopped_reason": "x" * 5000,
                                        "enabled": False, "estop": False},
                            "/wheels": {"wheels": [{"index": i, "fault": "f", "error": ""}
                                                   for i in range(40)]},
                            "/pose2d": {"x": 0, "y": 0, "theta": 0},
                            "/twist": {"measured": _twist(0, 0, 0)}},
                           0, node="/n", driver=None, period_s=0.5)
    read = summary.parse(json.dumps(made))
    assert read.stopped_reason == "x" * summary.MAX_TEXT + "... (5000 characters)"
    assert len(read.faults) == summary.MAX_FAULTS


# ------------------------------------------------------------------ tokens

CHUNK = st.from_regex(r"[A-Za-z_][A-Za-z0-9_]{0,8}", fullmatch=True)
NAMESPACES = st.lists(CHUNK, max_size=3).map(lambda cs: "/" + "/".join(cs))
HASH = st.binary(min_size=32, max_size=32).map(lambda b: "RIHS01_" + b.hex())
QOS = st.builds(rmw.Qos, st.sampled_from(rmw.Reliability), st.sampled_from(rmw.Durability),
                st.integers(1, 1000))
NODES = st.builds(rmw.RosNode, st.integers(0, 232), st.binary(min_size=16, max_size=16).map(
    bytes.hex), st.integers(0, 99), CHUNK, NAMESPACES, NAMESPACES)
TYPES = st.sampled_from(["std_msgs/msg/String", "nav_msgs/msg/Odometry",
                         "std_srvs/srv/Trigger"])


@given(NODES, st.integers(1, 10**6), st.sampled_from([k for k in rmw.Kind
                                                     if k is not rmw.Kind.NODE]),
       NAMESPACES, CHUNK, TYPES, HASH, QOS)
def test_tokens_read_back_into_their_fields(node: rmw.RosNode, entity_id: int, kind: rmw.Kind,
                                            ns: str, name: str, type_name: str, hash_: str,
                                            qos: rmw.Qos) -> None:
    fq = rmw.fully_qualified(ns, name)
    key = node.endpoint_token(entity_id, kind, fq, type_name, hash_, qos)
    token = rmw.parse_token(key)
    assert token == rmw.Token(node, entity_id, kind, fq, type_name, hash_, qos)
    assert token.node_name == rmw.fully_qualified(node.namespace, node.name)
    own = rmw.parse_token(node.token())
    assert (own.node, own.kind, own.entity_id) == (node, rmw.Kind.NODE, node.node_id)


def test_the_design_documents_tokens_read_back() -> None:
    """An empty namespace and enclave (``%``) read back as ``/``: the same token."""
    key = "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/10/MS/%/%/listener/%chatter/" \
          "std_msgs::msg::dds_::String_/RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021" \
          "743503259e948f6b1a18/::,10:,:,:,,"
    token = rmw.parse_token(key)
    assert (token.node.namespace, token.node.name, token.name, token.type_name) == \
        ("/", "listener", "/chatter", "std_msgs/msg/String")
    assert token.node.endpoint_token(10, token.kind, token.name, token.type_name,
                                     token.hash_, token.qos) == key
    assert token.node_name == "/listener"


@pytest.mark.parametrize("key", [
    "", "@ros2_lv", "0/chatter/std_msgs::msg::dds_::String_/RIHS01_00",
    "@ros2_lv/0/ab/0/0/XX/%/%/n",  # no such kind
    "@ros2_lv/0/ab/0/0/MP/%/%/n",  # a publisher without its topic
    "@ros2_lv/x/ab/0/0/NN/%/%/n",
    "@ros2_lv/0/ab/0/1/MP/%/%/n/%t/std_msgs::msg::dds_::String_/RIHS01_00/::,10:,:,:,,",
    "@ros2_lv/0/ab/0/1/MP/%/%/n/%t/std_msgs::msg::String/RIHS01_" + "0" * 64 + "/::,:,:,:,,",
])
def test_what_is_not_a_token_is_refused(key: str) -> None:
    with pytest.raises(ValueError):
        rmw.parse_token(key)


# ------------------------------------------------------------------ Trigger answers


@given(st.booleans(), TEXT)
def test_trigger_responses_read_back(success: bool, message: str) -> None:
    assert read_trigger_response(trigger_response(success, message)) == \
        (success, message.encode("utf-8", "replace").decode())


@pytest.mark.parametrize("data", [b"", b"\x00\x01\x00\x00\x01\x00\x00\x00",
                                  b"\x00\x01\x00\x00\x01\x00\x00\x00\x09\x00\x00\x00ab\x00",
                                  b"\x00\x01\x00\x00\x01\x00\x00\x00\x02\x00\x00\x00abc"])
def test_what_is_not_a_trigger_response_is_refused(data: bytes) -> None:
    with pytest.raises(ValueError):
        read_trigger_response(data)


@given(st.text())
def test_a_json_topic_travels_as_the_string_ros_encodes(text: str) -> None:
    """The bridge writes std_msgs/msg/String's CDR directly: the same bytes as the ROS
    type store's encoding, which reads it back."""
    pytest.importorskip("rosbags", reason="needs the zenoh extra")
    from omnican.telemetry import cdr
    from omnican.zenoh.bridge import STRING, string_cdr

    data = text.encode()
    assert string_cdr(data) == cdr.encode(STRING, {"data": text})
    assert cdr.decode(STRING, string_cdr(data))["data"] == text
