"""The robot's state as messages (omnican.telemetry, pure: one builder for every front
end) and their CDR bytes (omnican.telemetry.cdr), checked against an independent decoder
(mcap_ros2)."""

from __future__ import annotations

import itertools
import math
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.records import Schema
from mcap_ros2.decoder import DecoderFactory

from omnican import default_config
from omnican.chassis.state import ChassisStatus, WheelState
from omnican.core.kinematics import Twist
from omnican.core.odometry import Pose2D
from omnican.protocol.cia402 import State
from omnican.telemetry import Telemetry, TelemetrySettings, cdr
from omnican.telemetry import messages as telemetry

finite = st.floats(-1e3, 1e3, allow_nan=False)
# The first encode builds rosbags' type store (a few hundred ms): no deadline here.
codec = settings(deadline=None)


def wheel(index: int, **kw: object) -> WheelState:
    fields: dict[str, object] = dict(
        index=index, node_id=index + 1, axis=0, state=State.OPERATION_ENABLED,
        statusword=0x1637, mode=3, target_speed=0.1, actual_speed=0.1, travel=0.5,
        online=True, fault=None, error=None)
    fields.update(kw)
    return WheelState(**fields)  # type: ignore[arg-type]


def status(**kw: object) -> ChassisStatus:
    fields: dict[str, object] = dict(
        enabled=True, stopped_reason=None, command_age_s=0.01, loop_hz=100.0,
        late_fraction=0.0, cycles=10, bus_load=0.2, bus_bits_per_s=1e5, bus_error=None,
        warnings=())
    fields.update(kw)
    return ChassisStatus(**fields)  # type: ignore[arg-type]


ORIGIN = Pose2D()


def sample(pose: Pose2D = ORIGIN, wheels: tuple[WheelState, ...] | None = None,
           **kw: object) -> telemetry.TelemetrySample:
    return telemetry.TelemetrySample(
        stamp_ns=1_700_000_000_123_456_789, pose=pose, twist=Twist(0.1, 0.2, 0.3),
        command=Twist(0.1, 0.2, 0.3), wheels=wheels or tuple(wheel(i) for i in range(3)),
        status=status(**kw))


CFG = default_config()
SETTINGS = TelemetrySettings.from_config(CFG)


def decoder(typename: str):  # type: ignore[no-untyped-def]
    schema = Schema(id=1, name=typename, encoding="ros2msg",
                    data=cdr.msgdef(typename).encode())
    return DecoderFactory().decoder_for("cdr", schema)


@codec
@given(x=finite, y=finite, theta=st.floats(-20, 20))
def test_odometry_pose_and_transform_agree_with_the_pose(x: float, y: float,
                                                         theta: float) -> None:
    s = sample(Pose2D(x, y, theta))
    pose_cov = [float(i) for i in range(36)]
    twist_cov = [float(-i) for i in range(36)]
    odo = decoder("nav_msgs/msg/Odometry")(cdr.encode(
        "nav_msgs/msg/Odometry", telemetry.odometry(s, SETTINGS, pose_cov, twist_cov)))
    q = odo.pose.pose.orientation
    yaw = math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y ** 2 + q.z ** 2))
    assert math.isclose(math.remainder(yaw - theta, math.tau), 0.0, abs_tol=1e-9)
    assert (odo.pose.pose.position.x, odo.pose.pose.position.y) == (x, y)
    assert (odo.header.frame_id, odo.child_frame_id) == ("odom", "base_link")
    assert (odo.header.stamp.sec, odo.header.stamp.nanosec) == (1_700_000_000, 123_456_789)
    assert (odo.twist.twist.linear.x, odo.twist.twist.linear.y,
            odo.twist.twist.angular.z) == (0.1, 0.2, 0.3)
    assert list(odo.pose.covariance) == pose_cov
    assert list(odo.twist.covariance) == twist_cov
    tf = decoder("tf2_msgs/msg/TFMessage")(cdr.encode("tf2_msgs/msg/TFMessage",
                                                         telemetry.transforms(s, SETTINGS)))
    (t,) = tf.transforms
    assert (t.header.frame_id, t.child_frame_id) == ("odom", "base_link")
    assert (t.transform.translation.x, t.transform.translation.y) == (x, y)
    r = t.transform.rotation
    assert (r.x, r.y, r.z, r.w) == (q.x, q.y, q.z, q.w)


