"""Driving from Foxglove, the parts that need no other process: reading a Twist, the
control's rules against a stand-in base, the relay (either name of the protocol, TLS)
and the settings. The arbiter (one controller at a time) is tests/chassis/test_arbiter.py;
the same paths across processes, with Foxglove's own client,
tests/interop/test_foxglove_node.py."""

from __future__ import annotations

import json
import logging
import math
import shutil
import ssl
import string
import subprocess
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
from hypothesis import example, given
from hypothesis import strategies as st

from omnican import Pose2D, Twist, default_config
from omnican.chassis.arbiter import CommandArbiter, CommandSource
from omnican.config import ChassisSettings, load_config, with_live_limits
from omnican.core.limits import top_speeds
from omnican.errors import ConfigError, quote
from omnican.live.control import Control
from omnican.live.relay import (
    GRANT_CHANNEL_ID,
    GRANT_PREFIX,
    given_token,
    offered_subprotocols,
    rewrite_protocol,
    without_query,
)
from omnican.live.requests import decode_twist, parameter_value
from omnican.live.settings import FoxgloveSettings, check_token, resolve
from omnican.live.view import describe_control
from omnican.telemetry import cdr
from omnican.telemetry.attach import simulator_feed
from tests.support.helpers import one_error_line

# ---------------------------------------------------------------- reading a Twist


def _twist_json(**fields: Any) -> bytes:
    return json.dumps(fields).encode()


def test_twists_are_read_from_json_and_cdr_stamped_or_not() -> None:
    msg = {"linear": {"x": 0.3, "y": -0.1, "z": 9.0}, "angular": {"x": 9.0, "y": 9.0, "z": 0.5}}
    expected = Twist(0.3, -0.1, 0.5)  # z, roll and pitch are not the base's
    assert decode_twist("json", "geometry_msgs/Twist", json.dumps(msg).encode()) == expected
    assert decode_twist("cdr", "geometry_msgs/msg/Twist",
                        cdr.encode("geometry_msgs/msg/Twist", msg)) == expected
    stamped = {"header": {"stamp": {"sec": 1, "nanosec": 2}, "frame_id": "base_link"},
               "twist": msg}
    assert decode_twist("json", "geometry_msgs/msg/TwistStamped",
                        json.dumps(stamped).encode()) == expected
    assert decode_twist("cdr", "geometry_msgs/TwistStamped",
                        cdr.encode("geometry_msgs/msg/TwistStamped", stamped)) == expected
    # A field left out is zero (a hand-written publisher may send only what it uses).
    assert decode_twist("json", "geometry_msgs/Twist",
                        _twist_json(linear={"x": 0.2})) == Twist(0.2, 0.0, 0.0)


@pytest.mark.parametrize(("encoding", "schema", "data", "why"), [
    ("json", "geometry_msgs/Twist", b'{"linear": {"x": NaN}}', "not a finite number: NaN"),
    ("json", "geometry_msgs/Twist", b'{"angular": {"z": -Infinity}}',
     "not a finite number: -Infinity"),
    ("json", "geometry_msgs/Twist", b'{"linear": {"x": null}}',
     "linear.x must be a number, got None"),
    ("json", "geometry_msgs/Twist", b'{"linear": {"y": true}}',
     "linear.y must be a number, got True"),
    ("json", "geometry_msgs/Twist", b'{"linear": {"x": 1e400}}', "linear.x must be finite"),
    ("json", "geometry_msgs/Twist", b'{"linear": [1, 2, 3]}', "linear must be an object"),
    ("json", "geometry_msgs/Twist", b'[0.1, 0, 0]', "want an object with linear and angular"),
    ("json", "geometry_msgs/Twist", b'{"linear": ', "not JSON"),
    ("json", "std_msgs/String", b'{"data": "go"}', "want geometry_msgs/Twist, got 'std_msgs/String'"),
    ("ros1", "geometry_msgs/Twist", b"\x00" * 48, "cannot read 'ros1' messages"),
    ("cdr", "geometry_msgs/Twist", b"\x00\x01\x00\x00\x00", "not a CDR geometry_msgs/msg/Twist"),
])
def test_a_twist_that_cannot_be_obeyed_is_refused_with_the_reason(
        encoding: str, schema: str, data: bytes, why: str) -> None:
    with pytest.raises(ValueError) as info:
        decode_twist(encoding, schema, data)
    assert why in str(info.value)


def test_a_cdr_nan_is_refused() -> None:
    msg = {"linear": {"x": 0.1, "y": math.nan, "z": 0.0}, "angular": {"x": 0, "y": 0, "z": 0}}
    with pytest.raises(ValueError, match=r"linear\.y must be finite, got nan"):
        decode_twist("cdr", "geometry_msgs/msg/Twist", cdr.encode("geometry_msgs/msg/Twist",
                                                                     msg))


def test_parameter_values_as_the_parameters_panel_sends_them() -> None:
    assert parameter_value("p", 0.5) == 0.5 and parameter_value("p", 2) == 2
    assert parameter_value("p", "inf") == math.inf and parameter_value("p", " 0.25 ") == 0.25
    for bad in ("fast", "nan", True, None, [1.0]):
        with pytest.raises(ValueError, match="p: must be a number"):
            parameter_value("p", bad)


# ---------------------------------------------------------------- the control's rules


@dataclass
class StandInBase:
    """What Control calls on a Chassis, recorded."""

    cfg: Any = field(default_factory=default_config)
    calls: list[tuple[str, Any]] = field(default_factory=list)
    time: float = 0.0
    recover_fails: str | None = None
    timeout_s: float = 0.5  # the command timeout: how long a silent driver holds control
    arbiter: CommandArbiter = field(init=False)

    def __post_init__(self) -> None:
        self.arbiter = CommandArbiter(self.timeout_s)

    @property
    def clock(self) -> Any:
        return SimpleNamespace(now=lambda: self.time)

    def command_source(self, name: str) -> CommandSource:
        return CommandSource(self, self.arbiter, name)

    def set_twist(self, t: Twist) -> None:
        self.calls.append(("velocity", (t.vx, t.vy, t.wz)))

    def stop(self) -> None:
        self.calls.append(("stop", None))

    def recover(self) -> None:
        from omnican.errors import DriveError

        if self.recover_fails:
            raise DriveError(self.recover_fails)
        self.calls.append(("recover", None))

    def reset_pose(self, pose: Pose2D) -> None:
        self.calls.append(("reset_pose", pose))

    def set_limits(self, **changes: float) -> ChassisSettings:
        settings = with_live_limits(self.cfg.chassis, changes)
        self.cfg = replace(self.cfg, chassis=settings)
        self.calls.append(("limits", changes))
        return settings


