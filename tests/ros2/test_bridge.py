"""omnican ros2 without a network: names, settings and the [ros2] table, the Cyclone
configuration, odometry covariances, joint states, diagnostics, and the bridge on a
real (simulated) chassis over an in-memory transport."""

from __future__ import annotations

import collections
import math
import re
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any
from xml.etree import ElementTree

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from omnican import Chassis, Pose2D, Twist, default_config, load_config
from omnican.cli import main
from omnican.errors import ConfigError
from omnican.protocol.cia402 import State
from omnican.ros2.cmd_vel import twist_from_msg
from omnican.ros2.settings import (
    EPROSIMA_VENDOR_ID,
    Ros2Settings,
    cyclone_config,
    dds_topic,
    from_table,
    normalize_namespace,
    parse_remap,
    resolve_name,
    validate,
)
from omnican.sim import SimulatedBase
from omnican.telemetry import messages as model
from omnican.telemetry.covariance import UNOBSERVED_VARIANCE, OdomCovariance
from tests.support.helpers import lockstep_rig, one_error_line, sim_config, wait_for, with_truth

names = st.from_regex(r"[A-Za-z_][A-Za-z0-9_]{0,8}", fullmatch=True)

# ------------------------------------------------------------ names


@settings(deadline=None)  # wall-clock limits fail on a loaded machine
@given(st.lists(names, max_size=3), st.lists(names, min_size=1, max_size=3), names)
def test_relative_names_live_in_the_namespace(ns: list[str], topic: list[str], node: str) -> None:
    namespace = "/" + "/".join(ns)
    full = resolve_name("/".join(topic), namespace, node)
    assert full == (namespace.rstrip("/") + "/" + "/".join(topic))
    assert resolve_name("/" + "/".join(topic), namespace, node) == "/" + "/".join(topic)
    private = resolve_name("~/" + "/".join(topic), namespace, node)
    assert private == namespace.rstrip("/") + "/" + node + "/" + "/".join(topic)
    assert dds_topic(full) == "rt" + full


def test_name_examples_and_refusals() -> None:
    assert resolve_name("cmd_vel", "robot1") == "/robot1/cmd_vel"
    assert resolve_name("~/recover", "/robot1/", "base") == "/robot1/base/recover"
    assert resolve_name("/tf", "/robot1") == "/tf"
    assert normalize_namespace("") == "/"
    for bad in ("2odom", "odom/", "od om", "a//b", "~recover", ""):
        with pytest.raises(ValueError):
            resolve_name(bad)
    with pytest.raises(ValueError):
        normalize_namespace("/robot-1")


def test_remap_parsing() -> None:
    assert parse_remap("cmd_vel:=/nav/cmd_vel") == ("cmd_vel", "/nav/cmd_vel")
    for bad in ("cmd_vel", "cmd_vel:=", "scan:=/scan"):
        with pytest.raises(ValueError):
            parse_remap(bad)


# ------------------------------------------------------------ settings and config


def test_ros2_table_from_toml(tmp_path: Path) -> None:
    path = tmp_path / "robot.toml"
    path.write_text((Path(__file__).resolve().parents[1] / "interop" / "ros2_interop" / "robot.toml").read_text()
                    + 'namespace = "robot1"\ndomain_id = 17\npeers = ["10.0.0.2"]\n')
    cfg = load_config(path)
    assert cfg.wheels[0].wheel_radius == 0.05
    s = from_table(cfg.front_ends.get("ros2") or {}, str(path))
    assert s.node_namespace == "/robot1" and s.domain_id == 17 and s.peers == ("10.0.0.2",)
    assert s.topic("cmd_vel") == "/robot1/cmd_vel"
    assert s.topic("tf") == "/tf" and s.topic("diagnostics") == "/diagnostics"
    assert s.topic("recover") == "/robot1/omnican/recover"
    assert s.wheel_joint_names(3) == ("wheel_0_joint", "wheel_1_joint", "wheel_2_joint")
    assert default_config().front_ends.get("ros2") is None and default_config().wheels[0].wheel_radius == 0.05


@pytest.mark.parametrize(("line", "message"), [
    ("domain_id = 300", "ros2.domain_id: must be 0-232"),
    ('namespace = "robot-1"', "ros2.namespace: invalid namespace"),
    ('odom_topic = "2odom"', "ros2.odom_topic: invalid topic name"),
    ('base_frame = "/base_link"', "ros2.base_frame: must be a tf2 frame id"),
    ('base_frame = "odom"', "ros2.base_frame: must differ from odom_frame"),
    ("odom_rate_hz = 0", "ros2.odom_rate_hz: must be 0.01-1000, got 0"),
    ("odom_slip = 1.5", "ros2.odom_slip: must be 0-0.99, got 1.5"),
    ("wheel_radius = -1", "ros2.wheel_radius: must be 0.001-10, got -1"),
    ("joint_names = [1, 2, 3]", "ros2.joint_names: must be an array of strings"),
    ('joint_names = ["a", "a", "b"]', "ros2.joint_names: must be distinct"),
    ('publish_tf = "yes"', "ros2.publish_tf: must be bool"),
    ("speed = 3", "ros2.speed: unknown key"),
])
def test_bad_ros2_tables_name_the_key(tmp_path: Path, line: str, message: str) -> None:
    path = tmp_path / "robot.toml"
    text = (Path(__file__).resolve().parents[1] / "interop" / "ros2_interop" / "robot.toml").read_text()
    path.write_text(text.split("\n[ros2]\n")[0] + "\n[ros2]\n" + line + "\n")
    with pytest.raises(ConfigError, match=re.escape(message)):
        cfg = load_config(path)
        from_table(cfg.front_ends.get("ros2") or {}, str(path))