def test_odom_covariance_is_the_propagated_one_and_grows_with_distance() -> None:
    model = Telemetry(SETTINGS, CFG.kinematics())
    variances = []
    for i in range(20):
        s = sample(Pose2D(0.05 * i, 0.0, 0.0))
        (odom,) = [m for m in model.messages(s) if m.topic == "/odom"]
        cov = odom.decoded()["pose"]["covariance"]
        variances.append(cov[0])
        assert cov[14] == cov[21] == cov[28] == 1e6  # z, roll, pitch: not observed
    assert variances[0] == 0.0
    assert all(b >= a for a, b in itertools.pairwise(variances))
    assert variances[-1] > 0.0


@codec
@given(travel=st.lists(finite, min_size=3, max_size=3),
       radius=st.floats(0.01, 1.0))
def test_joint_states_are_wheel_angles(travel: list[float], radius: float) -> None:
    s = sample(wheels=tuple(wheel(i, travel=t, actual_speed=t / 10)
                            for i, t in enumerate(travel)))
    settings_ = TelemetrySettings.from_config(CFG, wheel_radius=radius)
    js = telemetry.joint_states(s, settings_)
    assert js is not None
    msg = decoder("sensor_msgs/msg/JointState")(cdr.encode("sensor_msgs/msg/JointState", js))
    assert list(msg.name) == ["wheel_0_joint", "wheel_1_joint", "wheel_2_joint"]
    assert list(msg.position) == pytest.approx([t / radius for t in travel])
    assert list(msg.velocity) == pytest.approx([t / 10 / radius for t in travel])


def test_joint_states_use_the_configured_names_and_need_every_wheel_radius() -> None:
    from dataclasses import replace

    named = replace(CFG, front_ends={"ros2": {"joint_names": ["back", "right", "left"]}})
    js = telemetry.joint_states(sample(), TelemetrySettings.from_config(named))
    assert js is not None and js["name"] == ["back", "right", "left"]
    no_radius = replace(CFG, wheels=tuple(replace(w, wheel_radius=None) for w in CFG.wheels))
    assert telemetry.joint_states(sample(), TelemetrySettings.from_config(no_radius)) is None
    one_missing = replace(CFG, wheels=tuple(
        replace(w, wheel_radius=None) if i == 1 else w for i, w in enumerate(CFG.wheels)))
    assert telemetry.joint_states(sample(), TelemetrySettings.from_config(one_missing)) is None


def _levels(s: telemetry.TelemetrySample) -> dict[str, tuple[int, str]]:
    msg = decoder("diagnostic_msgs/msg/DiagnosticArray")(
        cdr.encode("diagnostic_msgs/msg/DiagnosticArray", telemetry.diagnostics(s, SETTINGS)))
    return {st.name: (ord(st.level) if isinstance(st.level, bytes) else st.level, st.message)
            for st in msg.status}


def test_diagnostics_stale_wheel_and_bus_down() -> None:
    s = sample(wheels=(wheel(0), wheel(1, stale=True, actual_speed=0.0), wheel(2)),
               bus_up=False, bus_error="send 0x080 failed: Network is down")
    levels = _levels(s)
    assert levels["omnican: wheel 1"] == (telemetry.WARN, "no fresh encoder sample")
    assert levels["omnican: CAN bus"] == (telemetry.ERROR,
                                          "bus down: send 0x080 failed: Network is down")
    assert telemetry.status(s)["bus_up"] is False
    assert [w["stale"] for w in telemetry.wheels(s)["wheels"]] == [False, True, False]