def client(n: int) -> Any:
    return SimpleNamespace(id=n)


def channel(n: int, topic: str = "/cmd_vel", encoding: str = "json",
            schema: str = "geometry_msgs/Twist") -> Any:
    return SimpleNamespace(id=n, topic=topic, encoding=encoding, schema_name=schema)


def twist(vx: float = 0.0, wz: float = 0.0) -> bytes:
    return _twist_json(linear={"x": vx, "y": 0, "z": 0}, angular={"x": 0, "y": 0, "z": wz})


def vouch(c: Control, n: int) -> None:
    """What the relay does for a client that may drive: its first message advertises a
    channel named by a key the control gave it."""
    c.on_client_advertise(client(n), channel(GRANT_CHANNEL_ID, topic=GRANT_PREFIX + c.grant()))


def control(base: StandInBase, vouched: tuple[int, ...] = (1, 2, 3)) -> Control:
    """A Control whose clients ``vouched`` came in through the relay and may drive."""
    c = Control(base, FoxgloveSettings(control=True))
    for n in vouched:
        vouch(c, n)
    return c


def test_only_the_controller_moves_the_base_and_its_leaving_stops_it() -> None:
    base = StandInBase()
    c = control(base)
    for n in (1, 2):
        c.on_client_advertise(client(n), channel(10 + n))
    c.on_client_advertise(client(3), channel(13, topic="/other"))
    c.on_message_data(client(1), 11, twist(0.2))
    c.on_message_data(client(2), 12, twist(wz=1.0))  # refused: 1 drives
    c.on_message_data(client(3), 13, twist(0.9))  # not the control topic
    assert base.calls == [("velocity", (0.2, 0.0, 0.0))]
    assert (c.twists, c.refused) == (1, 1)
    c.on_client_unadvertise(client(2), 12)  # the refused one leaves: nothing happens
    c.on_client_unadvertise(client(3), 13)
    assert base.calls == [("velocity", (0.2, 0.0, 0.0))]
    c.on_client_unadvertise(client(1), 11)  # the driver leaves: the base stops now
    assert base.calls[-1] == ("stop", None)
    assert base.arbiter.holder(base.time) is None


def test_the_driver_with_two_panels_keeps_control_until_its_last_one_goes() -> None:
    base = StandInBase()
    c = control(base)
    c.on_client_advertise(client(1), channel(1))
    c.on_client_advertise(client(1), channel(2, encoding="cdr"))
    c.on_message_data(client(1), 1, twist(0.1))
    c.on_client_unadvertise(client(1), 1)
    assert ("stop", None) not in base.calls
    c.on_client_unadvertise(client(1), 2)
    assert base.calls[-1] == ("stop", None)


def test_a_silent_driver_gives_control_up_after_the_command_timeout() -> None:
    base = StandInBase()
    c = control(base)
    c.on_client_advertise(client(1), channel(1))
    c.on_client_advertise(client(2), channel(2))
    c.on_message_data(client(1), 1, twist(0.2))
    base.time = 0.4
    c.on_message_data(client(2), 2, twist(0.5))
    base.time = 0.91  # 1 silent for 0.51 s: the base stopped by itself, control is free
    c.on_message_data(client(2), 2, twist(0.5))
    assert base.calls == [("velocity", (0.2, 0.0, 0.0)), ("velocity", (0.5, 0.0, 0.0))]


def test_a_bad_twist_stops_the_base_only_when_it_is_the_drivers() -> None:
    base = StandInBase()
    c = control(base)
    c.on_client_advertise(client(1), channel(1))
    c.on_client_advertise(client(2), channel(2))
    c.on_message_data(client(1), 1, twist(0.2))
    c.on_message_data(client(2), 2, b'{"linear": {"x": NaN}}')
    assert base.calls == [("velocity", (0.2, 0.0, 0.0))]  # someone else's garbage: ignored
    c.on_message_data(client(1), 1, b'{"linear": {"x": NaN}}')
    assert base.calls[-1] == ("stop", None)
    assert c.refused == 2


def call(c: Control, name: str, client_id: int, body: Any = None) -> dict[str, Any]:
    service = next(s for s in c._services(__import__("foxglove")) if s.name == name)
    payload = b"" if body is None else json.dumps(body).encode()
    request = SimpleNamespace(encoding="json", payload=payload, client_id=client_id)
    reply: dict[str, Any] = json.loads(service.handler(request))
    return reply


def test_while_one_drives_others_may_only_stop() -> None:
    pytest.importorskip("foxglove", reason="needs the foxglove extra")
    base = StandInBase()
    c = control(base)
    c.on_client_advertise(client(1), channel(1))
    c.on_message_data(client(1), 1, twist(0.2))
    for name, body in (("/omnican/recover", None), ("/omnican/reset_odometry", {"x": 1})):
        reply = call(c, name, 2, body)
        assert reply["success"] is False
        assert reply["message"].startswith("Foxglove client 1 is driving")
    assert call(c, "/omnican/stop", 2) == {
        "success": True, "message": "stopping; Foxglove client 1 drives again once it has "
                                    "let go"}
    c.on_message_data(client(1), 1, twist(0.2))  # still pressing: refused
    assert [k for k, _ in base.calls] == ["velocity", "stop"]
    base.time = 0.6  # let go for 0.6 s: it drives again
    c.on_message_data(client(1), 1, twist(0.2))
    assert [k for k, _ in base.calls] == ["velocity", "stop", "velocity"]
    before = base.cfg.chassis
    assert c.on_set_parameters(client(2), [SimpleNamespace(name="chassis.max_speed",
                                                           get_value=lambda: 0.1)])
    assert base.cfg.chassis is before  # refused: 1 drives
    # The driver may.
    assert call(c, "/omnican/reset_odometry", 1, {"x": 1, "theta": 0.5})["success"]
    assert call(c, "/omnican/recover", 1)["success"]
    c.on_set_parameters(client(1), [SimpleNamespace(name="chassis.max_speed",
                                                    get_value=lambda: 0.1)])
    assert base.cfg.chassis.max_speed == 0.1
    assert [k for k, _ in base.calls] == ["velocity", "stop", "velocity", "reset_pose",
                                          "recover", "limits"]
    assert base.calls[3] == ("reset_pose", Pose2D(1.0, 0.0, 0.5))