def test_cyclone_config_layers() -> None:
    s = Ros2Settings(interface="eth0", peers=("10.0.0.2", "robot.local"), multicast=False)
    text = cyclone_config(s, "file:///etc/cyclone.xml")
    parts = text.split(",")
    assert parts[1] == "file:///etc/cyclone.xml"  # the user's file between ours
    first = ElementTree.fromstring(parts[0])
    assert first.findtext("Domain/Compatibility/IgnoreTypeInformation") == EPROSIMA_VENDOR_ID
    # A sample over 64 KB (a 16 MB TwistStamped) is dropped by Cyclone, unread by Python.
    assert first.findtext("Domain/Internal/MaxSampleSize") == "65536B"
    last = ElementTree.fromstring(parts[2])
    assert last.find("Domain/General/Interfaces/NetworkInterface").get("name") == "eth0"
    assert last.findtext("Domain/General/AllowMulticast") == "false"
    assert [p.get("address") for p in last.iter("Peer")] == ["10.0.0.2", "robot.local"]
    # Defaults: only the compatibility part; an address is given as one.
    assert len(cyclone_config(Ros2Settings()).split(",")) == 1
    lo = Ros2Settings().with_loopback()
    assert lo.loopback_only and not Ros2Settings().loopback_only
    addr = ElementTree.fromstring(cyclone_config(replace(lo, interface="127.0.0.1")
                                                 ).split(",")[1])
    assert addr.find("Domain/General/Interfaces/NetworkInterface").get("address") == \
        "127.0.0.1"


@settings(deadline=None)  # wall-clock limits fail on a loaded machine
@given(st.text(min_size=1, max_size=20))
def test_cyclone_config_escapes_what_it_is_given(interface: str) -> None:
    try:
        s = validate(Ros2Settings(interface=interface))
    except ConfigError:
        assert any(not ("!" <= c <= "~") or c == "," for c in interface)
        return
    part = cyclone_config(s).split(",")[1]
    el = ElementTree.fromstring(part).find("Domain/General/Interfaces/NetworkInterface")
    assert el is not None and interface in (el.get("name"), el.get("address"))


def test_validate_keeps_good_settings() -> None:
    s = validate(Ros2Settings(namespace="robot1/"))
    assert s.namespace == "/robot1"


# ------------------------------------------------------------ model


@settings(deadline=None)  # wall-clock limits fail on a loaded machine
@given(st.floats(-1e3, 1e3))
def test_yaw_quaternion_round_trip(theta: float) -> None:
    q = model.yaw_quaternion(theta)
    assert math.fsum(v * v for v in q.values()) == pytest.approx(1.0)
    back = model.quaternion_yaw(q["x"], q["y"], q["z"], q["w"])
    assert math.remainder(back - theta, 2 * math.pi) == pytest.approx(0.0, abs=1e-9)


@settings(deadline=None)  # wall-clock limits fail on a loaded machine
@given(st.integers(0, 4 * 10**18))
def test_ros_time(ns: int) -> None:
    t = model.stamp(ns)
    assert 0 <= t["nanosec"] < 1_000_000_000
    assert t["sec"] * 1_000_000_000 + t["nanosec"] == ns


def _cov_model(slip: float = 0.02) -> OdomCovariance:
    cfg = default_config()
    return OdomCovariance(cfg.kinematics(), slip,
                                [w.position_scale for w in cfg.wheels], 0.1)


steps = st.lists(st.tuples(st.floats(-0.05, 0.05), st.floats(-0.05, 0.05),
                           st.floats(-0.2, 0.2)), min_size=1, max_size=40)


@settings(deadline=None)  # wall-clock limits fail on a loaded machine
@given(steps)
def test_pose_covariance_is_a_covariance_that_grows(moves: list[tuple[float, float, float]]
                                                    ) -> None:
    cov = _cov_model()
    pose = Pose2D()
    cov.update(pose)
    last_trace = 0.0
    for dx, dy, dth in moves:
        pose = pose.compose(Pose2D(dx, dy, dth))
        c = cov.update(pose)
        assert np.allclose(c, c.T)
        assert np.linalg.eigvalsh(c).min() >= -1e-12
        assert np.trace(c) >= last_trace - 1e-15
        last_trace = float(np.trace(c))
    full = np.array(cov.pose_covariance()).reshape(6, 6)
    assert full[2, 2] == full[3, 3] == full[4, 4] == UNOBSERVED_VARIANCE