def test_diagnostics_levels_and_emcy_text() -> None:
    wheels = (wheel(0), wheel(1, state=State.FAULT, fault="0x2310 continuous over-current"),
              wheel(2, online=False))
    s = sample(wheels=wheels, stopped_reason="node 2 fault: 0x2310 continuous over-current",
               enabled=False)
    levels = _levels(s)
    assert levels["omnican: wheel 0"] == (telemetry.OK, "OPERATION ENABLED")
    assert levels["omnican: wheel 1"] == (
        telemetry.ERROR, "fault: 0x2310 continuous over-current")
    assert levels["omnican: wheel 2"] == (telemetry.ERROR, "offline (no heartbeat)")
    assert levels["omnican: chassis"] == (
        telemetry.ERROR,
        "stopped: node 2 fault: 0x2310 continuous over-current (recover to clear)")
    chassis = next(st for st in telemetry.diagnostics(s, SETTINGS)["status"]
                   if st["name"] == "omnican: chassis")
    assert {kv["key"]: kv["value"] for kv in chassis["values"]}["loop_hz"] == "100"


def test_diagnostics_once_a_period_and_at_once_on_a_change() -> None:
    model = Telemetry(SETTINGS, CFG.kinematics())

    def diag_at(ns: int, **kw: object) -> bool:
        s = telemetry.TelemetrySample(**{**sample(**kw).__dict__, "stamp_ns": ns})
        return any(m.topic == "/diagnostics" for m in model.messages(s))

    assert diag_at(0)
    assert not diag_at(20_000_000) and not diag_at(999_000_000)
    assert diag_at(1_000_000_000)  # a second later
    assert diag_at(1_020_000_000, stopped_reason="node 1 fault: x", enabled=False)  # a change
    assert not diag_at(1_040_000_000, stopped_reason="node 1 fault: x", enabled=False)


def test_every_state_topic_is_declared_and_encodes() -> None:
    s = telemetry.TelemetrySample(**{**sample(battery_v=23.9).__dict__, "true_pose": Pose2D(1, 2, 3),
                            "true_twist": Twist(1, 0, 0)})
    topics = {m.topic: m for m in Telemetry(SETTINGS, CFG.kinematics()).messages(s)}
    assert set(topics) == set(telemetry.TOPICS)
    for topic, message in topics.items():
        schema, kind = telemetry.TOPICS[topic]
        assert message.stamp_ns == s.stamp_ns
        if kind == telemetry.ROS2:
            assert decoder(schema)(message.payload()) is not None
        else:
            assert set(message.decoded()) <= set(telemetry.JSON_SCHEMAS[schema]["properties"])


@codec
@given(can_id=st.integers(0, 0x1FFFFFFF), data=st.binary(max_size=8),
       channel=st.text(st.characters(exclude_characters='\x00',
                                             exclude_categories=('Cs',)), max_size=30),
       ns=st.integers(0, 2**31 * 10**9 - 1),  # ROS time: int32 seconds
       flags=st.tuples(st.booleans(), st.booleans(), st.booleans()))
def test_fast_can_frame_codec_matches_the_generic_one(can_id: int, data: bytes, channel: str,
                                                       ns: int,
                                                       flags: tuple[bool, bool, bool]) -> None:
    extended, remote, error = flags
    fast = cdr.encode_can_frame(ns, can_id, data, channel, extended=extended, remote=remote,
                                   error=error)
    message = telemetry.can_frame(0.0, can_id, data, extended=extended, remote=remote,
                                  error=error, channel=channel)
    message["header"]["stamp"] = telemetry.stamp(ns)
    assert fast == cdr.encode(telemetry.CAN_FRAME, message)
    assert cdr.decode_can_frame(fast) == (ns, can_id, data, channel, extended, remote, error)
    independent = decoder(telemetry.CAN_FRAME)(fast)
    assert (independent.id, independent.dlc, bytes(independent.data)[:len(data)]) == (
        can_id, len(data), data)