def test_services_refuse_what_they_cannot_do_and_say_why() -> None:
    pytest.importorskip("foxglove", reason="needs the foxglove extra")
    base = StandInBase(recover_fails="node 2: still in FAULT")
    c = control(base)
    assert call(c, "/omnican/recover", 1) == {"success": False,
                                              "message": "recover failed: node 2: still in FAULT"}
    assert call(c, "/omnican/reset_odometry", 1, {"x": "far"}) == {
        "success": False, "message": "x must be a number, got 'far'"}
    assert call(c, "/omnican/reset_odometry", 1, {"z": 1}) == {
        "success": False, "message": "unknown field 'z' (x, y, theta)"}
    assert call(c, "/omnican/reset_odometry", 1) == {
        "success": True, "message": "odometry reset to x=0 y=0 theta=0"}
    with pytest.raises(ValueError, match="takes a JSON object"):
        call(c, "/omnican/stop", 1, [1, 2])
    assert "/omnican/sim/console" not in c.service_names()  # no simulator, no console


def test_parameters_read_as_config_keys_and_refusals_keep_the_value() -> None:
    pytest.importorskip("foxglove", reason="needs the foxglove extra")
    base = StandInBase()
    c = control(base)
    values = {p.name: p.get_value() for p in c.on_get_parameters(client(1), [])}
    # The unlimited speeds read as numbers (Foxglove's panel shows a text value as text):
    # the top speeds the wheel limit allows, 1 m/s at the rim of the b21 base of 0.19 m.
    assert values == {"chassis.max_speed": pytest.approx(4 / 3),
                      "chassis.max_angular_speed": pytest.approx(1.0 / 0.19),
                      "chassis.max_accel": 1.0, "chassis.max_angular_accel": 3.0,
                      "chassis.stop_decel": 2.0, "chassis.stop_angular_decel": 6.0,
                      "chassis.max_wheel_speed": 1.0}
    assert all(type(v) is float for v in values.values())
    [p] = c.on_set_parameters(client(1), [SimpleNamespace(name="chassis.max_accel",
                                                          get_value=lambda: 0)])
    assert (p.name, p.get_value()) == ("chassis.max_accel", 1.0)
    [p] = c.on_set_parameters(client(1), [SimpleNamespace(name="chassis.max_speed",
                                                          get_value=lambda: "0.4")])
    assert p.get_value() == 0.4
    assert c.on_set_parameters(client(1), [SimpleNamespace(name="chassis.rate_hz",
                                                           get_value=lambda: 5.0)]) == []
    assert base.cfg.chassis.rate_hz == 100.0


def test_an_unlimited_speed_reads_as_the_top_speed_and_round_trips() -> None:
    """An unlimited max_speed shows the speed the base can reach under its other limits;
    a client that sets the value it read back changes nothing the base does, and a lower
    wheel limit lowers what it reads."""
    pytest.importorskip("foxglove", reason="needs the foxglove extra")
    base = StandInBase()
    c = control(base)
    top = _set(c, 1, "chassis.max_angular_speed", 1e9)  # faster: refused, reads as before
    assert top == pytest.approx(1.0 / 0.19) and base.cfg.chassis.max_angular_speed == math.inf
    shown = {p.name: p.get_value() for p in c.on_get_parameters(client(1), [])}
    before = base.cfg.limits()
    assert _set(c, 1, "chassis.max_speed", shown["chassis.max_speed"]) == shown["chassis.max_speed"]
    assert base.cfg.chassis.max_speed == pytest.approx(4 / 3)  # now a number, the same top
    assert top_speeds(base.cfg.limits(), base.cfg.kinematics()) == pytest.approx(
        top_speeds(before, base.cfg.kinematics()))
    assert _set(c, 1, "chassis.max_wheel_speed", 0.5) == 0.5
    assert _set(c, 1, "chassis.max_angular_speed", "inf") == pytest.approx(0.5 / 0.19)
    assert base.cfg.chassis.max_angular_speed == math.inf


# ---------------------------------------------------------------- abusive clients


@dataclass
class StatusBoard:
    """The SDK server's status messages, as Control sends them (to every client)."""

    sent: list[str] = field(default_factory=list)

    def publish_status(self, message: str, level: Any, status_id: str) -> None:
        self.sent.append(message)

    def remove_status(self, ids: list[str]) -> None:
        pass


def attached(c: Control) -> StatusBoard:
    board = StatusBoard()
    c._server, c._status_level = board, SimpleNamespace(Info="info", Warning="warning")
    return board


def test_a_client_the_relay_did_not_vouch_for_may_watch_only() -> None:
    """No key from the relay (a client without the token, or one on the SDK's own port):
    its Twists, service calls and parameter changes do nothing and it is told why; a key
    the control did not give, or one used before, vouches for no one."""
    pytest.importorskip("foxglove", reason="needs the foxglove extra")
    base = StandInBase()
    c = control(base, vouched=(1,))
    board = attached(c)
    c.on_client_advertise(client(2), channel(GRANT_CHANNEL_ID, topic=GRANT_PREFIX + "0" * 32))
    key = c.grant()
    vouch_3 = channel(GRANT_CHANNEL_ID, topic=GRANT_PREFIX + key)
    c.on_client_advertise(client(3), vouch_3)
    c.on_client_advertise(client(4), vouch_3)  # the same key again: used up
    assert [c.may_drive(n) for n in (1, 2, 3, 4)] == [True, False, True, False]
    for n in (2, 4):
        c.on_client_advertise(client(n), channel(n))
        c.on_message_data(client(n), n, twist(0.3))
        with pytest.raises(ValueError, match=f"Foxglove client {n} may watch, not call "
                                             "/omnican/stop"):
            call(c, "/omnican/stop", n)
        assert c.on_set_parameters(client(n), [SimpleNamespace(
            name="chassis.max_speed", get_value=lambda: 0.1)])[0].get_value() == 4 / 3
    assert base.calls == [] and base.cfg.chassis.max_speed == math.inf
    assert any("Foxglove client 2 may watch, not drive" in m for m in board.sent)
    assert {p.name for p in c.on_get_parameters(client(2), [])} >= {"chassis.max_speed"}
    c.on_client_unadvertise(client(3), GRANT_CHANNEL_ID)  # it left: its id vouches no more
    assert not c.may_drive(3)
    c.on_client_advertise(client(1), channel(1))
    c.on_message_data(client(1), 1, twist(0.2))
    assert base.calls == [("velocity", (0.2, 0.0, 0.0))]