def test_pose_variance_grows_with_distance_not_with_the_publish_rate() -> None:
    """slip**2 per metre of wheel travel: the same drive sampled finely or coarsely ends
    with the same uncertainty (a random walk, not a sum of squared steps)."""
    results = []
    for n in (10, 1000):
        cov = _cov_model(0.02)
        cov.update(Pose2D())
        for i in range(1, n + 1):
            cov.update(Pose2D(2.0 * i / n, 0.0, 0.0))  # 2 m straight ahead
        results.append(cov.pose_cov3.copy())
    assert results[0][0, 0] == pytest.approx(results[1][0, 0], rel=1e-6)
    # x error from 2 m of travel: slip**2 * (each wheel's |travel|) through the forward map.
    kin = default_config().kinematics()
    travel = np.abs(kin.to_wheel_speeds(__import__("omnican").Twist(2.0, 0.0, 0.0)))
    fwd = np.asarray(kin.forward_matrix)
    expected = (fwd * (0.02**2 * travel)) @ fwd.T
    assert results[1][0, 0] == pytest.approx(expected[0, 0], rel=1e-6)
    # Standing still adds nothing; driving further adds more.
    cov = _cov_model()
    cov.update(Pose2D())
    assert not cov.update(Pose2D()).any()


def test_twist_covariance_has_an_encoder_floor_and_grows_with_speed() -> None:
    cov = _cov_model()
    still = np.array(cov.twist_covariance([0.0, 0.0, 0.0])).reshape(6, 6)
    moving = np.array(cov.twist_covariance([0.5, -0.5, 0.2])).reshape(6, 6)
    assert 0 < still[0, 0] < 1e-6  # one count in 0.1 s of a 4096 x 16 count wheel
    assert moving[0, 0] > still[0, 0] and moving[5, 5] > still[5, 5]


@settings(deadline=None)  # wall-clock limits fail on a loaded machine
@given(st.lists(st.floats(-5, 5), min_size=6, max_size=6))
def test_twist_from_msg_keeps_the_planar_part(v: list[float]) -> None:
    t = twist_from_msg(v[:3], v[3:])
    assert (t.vx, t.vy, t.wz) == (v[0], v[1], v[5])


# ------------------------------------------------------------ the bridge, in memory


class MemoryTransport:
    """Transport for the tests: publishers record; what a test delivers waits, serialised
    as DDS carries it, in each reader's history (keep-last, its depth) until the bridge
    polls."""

    def __init__(self) -> None:
        self.published: dict[str, list[Any]] = {}
        self.readers: dict[str, tuple[type, collections.deque[Any]]] = {}
        self.discovered: list[Any] = []
        self.qos: dict[str, Any] = {}
        self.lock = threading.Lock()
        self.closed = False

    def publisher(self, topic: str, msg_type: type, qos: Any) -> Callable[[Any], None]:
        self.qos[topic] = qos
        self.published[topic] = []

        def publish(msg: Any) -> None:
            assert isinstance(msg, msg_type)
            msg.serialize(use_version_2=False)  # everything published must serialise
            with self.lock:
                self.published[topic].append(msg)
        return publish

    def reader(self, topic: str, msg_type: type, qos: Any) -> Callable[[], list[Any]]:
        self.qos[topic] = qos
        history: collections.deque[Any] = collections.deque(maxlen=qos.depth)
        self.readers[topic] = (msg_type, history)

        def take() -> list[Any]:
            with self.lock:
                got = list(history)
                history.clear()
            return got
        return take

    def deliver(self, topic: str, msg: Any, writer: int = 1) -> None:
        msg_type: Any = self.readers[topic][0]
        assert type(msg) is msg_type
        self.deliver_raw(topic, msg.serialize(use_version_2=False), writer)

    def deliver_raw(self, topic: str, data: bytes, writer: int = 1) -> None:
        from omnican.ros2.transport import Received

        with self.lock:
            self.readers[topic][1].append(Received(writer, data))

    def writer_guid(self, topic: str, writer: int) -> str:
        return f"{writer:032x}"

    def publications(self) -> list[Any]:
        with self.lock:
            found, self.discovered = self.discovered, []
        return found

    def last(self, topic: str) -> Any:
        with self.lock:
            return self.published[topic][-1] if self.published[topic] else None

    def close(self) -> None:
        self.closed = True


def _cfg(channel: str) -> Any:
    # Heartbeats may go missing for 1 s (not 0.3 s): the simulated drives, the host and the
    # bridge share one process, on a machine that may be oversubscribed (seen: load 8 on 2
    # cores). These tests are about the bridge, not about scheduling latency.
    return sim_config(channel, heartbeat_timeout_factor=10.0)