# ---------------------------------------------------------------- what the drives know


def test_battery_state_is_the_dc_link_and_says_what_it_cannot_know() -> None:
    assert telemetry.battery_state(sample(), SETTINGS) is None  # no drive reports one
    for level, health in ((None, 0), ("ok", 1), ("low", 1), ("cutoff", 3)):
        msg = telemetry.battery_state(sample(battery_v=21.25, battery=level), SETTINGS)
        assert msg is not None
        assert msg["voltage"] == 21.25 and msg["power_supply_health"] == health
        assert msg["present"] and msg["header"]["frame_id"] == "base_link"
        assert all(math.isnan(msg[k]) for k in ("current", "charge", "percentage",
                                                 "temperature"))
        decoded = decoder("sensor_msgs/msg/BatteryState")(
            cdr.encode("sensor_msgs/msg/BatteryState", msg))
        assert decoded.voltage == pytest.approx(21.25) and decoded.power_supply_health == health


def test_each_wheels_health_goes_to_the_wheels_topic_and_its_diagnostics() -> None:
    w = wheel(1, current_a=1.5, torque_pct=30.0, voltage_v=23.9, temperature_c=41.2,
              error_register=0x05)
    s = sample(wheels=(wheel(0), w, wheel(2)))
    row = telemetry.wheels(s)["wheels"][1]
    assert (row["current_a"], row["torque_pct"], row["voltage_v"], row["temperature_c"]) == (
        1.5, 30.0, 23.9, 41.2)
    assert "current_a" not in telemetry.wheels(s)["wheels"][0]  # not given: absent
    diag = telemetry.wheel_status(w, "omnican", "wheel_1_joint")
    values = {kv["key"]: kv["value"] for kv in diag["values"]}
    assert (values["current_a"], values["voltage_v"], values["temperature_c"],
            values["error_register"]) == ("1.5", "23.9", "41.2", "0x05")


@pytest.mark.parametrize(("state", "level", "message"), [
    (None, telemetry.OK, "bus load 20%"),
    ("error-active", telemetry.OK, "bus load 20%"),
    ("error-warning", telemetry.WARN, "CAN error-warning (tx 97, rx 0)"),
    ("error-passive", telemetry.WARN, "CAN error-passive (tx 97, rx 0)"),
    ("bus-off", telemetry.ERROR, "CAN bus-off (tx 97, rx 0)")])
def test_the_can_controllers_state_is_in_the_bus_diagnostics(state: str | None, level: int,
                                                            message: str) -> None:
    st = status(can_state=state, can_tx_errors=97, can_rx_errors=0, can_error_frames=4)
    bus = telemetry.bus_status(st, "omnican", "can0")
    assert (bus["level"], bus["message"]) == (level, message)
    values = {kv["key"]: kv["value"] for kv in bus["values"]}
    assert values["tx_error_counter"] == "97" and values["error_frames"] == "4"
    json_status = telemetry.status(sample(can_state=state, estop=True, battery_v=20.5))
    assert json_status["can_state"] == (state or "") and json_status["estop"]
    assert json_status["battery_v"] == 20.5


# ---------------------------------------------------------------- what Foxglove's app reads

# The app's JSON schema parser (parseJsonSchema in Foxglove Studio's and Lichtblick's
# mcap-support; tests/interop/test_foxglove_app.py runs the app's own code): one type per field.
APP_FIELD_TYPES = {"boolean", "string", "number", "integer", "object", "array"}
APP_ITEM_TYPES = {"boolean", "string", "number", "integer", "object"}