def test_the_token_is_named_to_a_client_that_did_not_give_it() -> None:
    base = StandInBase()
    c = Control(base, FoxgloveSettings(control=True, token="s3cret"))
    board = attached(c)
    c.on_client_advertise(client(1), channel(1))
    c.on_message_data(client(1), 1, twist(0.3))
    assert board.sent == ["Foxglove client 1 may watch, not drive: only a client that "
                          "connects with the token (ws://HOST:PORT/?token=...) through "
                          "omnican's port may"]
    assert "s3cret" not in board.sent[0]


def test_an_oversized_message_is_refused_before_it_is_read(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A 16 MB Twist or service request is not parsed at all (json.loads never sees it):
    from a bystander it is ignored, from the driver it stops the base, as other junk."""
    pytest.importorskip("foxglove", reason="needs the foxglove extra")
    base = StandInBase()
    c = control(base)
    board = attached(c)
    for n in (1, 2):
        c.on_client_advertise(client(n), channel(n))
    c.on_client_advertise(client(3), channel(3, encoding="cdr"))
    c.on_message_data(client(1), 1, twist(0.2))
    read: list[int] = []
    real_loads = json.loads

    def loads(data: Any, **kw: Any) -> Any:
        read.append(len(data))
        return real_loads(data, **kw)

    monkeypatch.setattr(json, "loads", loads)
    huge = b'{"linear": {"x": 0.1}, "pad": "' + b"x" * (16 << 20) + b'"}'
    c.on_message_data(client(2), 2, huge)
    c.on_message_data(client(3), 3, b"\x00" * (16 << 20))
    assert base.calls == [("velocity", (0.2, 0.0, 0.0))]
    c.on_message_data(client(1), 1, huge)
    assert base.calls[-1] == ("stop", None)
    with pytest.raises(ValueError, match=r"/omnican/reset_odometry: a request of 16777\d+ "
                                         r"bytes \(at most 4096\): not read"):
        call(c, "/omnican/reset_odometry", 1, {"x": 1.0, "pad": "x" * (16 << 20)})
    assert read == []
    assert all(len(m) < 300 for m in board.sent)
    assert any("a message of 16777" in m and "the base stops" in m for m in board.sent)


@pytest.mark.parametrize(("data", "why"), [
    (b"[" * 4000, "nested too deeply"), (b'{"":' * 1020, "nested too deeply"),
    (b"[" * 100_000, "not read"), (b'{"linear":' * 50_000, "not read")])
def test_deep_nesting_is_junk_like_any_other(data: bytes, why: str) -> None:
    """JSON nested deeper than Python's parser goes (a RecursionError inside json) is a
    Twist that cannot be read: ignored from a bystander, a stop at once from the driver;
    a service answers why. (Deeper still, it is too long to be read at all.)"""
    pytest.importorskip("foxglove", reason="needs the foxglove extra")
    base = StandInBase()
    c = control(base)
    c.on_client_advertise(client(1), channel(1))
    c.on_client_advertise(client(2), channel(2, schema="geometry_msgs/TwistStamped"))
    c.on_message_data(client(1), 1, twist(0.2))
    c.on_message_data(client(2), 2, data)
    assert base.calls == [("velocity", (0.2, 0.0, 0.0))]
    c.on_message_data(client(1), 1, data)
    assert base.calls[-1] == ("stop", None)
    with pytest.raises(ValueError, match=why):
        service = next(s for s in c._services(__import__("foxglove"))
                       if s.name == "/omnican/reset_odometry")
        service.handler(SimpleNamespace(encoding="json", payload=data, client_id=1))


def test_a_long_bad_value_is_quoted_short_everywhere(caplog: pytest.LogCaptureFixture) -> None:
    """A megabyte of a bad value comes back as a short prefix: in the log, in the status
    message every client sees and in a service's answer."""
    pytest.importorskip("foxglove", reason="needs the foxglove extra")
    base = StandInBase()
    c = control(base)
    board = attached(c)
    mega = "9" * 1_000_000 + "x"
    caplog.set_level(logging.INFO)
    c.on_set_parameters(client(1), [SimpleNamespace(name="chassis.max_speed",
                                                    get_value=lambda: mega)])
    c.on_set_parameters(client(1), [SimpleNamespace(name="chassis." + mega,
                                                    get_value=lambda: 1.0)])
    c.on_client_advertise(client(1), channel(1, schema=mega))
    c.on_message_data(client(1), 1, twist(0.2))
    c.on_client_advertise(client(2), channel(2))
    c.on_message_data(client(2), 2, json.dumps({"linear": "y" * 3000}).encode())
    for body in ({"x": "z" * 3000}, {"w" * 3000: 1}, ["v" * 3000]):
        service = next(s for s in c._services(__import__("foxglove"))
                       if s.name == "/omnican/reset_odometry")
        request = SimpleNamespace(encoding="json", payload=json.dumps(body).encode(),
                                  client_id=1)
        try:
            answer = json.loads(service.handler(request))["message"]
        except ValueError as exc:  # the SDK's failure answer
            answer = str(exc)
        assert len(answer) < 200, answer[:300]
    assert len(board.sent) >= 4
    assert all(len(m) < 300 for m in board.sent), [m[:300] for m in board.sent]
    assert all(len(r.getMessage()) < 300 for r in caplog.records)
    assert any("999999999" in m and "1000001 characters" in m for m in board.sent)


@given(st.one_of(st.text(), st.binary(), st.lists(st.text()), st.floats(), st.integers(),
                 st.dictionaries(st.text(), st.text())), st.integers(8, 100))
@example("000000000'", 8)  # the cut holds no ', the whole is quoted with "
@example(b"000000000'", 8)
def test_quote_is_short_and_begins_as_the_repr_does(value: Any, limit: int) -> None:
    text = quote(value, limit)
    full = repr(value)
    if len(full) <= limit:
        assert text == full
    else:
        assert len(text) <= limit + 30
        assert text.endswith(")") and "..." in text
        if isinstance(value, (str, bytes)):
            assert text.startswith(full[:limit])


# ---------------------------------------------------------------- the relay

REQUEST = (b"GET / HTTP/1.1\r\nHost: 127.0.0.1:8765\r\nUpgrade: websocket\r\n"
           b"Sec-WebSocket-Protocol: foxglove.websocket.v1, other\r\n"
           b"sec-websocket-protocol: third\r\nSec-WebSocket-Key: abc\r\n\r\n")


def test_the_relay_reads_and_rewrites_the_offered_subprotocols() -> None:
    assert offered_subprotocols(REQUEST) == ["foxglove.websocket.v1", "other", "third"]
    rewritten = rewrite_protocol(REQUEST, "foxglove.sdk.v1")
    assert offered_subprotocols(rewritten) == ["foxglove.sdk.v1"]
    assert b"Sec-WebSocket-Key: abc\r\n" in rewritten and rewritten.endswith(b"\r\n\r\n")
    assert rewritten.startswith(b"GET / HTTP/1.1\r\nHost: 127.0.0.1:8765\r\n")


@given(st.text(alphabet=string.ascii_letters + string.digits + "-_.~!$'()*,;:@", min_size=1,
               max_size=64), st.sampled_from(["/", "/ws", "/a/b"]), st.booleans())
def test_the_token_is_read_from_the_url_or_a_header_and_not_passed_on(
        token: str, path: str, in_url: bool) -> None:
    first = f"GET {path}?x=1&token={token} HTTP/1.1" if in_url else f"GET {path} HTTP/1.1"
    auth = "" if in_url else f"Authorization: Bearer {token}\r\n"
    head = f"{first}\r\nHost: robot:8765\r\n{auth}Origin: file://\r\n\r\n".encode()
    assert given_token(head) == token
    check_token(token, "token")  # what a config may hold, a URL carries as it is
    forwarded = without_query(head)
    assert forwarded.split(b"\r\n", 1)[0] == f"GET {path} HTTP/1.1".encode()
    assert forwarded.split(b"\r\n", 1)[1] == head.split(b"\r\n", 1)[1]
    assert given_token(head.replace(b"token=", b"tokens=").replace(b"Bearer", b"Basic")) is None


@pytest.fixture
def view(channel: str) -> Any:
    pytest.importorskip("foxglove", reason="needs the foxglove extra")
    from omnican.live import LiveView
    from omnican.sim import SimulatedBase

    cfg = default_config(bus={"interface": "virtual", "channel": channel})
    with SimulatedBase.from_config(cfg) as sim, simulator_feed(sim) as feed, \
            LiveView(feed, host="127.0.0.1", port=0) as v:
        yield v


@pytest.mark.parametrize("offered", [["foxglove.websocket.v1"], ["foxglove.sdk.v1"],
                                     ["foxglove.websocket.v1", "foxglove.sdk.v1"]])
def test_either_name_of_the_protocol_connects_and_gets_the_name_it_asked_for(
        view: Any, offered: list[str]) -> None:
    from websockets.sync.client import connect

    with connect(view.url, subprotocols=offered, open_timeout=5) as ws:  # type: ignore[arg-type]
        assert ws.subprotocol == ("foxglove.sdk.v1" if "foxglove.sdk.v1" in offered
                                  else "foxglove.websocket.v1")
        info = json.loads(ws.recv(timeout=5))
        assert info["op"] == "serverInfo" and info["name"] == "omnican"


def test_a_client_offering_neither_name_is_refused(view: Any) -> None:
    from websockets.exceptions import InvalidStatus
    from websockets.sync.client import connect

    with pytest.raises(InvalidStatus, match="400"):
        connect(view.url, subprotocols=["mqtt"], open_timeout=5)  # type: ignore[list-item]


def test_a_browser_opening_the_address_is_told_what_it_is(view: Any) -> None:
    """A phone's browser opening https://robot:8765 (to accept the certificate, say) gets
    a line saying where Foxglove connects, not a broken handshake."""
    import urllib.request

    from omnican.live.relay import PAGE

    with urllib.request.urlopen(view.url.replace("ws://", "http://"), timeout=5) as page:
        assert page.status == 200
        assert page.read().decode() == PAGE


@given(st.ip_addresses(v=4), st.integers(1, 65535), st.integers(0, 2**32 - 1),
       st.text(max_size=200))
def test_the_sdk_lines_of_one_kind_of_mistake_are_one_kind(
        address: Any, port: int, channel_id: int, detail: str) -> None:
    from omnican.live.view import mistake_kind

    invalid = mistake_kind(f"Invalid message from {address}:{port}: {detail}")
    assert invalid == mistake_kind("Invalid message from 127.0.0.1:1: key must be a string")
    unknown = mistake_kind(f"Client {address}:{port} attempted to subscribe to unknown "
                           f"channel: {channel_id}")
    assert unknown == mistake_kind("Client 10.0.0.1:80 attempted to subscribe to unknown "
                                   "channel: 7")
    assert invalid != unknown and len(invalid) <= 80


@pytest.fixture
def guarded(channel: str) -> Any:
    """A live view whose clients may drive a stand-in base, only with the token s3cret."""
    pytest.importorskip("foxglove", reason="needs the foxglove extra")
    from omnican.live import LiveView
    from omnican.sim import SimulatedBase

    cfg = default_config(bus={"interface": "virtual", "channel": channel})
    base = StandInBase(timeout_s=60.0)
    settings = FoxgloveSettings(port=0, control=True, token="s3cret")
    c = Control(base, settings)
    with SimulatedBase.from_config(cfg) as sim, simulator_feed(sim) as feed, \
            LiveView(feed, control=c, settings=settings) as v:
        yield v, base


def _open(url: str, **options: Any) -> Any:
    from websockets.sync.client import connect

    ws = connect(url, subprotocols=["foxglove.sdk.v1"], open_timeout=5,  # type: ignore[list-item]
                 max_size=None, **options).__enter__()
    assert json.loads(ws.recv(timeout=5))["op"] == "serverInfo"
    return ws


def _drive(ws: Any, vx: float, channel_id: int = 1) -> None:
    """Advertise /cmd_vel and publish one JSON Twist, as the Teleop panel does."""
    ws.send(json.dumps({"op": "advertise", "channels": [{
        "id": channel_id, "topic": "/cmd_vel", "encoding": "json",
        "schemaName": "geometry_msgs/Twist"}]}))
    ws.send(b"\x01" + channel_id.to_bytes(4, "little") + twist(vx))


def _round_trip(ws: Any, tag: str) -> list[dict[str, Any]]:
    """Every text message up to the answer to a getParameters (the server has handled
    all that came before it)."""
    ws.send(json.dumps({"op": "getParameters", "parameterNames": [], "id": tag}))
    seen = []
    while True:
        data = ws.recv(timeout=10)
        if isinstance(data, str):
            seen.append(json.loads(data))
            if seen[-1].get("op") == "parameterValues" and seen[-1].get("id") == tag:
                return seen


@pytest.mark.parametrize(("origin", "allowed"), [
    (None, True), ("https://app.foxglove.dev", True), ("https://studio.foxglove.dev", True),
    ("file://", True), ("https://evil.example", False), ("null", False),
    ("http://127.0.0.1:8080", False), ("https://app.foxglove.dev.evil.example", False)])
def test_only_the_foxglove_app_and_programs_may_connect(guarded: Any, origin: str | None,
                                                       allowed: bool) -> None:
    """A browser says which web page opened the connection: only Foxglove's app (and its
    desktop build, file://) gets in, not any page the operator happens to visit."""
    from websockets.exceptions import InvalidStatus

    view, base = guarded
    headers = {"Origin": origin} if origin is not None else {}
    if not allowed:
        with pytest.raises(InvalidStatus, match="403"):
            _open(view.url + "/?token=s3cret", additional_headers=headers)
        return
    with _open(view.url + "/?token=s3cret", additional_headers=headers) as ws:
        _drive(ws, 0.2)
        _round_trip(ws, "done")
    assert base.calls[0] == ("velocity", (0.2, 0.0, 0.0))


def test_more_origins_from_the_config_and_flags() -> None:
    s = resolve({"origins": ["http://localhost:8080/"]}, None, origins=["HTTPS://Lab.Example"])
    assert s.origin_allowed("http://localhost:8080") and s.origin_allowed("https://lab.example")
    assert not s.origin_allowed("https://app.foxglove.dev")  # the table's list replaces it
    assert s.origin_allowed(None)
    assert resolve({"origins": ["*"]}, None).origin_allowed("https://anything.example")
    for table, message in (({"origins": ["app.foxglove.dev"]}, "want an origin such as"),
                           ({"token": "has space"}, "foxglove.token: letters, digits"),
                           ({"token": ""}, "foxglove.token: want a non-empty text")):
        with pytest.raises(ConfigError, match=message):
            resolve(table, None)


@pytest.mark.parametrize(("flags", "message"), [
    (["--foxglove-token", "has space"], "--foxglove-token: letters, digits and punctuation"),
    (["--foxglove-origin", "evil.example"], "--foxglove-origin: want an origin such as"),
])
def test_a_bad_token_or_origin_flag_is_one_line(flags: list[str], message: str,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("foxglove", reason="needs the foxglove extra")
    from omnican.cli import main

    code = main(["drive", "--sim", "--foxglove-control", "--duration", "0.2", *flags])
    assert code == 2
    line = one_error_line(capsys.readouterr().err)
    assert message in line and "has space" not in line


def test_only_a_client_with_the_token_drives_and_the_sdk_port_never(guarded: Any) -> None:
    """Without the token a client watches: its Twist moves nothing and it is told why. With
    it (in the URL, as Foxglove's app can send it, or as a bearer header) it drives. A
    wrong one is refused at the door. The SDK's own port, on loopback past the relay and
    its checks, takes no command from anyone, token or not."""
    from websockets.exceptions import InvalidStatus

    view, base = guarded
    with _open(view.url) as ws:
        _drive(ws, 0.5)
        statuses = [m["message"] for m in _round_trip(ws, "w") if m.get("op") == "status"]
    assert base.calls == []
    assert any("may watch, not drive" in m for m in statuses), statuses
    with _open(f"ws://127.0.0.1:{view._server.port}/?token=s3cret") as ws:
        _drive(ws, 0.5)
        ws.send(json.dumps({"op": "setParameters", "id": "p", "parameters": [
            {"name": "chassis.max_speed", "value": 0.01}]}))
        _round_trip(ws, "inner")
    assert base.calls == [] and base.cfg.chassis.max_speed == math.inf
    with pytest.raises(InvalidStatus, match="403"):
        _open(view.url + "/?token=guess")
    with _open(view.url, additional_headers={"Authorization": "Bearer s3cret"}) as ws:
        _drive(ws, 0.1)
        _round_trip(ws, "b")
    with _open(view.url + "/?token=s3cret") as ws:
        _drive(ws, 0.2)
        _round_trip(ws, "q")
    assert [v for k, v in base.calls if k == "velocity"] == [(0.1, 0.0, 0.0), (0.2, 0.0, 0.0)]


@pytest.mark.parametrize("fragments", [1, 100])
def test_an_oversized_message_ends_the_connection_unread(guarded: Any,
                                                        fragments: int) -> None:
    """A 16 MB message (or 100 fragments of 1 KB each, one message) from a client ends its
    connection at the relay, before the server holds or reads any of it; the driver
    leaving so stops the base."""
    from websockets.exceptions import ConnectionClosed

    view, base = guarded
    ws = _open(view.url + "/?token=s3cret")
    _drive(ws, 0.2)
    _round_trip(ws, "driving")
    assert base.calls == [("velocity", (0.2, 0.0, 0.0))]
    size = 16_000_000 if fragments == 1 else 1024  # (the SDK itself takes frames < 16 MiB)
    body = b"\x01" + (1).to_bytes(4, "little") + b"[" * size
    with pytest.raises(ConnectionClosed):
        if fragments == 1:
            ws.send(body)
        else:
            ws.send([body] * fragments)
        _round_trip(ws, "after")
    ws.close()
    # the SDK says the client left: the base stops (it got nothing of the message)
    deadline = 200
    while base.calls[-1] != ("stop", None) and deadline:
        import time

        time.sleep(0.05)
        deadline -= 1
    assert base.calls == [("velocity", (0.2, 0.0, 0.0)), ("stop", None)]


def test_protocol_mistakes_are_logged_once_in_a_while(guarded: Any,
                                                     caplog: pytest.LogCaptureFixture) -> None:
    """5,000 invalid messages: a handful of log lines, not 5,000 ERRORs."""
    view, _ = guarded
    caplog.set_level(logging.INFO)
    with _open(view.url) as ws:
        for batch in range(25):  # reading the server's answers (a status each) in between
            for i in range(100):
                ws.send("{not json")
                ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                    {"id": batch * 100 + i + 1, "channelId": 99999}]}))
            _round_trip(ws, f"batch {batch}")
    mistakes = [r for r in caplog.records if "not json" in r.getMessage().lower()
                or "Invalid message" in r.getMessage() or "unknown channel" in r.getMessage()]
    assert 2 <= len(mistakes) <= 6, [r.getMessage() for r in mistakes]
    assert all(r.levelno == logging.WARNING for r in mistakes)