@pytest.fixture
def rig(channel: str) -> Iterator[tuple[SimulatedBase, Chassis]]:
    cfg = _cfg(channel)
    with SimulatedBase.from_config(cfg) as sim, Chassis.open(cfg) as base:
        yield sim, base


def _twist(vx: float, vy: float, wz: float) -> Any:
    from omnican.ros2 import msgs

    return msgs.Twist(msgs.Vector3(vx, vy, 0.0), msgs.Vector3(0.0, 0.0, wz))


def test_bridge_drives_publishes_and_recovers(rig: tuple[SimulatedBase, Chassis]) -> None:
    pytest.importorskip("cyclonedds")
    from omnican.ros2 import msgs
    from omnican.ros2.bridge import TF_DEPTH, Bridge

    sim, base = rig
    t = MemoryTransport()
    with with_truth(base, sim), Bridge(base, Ros2Settings(diagnostics_rate_hz=5.0), t,
                                       sim=sim, poll_thread=False) as bridge:
        assert set(t.readers) == {"/cmd_vel", "/omnican/recover"}
        assert t.qos["/tf"].depth == TF_DEPTH and t.qos["/odom"].reliable
        def at_speed() -> bool:  # cmd_vel kept coming, as a nav stack sends it
            _send(t, bridge, "/cmd_vel", _twist(0.3, 0.0, 0.5))
            odom = t.last("/odom")
            return odom is not None and \
                odom.twist.twist.linear.x == pytest.approx(0.3, abs=0.02) and \
                odom.twist.twist.angular.z == pytest.approx(0.5, abs=0.05)

        assert wait_for(at_speed, 10.0, step=0.02), t.last("/odom")
        # cmd_vel stops: the chassis watchdog stops the base.
        assert wait_for(lambda: abs(t.last("/odom").twist.twist.linear.x) < 1e-3, 2.0)
        time.sleep(0.05)
        odom, truth = t.last("/odom"), sim.true_pose
        assert odom.header.frame_id == "odom" and odom.child_frame_id == "base_link"
        assert odom.pose.pose.position.x == pytest.approx(truth.x, abs=0.005)
        assert model.quaternion_yaw(*_xyzw(odom.pose.pose.orientation)) == \
            pytest.approx(truth.theta, abs=0.005)
        tf = t.last("/tf").transforms[0]
        assert (tf.header.frame_id, tf.child_frame_id) == ("odom", "base_link")
        joints = t.last("/joint_states")
        assert list(joints.name) == ["wheel_0_joint", "wheel_1_joint", "wheel_2_joint"]
        for w, pos in zip(base.wheels, joints.position, strict=True):
            assert pos * 0.05 == pytest.approx(w.travel, abs=1e-3)
        truth_msg = t.last("/omnican/sim/true_pose")
        assert truth_msg.pose.position.x == pytest.approx(truth.x, abs=0.005)

        # A fault: diagnostics at once, ERROR with the EMCY text; cmd_vel no longer moves.
        n_diag = len(t.published["/diagnostics"])
        sim.drives[1].inject_fault(0x2310)
        assert wait_for(lambda: _level(t, "canopen node 2") == model.ERROR, 1.0)
        assert len(t.published["/diagnostics"]) > n_diag
        status = _status(t, "canopen node 2")
        assert "0x2310" in status.message and "over-current" in status.message
        _send(t, bridge, "/cmd_vel", _twist(0.3, 0.0, 0.0))
        time.sleep(0.2)
        assert abs(sim.true_twist.vx) < 1e-3
        # Recover over the topic; the base is enabled again and the note says so.
        _send(t, bridge, "/omnican/recover", msgs.Empty())
        assert wait_for(lambda: base.status.enabled, 5.0)
        assert wait_for(lambda: bridge.recover_note is not None
                        and bridge.recover_note.startswith("ok"), 2.0)
        assert wait_for(lambda: _chassis_level(t) == model.OK, 2.0)
        # NaN commands are counted and refused; nothing moves.
        _send(t, bridge, "/cmd_vel", _twist(math.nan, 0.0, 0.0))
        assert bridge.cmd_vel_rejected == 1
    rates = bridge.achieved_rates()
    assert rates["odom"] > 0 and rates["diagnostics"] > 0


def _send(t: MemoryTransport, bridge: Any, topic: str, msg: Any, writer: int = 1) -> None:
    """A sample arrives and the bridge polls (as its thread does every cycle)."""
    t.deliver(topic, msg, writer)
    bridge.poll()


def _xyzw(q: Any) -> tuple[float, float, float, float]:
    return q.x, q.y, q.z, q.w


def _base_diagnostics(t: MemoryTransport) -> Any:
    """The newest diagnostics: the base's statuses, and the bridge's after them."""
    last = t.last("/diagnostics")
    assert last.status[-1].name == "omnican: ros2 bridge"
    return last


def _status(t: MemoryTransport, hardware_id: str) -> Any:
    return next(s for s in _base_diagnostics(t).status if s.hardware_id == hardware_id)


def _level(t: MemoryTransport, hardware_id: str) -> int:
    return int(_status(t, hardware_id).level)