def _app_rejects(schema: dict[str, Any], path: str = "") -> list[str]:
    """What the app's parser would refuse in an object schema, as "path: why"."""
    if schema.get("type") != "object":
        return [f"{path or '<root>'}: not an object"]
    bad: list[str] = []
    for name, field in schema["properties"].items():
        where = f"{path}.{name}" if path else name
        kind = field.get("type")
        if not isinstance(kind, str) or kind not in APP_FIELD_TYPES:
            bad.append(f"{where}: type {kind!r}")
        elif kind == "object":
            bad += _app_rejects(field, where)
        elif kind == "array":
            item = field["items"]
            if item.get("type") not in APP_ITEM_TYPES:
                bad.append(f"{where}[]: type {item.get('type')!r}")
            elif item["type"] == "object":
                bad += _app_rejects(item, where + "[]")
    return bad


def test_json_schemas_use_only_what_foxglove_parses() -> None:
    for name, schema in telemetry.JSON_SCHEMAS.items():
        assert _app_rejects(schema) == [], name


_JSON_TYPES = {"number": (int, float), "integer": (int,), "string": (str,),
               "boolean": (bool,), "object": (dict,), "array": (list,)}


def _conforms(given: Any, schema: dict[str, Any], path: str = "") -> list[str]:
    kind = schema["type"]
    assert isinstance(kind, str)
    if not isinstance(given, _JSON_TYPES[kind]) or (
            kind in ("number", "integer") and isinstance(given, bool)):
        return [f"{path}: {given!r} is not {kind}"]
    value: Any = given
    if kind == "number" and not math.isfinite(value):
        return [f"{path}: {value!r} (JSON has no NaN or infinity)"]
    if kind == "object":
        props = schema["properties"]
        return ([f"{path}.{k}: not in the schema" for k in value if k not in props]
                + [e for k, v in value.items() if k in props
                   for e in _conforms(v, props[k], f"{path}.{k}")])
    if kind == "array":
        return [e for i, v in enumerate(value)
                for e in _conforms(v, schema["items"], f"{path}[{i}]")]
    return []


maybe = st.none() | finite
maybe_count = st.none() | st.integers(0, 255)


@codec
@given(readings=st.lists(st.tuples(maybe, maybe, maybe, maybe, st.none() | st.integers(0, 0xFFFF)),
                         min_size=3, max_size=3),
       bus_load=st.none() | st.floats(0.0, 2.0), tx=maybe_count, rx=maybe_count,
       battery_v=maybe)
def test_json_messages_leave_out_what_is_not_measured(
        readings: list[tuple[float | None, ...]], bus_load: float | None, tx: int | None,
        rx: int | None, battery_v: float | None) -> None:
    """Every /wheels and /status message fits its schema (no null anywhere); a reading
    that is not there is an absent field, never a stand-in value such as -1."""
    wheels = tuple(wheel(i, current_a=c, torque_pct=t, voltage_v=v, temperature_c=k,
                         statusword=sw) for i, (c, t, v, k, sw) in enumerate(readings))
    s = sample(wheels=wheels, bus_load=bus_load, can_tx_errors=tx, can_rx_errors=rx,
               battery_v=battery_v)
    for topic, msg in (("/wheels", telemetry.wheels(s)), ("/status", telemetry.status(s))):
        schema = telemetry.JSON_SCHEMAS[telemetry.TOPICS[topic][0]]
        assert _conforms(msg, schema, topic) == []
    rows = telemetry.wheels(s)["wheels"]
    for row, (c, t, v, k, sw) in zip(rows, readings, strict=True):
        for key, given_ in (("current_a", c), ("torque_pct", t), ("voltage_v", v),
                            ("temperature_c", k), ("statusword", sw)):
            assert row.get(key) == given_ and (key in row) == (given_ is not None)
    st_ = telemetry.status(s)
    for key, given_ in (("bus_load", bus_load), ("can_tx_errors", tx),
                        ("can_rx_errors", rx), ("battery_v", battery_v)):
        assert st_.get(key) == given_ and (key in st_) == (given_ is not None)