def make_certificate(tmp_path: Path) -> tuple[Path, Path]:
    openssl = shutil.which("openssl")
    if openssl is None:
        pytest.skip("needs openssl to make a test certificate")
    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    subprocess.run([openssl, "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1",
                    "-subj", "/CN=127.0.0.1", "-addext", "subjectAltName=IP:127.0.0.1",
                    "-keyout", str(key), "-out", str(cert)], check=True, capture_output=True)
    return cert, key


def test_tls_serves_wss_and_refuses_plain_ws(channel: str, tmp_path: Path) -> None:
    pytest.importorskip("foxglove", reason="needs the foxglove extra")
    from websockets.sync.client import connect

    from omnican.live import LiveView
    from omnican.sim import SimulatedBase

    cert, key = make_certificate(tmp_path)
    cfg = default_config(bus={"interface": "virtual", "channel": channel})
    settings = FoxgloveSettings(port=0, tls_cert=cert, tls_key=key)
    with SimulatedBase.from_config(cfg) as sim, simulator_feed(sim) as feed, \
            LiveView(feed, settings=settings) as v:
        assert v.url.startswith("wss://127.0.0.1:")
        trust = ssl.create_default_context(cafile=str(cert))
        with connect(v.url, ssl=trust, subprotocols=["foxglove.websocket.v1"],  # type: ignore[list-item]
                     open_timeout=5) as ws:
            assert json.loads(ws.recv(timeout=5))["op"] == "serverInfo"
        with pytest.raises(Exception):  # noqa: B017 - the handshake fails, however it says so
            connect(v.url.replace("wss://", "ws://"), open_timeout=3,
                    subprotocols=["foxglove.sdk.v1"]).close()  # type: ignore[list-item]