def _chassis_level(t: MemoryTransport) -> int:
    return int(next(s for s in _base_diagnostics(t).status if s.name.endswith(": chassis")).level)


def test_stamped_cmd_vel_and_no_joint_states_without_a_radius(channel: str) -> None:
    pytest.importorskip("cyclonedds")
    from omnican.ros2 import msgs
    from omnican.ros2.bridge import Bridge

    cfg = _cfg(channel)
    cfg = replace(cfg, wheels=tuple(replace(w, wheel_radius=None) for w in cfg.wheels))
    t = MemoryTransport()
    with SimulatedBase.from_config(cfg) as sim, Chassis.open(cfg) as base, \
            Bridge(base, Ros2Settings(cmd_vel_stamped=True, publish_tf=False), t,
                   poll_thread=False) as bridge:
        assert bridge.wheel_radii is None
        assert "/joint_states" not in t.published and "/tf" not in t.published
        stamped = msgs.TwistStamped(msgs.Header(), _twist(0.0, 0.2, 0.0))
        def at_speed() -> bool:
            _send(t, bridge, "/cmd_vel", stamped)
            return bool(sim.true_twist.vy == pytest.approx(0.2, abs=0.03))

        assert wait_for(at_speed, 10.0, step=0.02), sim.true_twist


def test_cmd_vel_waits_while_another_source_drives(rig: tuple[SimulatedBase, Chassis]) -> None:
    """With another source of the base's commands (``omnican ros2 --foxglove-control``),
    cmd_vel is one source among others: ignored, and counted, while a Foxglove client
    drives; it drives once that one has stopped for the command timeout."""
    pytest.importorskip("cyclonedds")
    from omnican.ros2.bridge import Bridge
    from omnican.ros2.cmd_vel import CMD_VEL_SOURCE

    sim, base = rig
    foxglove = base.command_source("Foxglove client 1")
    t = MemoryTransport()
    with Bridge(base, Ros2Settings(), t, poll_thread=False) as bridge:
        # The Foxglove client drives (a turn), sending as its Teleop panel does; every
        # cmd_vel between its commands is refused, however slowly this machine runs.
        for _ in range(10):
            assert foxglove.drive(Twist(0.0, 0.0, 0.5)).ok
            _send(t, bridge, "/cmd_vel", _twist(0.3, 0.0, 0.0))
            time.sleep(0.02)
        assert bridge.cmd_vel_refused == 10
        assert sim.true_twist.vx == pytest.approx(0.0, abs=0.01)
        time.sleep(0.6)  # the Foxglove client sends nothing more: its hold lapses

        def driven_by_cmd_vel() -> bool:
            _send(t, bridge, "/cmd_vel", _twist(0.3, 0.0, 0.0))
            return ((foxglove.holder() or "").startswith(CMD_VEL_SOURCE) and
                    sim.true_twist.vx == pytest.approx(0.3, abs=0.03))

        assert wait_for(driven_by_cmd_vel, 10.0, step=0.02)


def test_wheel_status_levels() -> None:
    from omnican.chassis import WheelState

    w = WheelState(0, 1, 0, State.OPERATION_ENABLED, 0x637, 3, 0.1, 0.1, 1.0, True, None, None)
    assert model.wheel_status(w, "x", "j")["level"] == model.OK
    assert model.wheel_status(replace(w, state=State.SWITCHED_ON), "x", "j")["level"] == model.WARN
    assert model.wheel_status(replace(w, online=False), "x", "j")["level"] == model.ERROR
    assert model.wheel_status(replace(w, stale=True), "x", "j")["level"] == model.WARN
    assert model.wheel_status(replace(w, error="stuck"), "x", "j")["level"] == model.ERROR
    faulted = model.wheel_status(replace(w, state=State.FAULT, fault="0x2310 x"), "x", "j")
    assert faulted["level"] == model.ERROR and "0x2310" in faulted["message"]
    assert faulted["hardware_id"] == "canopen node 1"
    assert faulted["name"] == "x: wheel 0"


# ------------------------------------------------------------ the command line