def test_diagnostic_names_read_once_in_foxglove() -> None:
    """Foxglove lists a status as "hardware_id: name": the prefix appears once, and a
    bus without a bitrate (a virtual one, --sim) says its traffic rather than "unknown"."""
    statuses = telemetry.diagnostics(sample(bus_load=None, bus_bits_per_s=52_300.0),
                                     SETTINGS)["status"]
    shown = [f"{s['hardware_id']}: {s['name']}" if s["hardware_id"] else s["name"]
             for s in statuses]
    assert shown[0] == "omnican: chassis"
    assert all(text.count("omnican") == 1 for text in shown), shown
    assert shown[2:] == [f"canopen node {i + 1}: omnican: wheel {i}" for i in range(3)]
    bus = statuses[1]
    assert (bus["level"], bus["message"]) == (telemetry.OK, "52.3 kbit/s (no bitrate set)")
    values = {kv["key"]: kv["value"] for kv in statuses[2]["values"]}
    assert values["joint"] == "wheel_0_joint"  # the joint: in the values, not the name


def test_the_odometry_pose_and_path_so_far_go_out_as_the_3d_panel_draws_them() -> None:
    """/odom/pose each sample (a PoseStamped: the 3D panel draws no Odometry); /odom/path
    (nav_msgs/Path) every half second of the base's clock, with the run so far."""
    model = Telemetry(SETTINGS, CFG.kinematics())
    paths: list[tuple[int, object]] = []
    for i in range(100):  # 2 s at 50 Hz, 0.5 m/s along x
        ns = 1_700_000_000_000_000_000 + i * 20_000_000
        s = telemetry.TelemetrySample(**{**sample(Pose2D(0.01 * i, 0.0, 0.0)).__dict__, "stamp_ns": ns})
        out = {m.topic: m for m in model.messages(s)}
        pose = decoder("geometry_msgs/msg/PoseStamped")(out["/odom/pose"].payload())
        assert (pose.header.frame_id, pose.pose.position.x) == ("odom", pytest.approx(0.01 * i))
        if "/odom/path" in out:
            paths.append((i, decoder("nav_msgs/msg/Path")(out["/odom/path"].payload())))
    assert [i for i, _ in paths] == [0, 25, 50, 75]
    last = paths[-1][1]
    xs = [p.pose.position.x for p in last.poses]  # type: ignore[attr-defined]
    assert last.header.frame_id == "odom"  # type: ignore[attr-defined]
    assert xs[0] == 0.0 and 0.75 - xs[-1] < 0.02 + 1e-9  # up to the base, one spacing behind
    assert all(0.02 - 1e-9 < b - a < 0.03 + 1e-9 for a, b in itertools.pairwise(xs))


@codec
@given(points=st.lists(st.tuples(st.integers(0, 2**31 * 10**9 - 1), finite, finite,
                                 st.floats(-20, 20)), max_size=30),
       frame=st.text(st.characters(exclude_characters="\x00", exclude_categories=("Cs",)),
                     max_size=12),
       ns=st.integers(0, 2**31 * 10**9 - 1))
def test_fast_path_codec_matches_the_generic_one(points: list[tuple[int, float, float, float]],
                                                 frame: str, ns: int) -> None:
    """/odom/path's hundreds of poses are packed directly (the generic encoder holds the
    GIL for milliseconds): the same bytes, which an independent decoder reads back."""
    msg = telemetry.path(ns, [(t, Pose2D(x, y, th)) for t, x, y, th in points], frame)
    typename = "nav_msgs/msg/Path"
    fast = cdr.encode(typename, msg)
    generic = bytes(cdr.typestore().serialize_cdr(cdr._builder(typename)(msg), typename))
    assert fast == generic
    decoded = decoder(typename)(fast)
    assert [(p.pose.position.x, p.pose.position.y) for p in decoded.poses] == [
        (x, y) for _, x, y, _ in points]