def test_a_certificate_that_does_not_load_is_one_line(tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("foxglove", reason="needs the foxglove extra")
    from omnican.cli import main

    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    cert.write_text("not a certificate\n")
    key.write_text("nor a key\n")
    robot = tmp_path / "robot.toml"
    robot.write_text((Path(__file__).resolve().parents[2] / "examples" / "robot.toml")
                     .read_text() + '\n[foxglove]\ntls_cert = "cert.pem"\ntls_key = "key.pem"\n')
    code = main(["drive", "--sim", "--config", str(robot), "--vx", "0.1", "--duration", "0.2",
                 "--foxglove", "127.0.0.1:0"])
    assert code == 2
    line = one_error_line(capsys.readouterr().err)
    assert f"cannot use {cert} / {key} for TLS" in line


# ---------------------------------------------------------------- settings


def test_the_foxglove_table_is_read_with_paths_relative_to_the_config(tmp_path: Path) -> None:
    (tmp_path / "tls").mkdir()
    for name in ("cert.pem", "key.pem"):
        (tmp_path / "tls" / name).write_text("x")
    robot = tmp_path / "robot.toml"
    robot.write_text((Path(__file__).resolve().parents[2] / "examples" / "robot.toml")
                     .read_text() + '\n[foxglove]\ncontrol = true\ncmd_vel_topic = "/teleop"\n'
                     'tls_cert = "tls/cert.pem"\ntls_key = "tls/key.pem"\n')
    cfg = load_config(robot)
    s = resolve(cfg.front_ends.get("foxglove"), "127.0.0.1:9000")
    assert (s.control, s.cmd_vel_topic, s.port, s.scheme) == (True, "/teleop", 9000, "wss")
    assert s.tls_cert == tmp_path / "tls" / "cert.pem"
    assert resolve(cfg.front_ends.get("foxglove"), None, control=False).control is False  # the flag wins


@pytest.mark.parametrize(("table", "address", "message"), [
    ({"tls_cert": "/nowhere/cert.pem", "tls_key": "/nowhere/key.pem"}, None,
     "config: foxglove.tls_cert: no such file /nowhere/cert.pem"),
    ({"tls_cert": "cert.pem"}, None, "config: foxglove.tls_cert needs foxglove.tls_key too"),
    ({"cmd_vel_topic": "cmd vel"}, None, "foxglove.cmd_vel_topic: want a topic name"),
    ({"control": True}, "0.0.0.0:8765", "--foxglove-control on 0.0.0.0:8765 lets anyone who "
                                        "reaches this host drive the robot"),
    ({"control": True}, "robot.local:8765", "add --foxglove-allow-remote"),
    ({}, "host:port", "--foxglove: want [HOST:]PORT"),
])
def test_settings_that_would_be_unsafe_or_cannot_work_are_refused(
        table: dict[str, Any], address: str | None, message: str) -> None:
    with pytest.raises(ConfigError) as info:
        resolve(table, address)
    assert message in str(info.value)


def test_control_on_another_host_when_allowed_is_announced() -> None:
    s = resolve({"control": True, "allow_remote": True}, "0.0.0.0:8765")
    assert s.remote and s.control
    assert resolve({"control": True}, "[::1]:8765").remote is False  # loopback, either family
    fake = SimpleNamespace(settings=s, port=8765, control=SimpleNamespace(
        service_names=lambda: ["/omnican/stop"], timeout_s=0.5))
    lines = describe_control(fake)  # type: ignore[arg-type]
    assert lines[0].startswith("Foxglove control on: Twists on /cmd_vel")
    assert lines[1] == ("Foxglove clients: browsers from https://app.foxglove.dev, "
                        "https://studio.foxglove.dev, file://, and programs; any of them may "
                        "drive (--foxglove-token keeps it to those with it)")
    assert lines[2] == ("warning: anyone who reaches this host on port 8765 can drive the "
                        "robot (--foxglove-allow-remote)")
    fake.settings = replace(s, token="t", origins=("*",))
    assert describe_control(fake)[1] == (  # type: ignore[arg-type]
        "Foxglove clients: browsers from any web page, and programs; only a client with the "
        "token drives (its URL ending /?token=...), the others watch")


def test_an_unknown_foxglove_key_is_refused_by_the_config(tmp_path: Path) -> None:
    robot = tmp_path / "robot.toml"
    robot.write_text((Path(__file__).resolve().parents[2] / "examples" / "robot.toml")
                     .read_text() + "\n[foxglove]\ncontroll = true\n")
    with pytest.raises(ConfigError, match="foxglove.controll: unknown key 'controll' "
                                          r"\(did you mean 'control'\?\)"):
        load_config(robot)


def test_control_needs_an_sdk_that_says_when_a_client_leaves(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """foxglove-sdk before 0.25.2 does not tell the server's listener when a client
    disconnects, so the base could not stop when its driver leaves: control is refused
    there (watching is not)."""
    import importlib.metadata

    monkeypatch.setattr(importlib.metadata, "version", lambda name: "0.25.1")
    with pytest.raises(ConfigError, match=r"--foxglove-control needs foxglove-sdk 0\.25\.2 or "
                                          r"later .*; this is 0\.25\.1"):
        resolve({"control": True}, None)
    assert resolve({}, None).control is False  # watching only: no such need
    monkeypatch.setattr(importlib.metadata, "version", lambda name: "0.30.3")
    assert resolve({"control": True}, None).control is True


# ---------------------------------------------------------------- against a real base


@pytest.fixture
def real(channel: str) -> Any:
    """Control of a real Chassis (lock-step, on simulated drives): (clock, sim, base,
    control), as ``--foxglove-control`` wires them."""
    pytest.importorskip("foxglove", reason="needs the foxglove extra")
    from omnican import Chassis
    from omnican.clock import SimClock
    from omnican.sim import SimulatedBase
    from tests.support.helpers import sim_config

    cfg = sim_config(channel)
    clock = SimClock()
    with SimulatedBase.from_config(cfg, clock=clock) as sim, \
            Chassis.open(cfg, clock=clock) as base:
        c = Control(base, FoxgloveSettings(control=True))
        for n in (1, 2, 3):  # came in through the relay: they may drive
            vouch(c, n)
        yield clock, sim, base, c


def _set(c: Control, client_id: int, name: str, value: Any) -> Any:
    [p] = c.on_set_parameters(client(client_id), [SimpleNamespace(name=name,
                                                                  get_value=lambda: value)])
    return p.get_value()


def test_a_parameter_cannot_make_the_base_unstoppable_or_faster(real: Any) -> None:
    """Issue: with nobody driving, a client set stop_decel and stop_angular_decel to
    1e-6; the driving client then left and the base was still at 0.2 m/s two seconds
    later. A live value may only make the base safer than its config: a lower stop
    deceleration, a higher speed or acceleration are refused (the old value stays), a
    safer one is taken, and the driver leaving stops the base at once."""
    from tests.support.helpers import still

    clock, sim, base, c = real
    configured, configured_limits = base.cfg.chassis, base.cfg.limits()
    assert _set(c, 2, "chassis.stop_decel", 1e-6) == configured.stop_decel
    assert _set(c, 2, "chassis.stop_angular_decel", 0.5) == configured.stop_angular_decel
    assert _set(c, 2, "chassis.max_accel", 5.0) == configured.max_accel
    assert _set(c, 2, "chassis.max_wheel_speed", 2.0) == configured.max_wheel_speed
    assert _set(c, 2, "chassis.max_speed", 1e9) == top_speeds(configured_limits,
                                                              base.cfg.kinematics())[0]
    assert base.cfg.chassis == configured
    assert _set(c, 2, "chassis.max_speed", 0.25) == 0.25  # slower: safer, taken
    assert _set(c, 2, "chassis.stop_decel", 4.0) == 4.0  # a shorter stop: taken
    c.on_client_advertise(client(1), channel(1))
    end = clock.now() + 1.5
    while clock.now() < end:
        c.on_message_data(client(1), 1, twist(0.6))
        clock.sleep(0.02)
    assert sim.true_twist.vx == pytest.approx(0.25, abs=0.01)  # the lower limit holds
    c.on_client_unadvertise(client(1), 1)  # the driver leaves
    # 0.25 m/s at 4 m/s^2: 63 ms; a few cycles for the wheels' own lag.
    assert wait_for_sim(clock, lambda: still(sim), 0.3), sim.true_twist


def wait_for_sim(clock: Any, pred: Any, timeout: float) -> bool:
    return bool(clock.run_until(pred, timeout, 0.01))


def test_absurd_values_from_a_client_are_refused_with_the_reason(real: Any) -> None:
    """Issue: a Twist of 1e308 drove at the wheel limit, three of them moved nothing,
    reset_odometry took x = 1e308, max_speed took 1e9. The base refuses each (one
    check, in the library), the client is told why, and nothing moves."""
    from tests.support.helpers import still

    clock, sim, base, c = real
    statuses: list[str] = []
    c._server = SimpleNamespace(publish_status=lambda m, *_: statuses.append(m),
                                remove_status=lambda *_: None)
    c._status_level = SimpleNamespace(Warning="Warning", Info="Info")
    c.on_client_advertise(client(1), channel(1))
    for _ in range(3):
        c.on_message_data(client(1), 1, _twist_json(linear={"x": 1e308, "y": 0, "z": 0},
                                                    angular={"x": 0, "y": 0, "z": 0}))
        clock.sleep(0.1)
    assert still(sim) and base.command == Twist()
    assert c.twists == 0 and c.refused == 3
    assert "vx 1e+308 m/s is beyond any wheeled base" in statuses[-1]
    assert base.command_source("a test").holder() is None  # a refused one takes no control
    reply = call(c, "/omnican/reset_odometry", 1, {"x": 1e308})
    assert reply == {"success": False, "message": "odometry reset refused: x 1e+308 m is "
                     "beyond 1e+06 m (the motion added to it would be lost to rounding)"}
    assert base.pose == Pose2D()
    assert call(c, "/omnican/reset_odometry", 1, {"x": 2.0})["success"]
    assert base.pose == Pose2D(2.0, 0.0, 0.0)
    c.on_message_data(client(1), 1, twist(0.3))  # a sane one drives
    clock.sleep(0.5)
    assert sim.true_twist.vx == pytest.approx(0.3, abs=0.02)