@pytest.mark.parametrize(("argv", "message"), [
    (["ros2", "--sim", "--domain-id", "999"], "ros2.domain_id: must be 0-232"),
    (["ros2", "--sim", "--namespace", "a b"], "ros2.namespace: invalid namespace"),
    (["ros2", "--sim", "--remap", "scan:=/scan"], "--remap: cannot remap 'scan'"),
    (["ros2", "--sim", "--base-frame", "odom"], "ros2.base_frame: must differ"),
    (["ros2", "--sim", "--odom-rate", "0"], "must be positive"),
])
def test_bad_invocations_are_one_line_exit_2(argv: list[str], message: str,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's own errors
        code = int(exc.code or 0)
    assert code == 2
    err = capsys.readouterr().err
    assert message in one_error_line(err)


def test_without_the_ros2_extra_it_says_what_to_install(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setitem(__import__("sys").modules, "cyclonedds", None)
    assert main(["ros2", "--sim"]) == 2
    from omnican.extras import install_hint

    assert install_hint("ros2") in one_error_line(capsys.readouterr().err)


def test_bad_ros_domain_id_env(monkeypatch: pytest.MonkeyPatch,
                               capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setenv("ROS_DOMAIN_ID", "seven")
    assert main(["ros2", "--sim"]) == 2
    assert "ROS_DOMAIN_ID: not a number" in one_error_line(capsys.readouterr().err)


def test_settings_from_flags_and_env(monkeypatch: pytest.MonkeyPatch) -> None:
    import argparse

    from omnican.cli import build_parser
    from omnican.cli.ros2 import settings_from

    parser: argparse.ArgumentParser = build_parser()
    args = parser.parse_args(["ros2", "--namespace", "r1", "-r", "cmd_vel:=/nav/cmd_vel",
                              "--no-tf", "--dds-peer", "10.1.1.1", "--no-multicast"])
    s = settings_from(args, {"odom_rate_hz": 20}, "test", env={"ROS_DOMAIN_ID": "5"})
    assert s.domain_id == 5 and s.odom_rate_hz == 20 and not s.publish_tf
    assert s.topic("cmd_vel") == "/nav/cmd_vel" and s.topic("odom") == "/r1/odom"
    assert s.peers == ("10.1.1.1",) and not s.multicast and not s.loopback_only
    sim = settings_from(parser.parse_args(["ros2", "--sim"]), None, "test", env={})
    assert sim.loopback_only and sim.domain_id == 0
    # --sim with a network named: that network, not loopback.
    away = settings_from(parser.parse_args(["ros2", "--sim", "--dds-interface", "eth0"]), None,
                         "test", env={})
    assert not away.loopback_only and away.interface == "eth0"


def test_ros2_sim_console_is_the_simulators_with_recover(channel: str) -> None:
    """omnican ros2 --sim takes every command omnican sim takes (freeze and thaw too)."""
    import types

    from omnican.cli.ros2 import command

    with SimulatedBase.from_config(sim_config(channel)) as sim:
        recovered: list[bool] = []
        bridge = types.SimpleNamespace(sim=sim, recover_note=None,
                                       recover=lambda answered=False: recovered.append(answered)
                                       or True)
        assert command(bridge, "freeze 2") == "node 2: frozen" and sim.drives[1].frozen
        assert command(bridge, "thaw 2") == "node 2: thawed" and not sim.drives[1].frozen
        assert "freeze NODE" in (command(bridge, "help") or "")
        assert command(bridge, "recover") == "recovered" and recovered == [True]  # answered
        assert (command(bridge, "bogus") or "").startswith("error:")
        assert command(bridge, "quit") is None


def test_battery_state_is_published_at_its_rate_and_follows_the_battery(
        rig: tuple[SimulatedBase, Chassis]) -> None:
    """battery_state (relative, in the namespace): the drives' DC link, once a second by
    default; the e-stop and a low battery through ros2 --sim's console."""
    pytest.importorskip("cyclonedds")
    from omnican.cli.ros2 import command
    from omnican.ros2.bridge import Bridge

    sim, base = rig
    t = MemoryTransport()
    settings = Ros2Settings(namespace="/robot1", battery_state_rate_hz=10.0)
    with with_truth(base, sim), Bridge(base, settings, t, sim=sim) as bridge:
        assert wait_for(lambda: t.last("/robot1/battery_state") is not None, 2.0)
        msg = t.last("/robot1/battery_state")
        assert msg.voltage == pytest.approx(24.0, abs=0.2) and msg.power_supply_health == 1
        assert math.isnan(msg.current) and msg.present
        assert command(bridge, "battery 19") == "battery 19 V"
        assert wait_for(lambda: t.last("/robot1/battery_state").power_supply_health == 3, 3.0)
        assert "battery" in (base.status.stopped_reason or "")
        assert command(bridge, "estop on") == "e-stop pressed"
        assert wait_for(lambda: base.status.estop, 1.0)
        assert command(bridge, "estop off") == "e-stop released"
        assert command(bridge, "battery 24") == "battery 24 V"
        assert wait_for(lambda: t.last("/robot1/battery_state").power_supply_health == 1, 3.0)
        assert wait_for(lambda: not base.status.estop, 1.0)
        assert bridge.recover()
    # Every fifth sample (10 Hz of the 50 Hz state), odom every one; none in the samples
    # before the first health values came (a health period: a few samples).
    battery, odom = len(t.published["/robot1/battery_state"]), len(t.published["/robot1/odom"])
    assert odom // 5 - 3 <= battery <= odom // 5 + 1


# ------------------------------------------------------------ hostile and buggy publishers


@pytest.fixture
def stepped(channel: str) -> Iterator[tuple[Any, SimulatedBase, Chassis]]:
    with lockstep_rig(channel) as r:
        yield r


def _bridge(base: Chassis, t: MemoryTransport, **settings: Any) -> Any:
    from omnican.ros2.bridge import Bridge

    return Bridge(base, Ros2Settings(**settings), t, poll_thread=False)


def test_a_flood_costs_one_parsed_sample_per_publisher_and_poll(
        stepped: tuple[Any, SimulatedBase, Chassis]) -> None:
    """10,000 samples between two polls (a 10 kHz flood at 1 poll a second): the reader
    keeps the newest few, the bridge parses only the newest and drives with it."""
    pytest.importorskip("cyclonedds")
    from omnican.ros2.cmd_vel import CMD_VEL_DEPTH

    clock, sim, base = stepped
    t = MemoryTransport()
    with _bridge(base, t) as bridge:
        for k in range(10_000):
            t.deliver("/cmd_vel", _twist(0.3 * k / 9_999, 0.0, 0.0))
        bridge.poll()
        assert bridge.cmd_vel_count == CMD_VEL_DEPTH  # taken, unparsed
        assert bridge.cmd_vel_parsed == 1  # parsed and applied: the newest only
        for _ in range(40):  # a nav stack's 20 Hz, each time a burst of 100
            for _ in range(100):
                t.deliver("/cmd_vel", _twist(0.3, 0.0, 0.0))
            bridge.poll()
            clock.sleep(0.05)
        assert bridge.cmd_vel_parsed == 41
        assert sim.true_twist.vx == pytest.approx(0.3, abs=0.01)


def test_oversized_and_broken_samples_are_refused_unread_and_quoted_short(
        stepped: tuple[Any, SimulatedBase, Chassis], caplog: pytest.LogCaptureFixture) -> None:
    pytest.importorskip("cyclonedds")
    from omnican.ros2 import msgs

    clock, sim, base = stepped
    t = MemoryTransport()
    with _bridge(base, t, cmd_vel_stamped=True) as bridge:
        # A TwistStamped with a 2 MB frame id; bytes that are no TwistStamped at all.
        huge = msgs.TwistStamped(msgs.Header(frame_id="x" * 2_000_000), _twist(0.3, 0, 0))
        t.deliver("/cmd_vel", huge, writer=7)
        bridge.poll()
        t.deliver_raw("/cmd_vel", b"\x00\x01\x00\x00" + b"\xff" * 20, writer=8)
        bridge.poll()
        clock.sleep(0.3)
        assert bridge.cmd_vel_rejected == 2
        assert sim.true_twist.vx == pytest.approx(0.0, abs=1e-6)
    said = [r.getMessage() for r in caplog.records if "cmd_vel from" in r.getMessage()]
    sizes = [int(m.group(1)) for m in map(re.compile(r"a (\d+)-byte sample").search, said) if m]
    assert sizes and sizes[0] > 2_000_000, said
    assert any("cannot be read as a geometry_msgs/msg/TwistStamped" in m for m in said), said
    assert max(len(m) for m in said) < 300


def test_one_publisher_drives_at_a_time(stepped: tuple[Any, SimulatedBase, Chassis],
                                        caplog: pytest.LogCaptureFixture) -> None:
    """Two cmd_vel publishers: the first drives, the second is ignored (and the log says
    who drives) until the first has sent nothing for the command timeout."""
    pytest.importorskip("cyclonedds")
    clock, sim, base = stepped
    caplog.set_level("INFO", logger="omnican.ros2.cmd_vel")
    t = MemoryTransport()
    first, second = f"{1:032x}", f"{2:032x}"
    with _bridge(base, t) as bridge:
        for _ in range(30):  # both at 20 Hz, in the same poll
            t.deliver("/cmd_vel", _twist(0.2, 0.0, 0.0), writer=1)
            t.deliver("/cmd_vel", _twist(0.0, 0.2, 0.0), writer=2)
            bridge.poll()
            clock.sleep(0.05)
        assert sim.true_twist.vx == pytest.approx(0.2, abs=0.01)
        assert sim.true_twist.vy == pytest.approx(0.0, abs=0.01)
        assert bridge.cmd_vel_refused == 30
        # The first stops; the second keeps sending: the base stops (the watchdog), then
        # the second drives.
        for _ in range(30):
            t.deliver("/cmd_vel", _twist(0.0, 0.2, 0.0), writer=2)
            bridge.poll()
            clock.sleep(0.05)
        assert sim.true_twist.vx == pytest.approx(0.0, abs=0.01)
        assert sim.true_twist.vy == pytest.approx(0.2, abs=0.01)
    said = [r.getMessage() for r in caplog.records]
    assert f"ROS 2 cmd_vel publisher {first} drives the base" in said
    assert f"ROS 2 cmd_vel publisher {second} drives the base" in said
    ignored = [m for m in said if m.startswith(f"cmd_vel from ROS 2 cmd_vel publisher {second} "
                                               "ignored")]
    assert ignored and f"publisher {first} is driving the base" in ignored[0]
    assert len(ignored) <= 2  # throttled: not one line per sample


def test_many_publishers_cost_no_more_than_a_few(
        stepped: tuple[Any, SimulatedBase, Chassis]) -> None:
    """200 other writers beside the one driving: each poll parses the driver's sample and
    refuses the others unread; while no one drives, a few are parsed a poll."""
    pytest.importorskip("cyclonedds")
    from omnican.ros2.cmd_vel import MAX_PARSED_PER_POLL

    clock, sim, base = stepped
    t = MemoryTransport()
    with _bridge(base, t) as bridge:
        for _ in range(20):
            t.deliver("/cmd_vel", _twist(0.2, 0.0, 0.0), writer=1)
            for w in range(2, 202):
                t.deliver("/cmd_vel", _twist(0.0, -0.2, 0.0), writer=w)
            bridge.poll()
            clock.sleep(0.05)
        assert bridge.cmd_vel_parsed <= 20 + MAX_PARSED_PER_POLL  # the first poll's race
        assert sim.true_twist.vy == pytest.approx(0.0, abs=0.01)
        # No one drives: the first poll parses a few, one of them takes control, and from
        # then on it alone is parsed.
        clock.sleep(1.0)
        parsed = bridge.cmd_vel_parsed
        for _ in range(10):
            for w in range(2, 202):
                t.deliver("/cmd_vel", _twist(0.0, -0.2, 0.0), writer=w)
            bridge.poll()
            clock.sleep(0.05)
        assert bridge.cmd_vel_parsed - parsed <= 10 + MAX_PARSED_PER_POLL
        assert sim.true_twist.vy == pytest.approx(-0.2, abs=0.01)


@pytest.mark.parametrize(("stamped", "arrives", "hint"), [
    (False, "geometry_msgs/msg/TwistStamped", "start with --cmd-vel-stamped"),
    (True, "geometry_msgs/msg/Twist", "start without --cmd-vel-stamped"),
    (False, "std_msgs/msg/String", "TwistStamped with --cmd-vel-stamped"),
])
def test_a_cmd_vel_publisher_of_another_type_is_named_once(
        stepped: tuple[Any, SimulatedBase, Chassis], caplog: pytest.LogCaptureFixture,
        stamped: bool, arrives: str, hint: str) -> None:
    pytest.importorskip("cyclonedds")
    from omnican.ros2.transport import Publication

    _, _, base = stepped
    t = MemoryTransport()
    with _bridge(base, t, cmd_vel_stamped=stamped) as bridge:
        for _ in range(3):  # discovered again and again (e.g. its QoS changed)
            t.discovered += [Publication("ab" * 16, "/cmd_vel", arrives),
                             Publication("cd" * 16, "/other", arrives)]
            for _ in range(10):
                bridge.poll()
    said = [r.getMessage() for r in caplog.records if "ab" * 16 in r.getMessage()]
    assert len(said) == 1, said
    assert arrives in said[0] and hint in said[0] and said[0].startswith("/cmd_vel:")
    assert not any("cd" * 16 in r.getMessage() for r in caplog.records)
    assert bridge.wrong_types == {"ab" * 16: arrives}


@settings(deadline=None)
@given(st.one_of(st.text(max_size=5000), st.floats(allow_nan=True), st.integers()))
def test_quoted_values_stay_short(value: Any) -> None:
    from omnican.ros2.cmd_vel import QUOTE_CHARS, quote

    text = quote(value)
    assert len(text) <= QUOTE_CHARS + 40
    if len(repr(value)) <= QUOTE_CHARS:
        assert text == repr(value)


@settings(deadline=None)
@given(names, names)
def test_ros_type_names_from_dds_names(package: str, message: str) -> None:
    from omnican.ros2.transport import ros_type_name

    assert ros_type_name(f"{package}::msg::dds_::{message}_") == f"{package}/msg/{message}"
    assert ros_type_name(f"{package}::{message}") == f"{package}::{message}"  # not ROS 2's


def test_absurd_cmd_vel_values_are_refused_as_from_every_front_end(
        rig: tuple[SimulatedBase, Chassis], caplog: pytest.LogCaptureFixture) -> None:
    """A Twist of 1e308 drove at the wheel limit, three of them moved nothing (the
    scaling overflowed): the base refuses a value beyond sense (the check Foxglove's
    commands get too), the bridge counts it and says why, and no command reaches the
    base."""
    pytest.importorskip("cyclonedds")
    from omnican.ros2.bridge import Bridge

    _, base = rig
    t = MemoryTransport()
    with caplog.at_level("WARNING", logger="omnican"), \
            Bridge(base, Ros2Settings(), t, poll_thread=False) as bridge:
        for twist in (_twist(1e308, 0.0, 0.0), _twist(0.0, -1e308, 0.0),
                      _twist(0.0, 0.0, 1e9)):
            t.deliver("/cmd_vel", twist)
            bridge.poll()
        assert bridge.cmd_vel_rejected == 3
        assert base.command == Twist()
    assert "velocity command refused: vx 1e+308 m/s is beyond any wheeled base" in caplog.text
