"""The Zenoh front end against zenoh-ros2-sdk, an independent rmw_zenoh peer, on a
loopback router: the simulated base in lock-step, the test stepping its clock while the
Zenoh side answers in its own threads (waits have a generous real-time timeout for the
event; nothing is timed)."""

from __future__ import annotations

import itertools
import logging
import math
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from omnican.chassis import Chassis
from omnican.clock import SimClock
from omnican.sim import SimulatedBase
from omnican.zenoh import rmw
from tests.support.helpers import lockstep_rig, with_truth
from tests.zenoh.conftest import client, wait_real

pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed "
                    "(pip install 'omnican[zenoh]')")

TIMEOUT_S = 60.0  # real seconds: generous, for a loaded machine; a pass takes far less


@pytest.fixture
def stepped(channel: str) -> Iterator[tuple[SimClock, SimulatedBase, Chassis]]:
    with lockstep_rig(channel) as r:
        yield r


@pytest.fixture
def bridge(stepped: tuple[SimClock, SimulatedBase, Chassis], router: str) -> Iterator[Any]:
    from omnican.zenoh.bridge import ZenohBridge, open_session
    from omnican.zenoh.settings import ZenohSettings

    _, _, base = stepped
    settings = ZenohSettings(mode="client", connect=(router,),
                             rates_hz={"/odom": 50.0, "/joint_states": 50.0,
                                       "/battery_state": 10.0})
    session = open_session(settings)
    try:
        with ZenohBridge(base, settings, session, poll_thread=False) as b:
            yield b
    finally:
        session.close()


def run_until(clock: SimClock, bridge: Any, done: Callable[[], bool],
              each: Callable[[], None] | None = None) -> bool:
    """Step the simulation (and poll the bridge) until ``done()`` or TIMEOUT_S real
    seconds; ``each``: what a publisher does every step (a nav stack's stream)."""
    deadline = time.monotonic() + TIMEOUT_S
    while time.monotonic() < deadline:
        if each is not None:
            each()
        clock.sleep(0.02)
        bridge.poll()
        if done():
            return True
        time.sleep(0.002)  # the Zenoh side's threads deliver meanwhile
    return done()


def test_the_sdk_decodes_odom_and_battery_state(stepped: tuple[SimClock, SimulatedBase, Chassis],
                                                bridge: Any, sdk: Any) -> None:
    clock, _, base = stepped
    got: dict[str, list[Any]] = {"odom": [], "battery": []}
    odom = sdk.ROS2Subscriber("/odom", "nav_msgs/msg/Odometry", got["odom"].append,
                              router_port=_port(bridge))
    battery = sdk.ROS2Subscriber("/battery_state", "sensor_msgs/msg/BatteryState",
                                 got["battery"].append, router_port=_port(bridge))
    try:
        # The SDK computed its key from its own .msg files: the same key means the same
        # type hash.
        assert odom.keyexpr == bridge.publishers["/odom"].key
        assert battery.keyexpr == bridge.publishers["/battery_state"].key
        assert run_until(clock, bridge, lambda: bool(got["odom"] and got["battery"]))
        last = got["odom"][-1]
        assert (last.header.frame_id, last.child_frame_id) == ("odom", "base_link")
        assert last.pose.pose.position.x == pytest.approx(base.pose.x, abs=0.01)
        volts = got["battery"][-1]
        assert volts.voltage == pytest.approx(24.0, abs=0.2) and volts.present
    finally:
        odom.close()
        battery.close()


def test_the_sdks_twist_drives_the_base(stepped: tuple[SimClock, SimulatedBase, Chassis],
                                         bridge: Any, sdk: Any) -> None:
    clock, sim, _ = stepped
    pub = sdk.ROS2Publisher("/cmd_vel", "geometry_msgs/msg/Twist", router_port=_port(bridge))
    vector3 = pub.session_mgr.store.types["geometry_msgs/msg/Vector3"]
    assert pub.keyexpr == bridge.cmd_key
    try:
        start = sim.true_pose.x

        def send() -> None:
            pub.publish(linear=vector3(0.3, 0.0, 0.0), angular=vector3(0.0, 0.0, 0.0))

        assert run_until(clock, bridge, lambda: sim.true_pose.x > start + 0.05, each=send)
        assert sim.true_twist.vx == pytest.approx(0.3, abs=0.02)
        assert bridge.cmd_vel_rejected == 0
        # The publisher stops: the watchdog stops the base.
        assert run_until(clock, bridge, lambda: abs(sim.true_twist.vx) < 1e-3)
    finally:
        pub.close()


def test_attachments_count_up_by_one_with_a_fixed_gid(
        stepped: tuple[SimClock, SimulatedBase, Chassis], bridge: Any, router: str) -> None:
    Attachment = pytest.importorskip(  # the independent reading
        "zenoh_ros2_sdk.attachment", reason="zenoh-ros2-sdk is not installed "
        "(pip install zenoh-ros2-sdk)").Attachment

    clock, _, _ = stepped
    seen: list[Any] = []
    lock = threading.Lock()

    def on_sample(sample: Any) -> None:
        with lock:
            seen.append(Attachment.from_bytes(sample.attachment.to_bytes()))

    session = client(router)
    try:
        sub = session.declare_subscriber(bridge.publishers["/odom"].key, on_sample)
        assert run_until(clock, bridge, lambda: len(seen) >= 20)
        sub.undeclare()
        with lock:
            got = list(seen)
        seqs = [a.sequence_id for a in got]
        assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))
        assert {a.gid for a in got} == {bridge.publishers["/odom"].gid}
        assert all(b.timestamp_ns > a.timestamp_ns for a, b in itertools.pairwise(got))
        tokens = [str(r.ok.key_expr) for r in
                  session.liveliness().get("@ros2_lv/0/**", timeout=10.0) if r.ok]
    finally:
        session.close()
    assert bridge.node.token() in tokens
    assert {p.token_key for p in bridge.publishers.values()} <= set(tokens)
    assert any("/MS/" in t and "%cmd_vel/geometry_msgs::msg::dds_::Twist_/" in t
               for t in tokens)


def test_malformed_nan_and_oversized_commands_move_nothing(
        stepped: tuple[SimClock, SimulatedBase, Chassis], bridge: Any, router: str,
        caplog: pytest.LogCaptureFixture) -> None:
    import zenoh

    from omnican.telemetry import cdr

    clock, sim, _ = stepped
    twist = {"linear": {"x": math.nan, "y": 0.0, "z": 0.0},
             "angular": {"x": 0.0, "y": 0.0, "z": 0.0}}
    bad = {"nan": cdr.encode("geometry_msgs/msg/Twist", twist),
           "malformed": b"\x00\x01\x00\x00" + b"\xff" * 5,
           "oversized": b"\x00\x01\x00\x00" + bytes(2_000_000)}
    session = client(router)
    caplog.set_level(logging.WARNING, logger="omnican.zenoh.bridge")
    try:
        # Blocking, as a reliable ROS 2 publisher sends: a 2 MB sample is not dropped on
        # the way when the queue is full, it reaches the bridge to be refused there.
        pub = session.declare_publisher(bridge.cmd_key,
                                        congestion_control=zenoh.CongestionControl.BLOCK)
        # A put before the router told this session of the bridge's subscriber goes
        # nowhere: wait until it knows.
        assert wait_real(lambda: pub.matching_status.matching)
        for n, (_, payload) in enumerate(bad.items()):
            gid = bytes([n + 1]) * 16  # three publishers: one line each
            pub.put(payload, attachment=rmw.Attachment(1, 0, gid).encode())
        assert run_until(clock, bridge, lambda: bridge.cmd_vel_rejected == 3), \
            (bridge.cmd_vel_count, bridge.cmd_vel_rejected, [r.getMessage() for r in caplog.records])
        clock.sleep(0.3)
        assert sim.true_twist.vx == pytest.approx(0.0, abs=1e-6)
        assert sim.true_twist.wz == pytest.approx(0.0, abs=1e-6)
        pub.undeclare()
    finally:
        session.close()
    said = [r.getMessage() for r in caplog.records if "cmd_vel from" in r.getMessage()]
    assert len(said) == 3, said
    assert any("not finite" in m for m in said)
    assert any("cannot be read as a geometry_msgs/msg/Twist" in m for m in said)
    assert any("2000004-byte sample" in m for m in said)
    assert max(len(m) for m in said) < 300


def _port(bridge: Any) -> int:
    (endpoint,) = bridge.settings.connect
    return int(endpoint.rsplit(":", 1)[1])


def test_a_second_controller_is_refused_while_the_first_drives(
        stepped: tuple[SimClock, SimulatedBase, Chassis], bridge: Any, router: str) -> None:
    from omnican.telemetry import cdr

    clock, sim, _ = stepped

    def twist(vx: float) -> bytes:
        return cdr.encode("geometry_msgs/msg/Twist", {"linear": {"x": vx, "y": 0.0, "z": 0.0},
                                                      "angular": {"x": 0.0, "y": 0.0, "z": 0.0}})

    session = client(router)
    try:
        pub = session.declare_publisher(bridge.cmd_key)
        assert wait_real(lambda: pub.matching_status.matching)
        first, second = bytes([0xA1]) * 16, bytes([0xB2]) * 16
        seq = itertools.count(1)

        def send(*who: tuple[bytes, float]) -> Callable[[], None]:
            def each() -> None:
                for gid, vx in who:
                    pub.put(twist(vx), attachment=rmw.Attachment(next(seq), 0, gid).encode())
            return each

        assert run_until(clock, bridge, lambda: sim.true_twist.vx > 0.15,
                         each=send((first, 0.2)))
        assert run_until(clock, bridge, lambda: bridge.cmd_vel_refused >= 20,
                         each=send((first, 0.2), (second, -0.2)))
        assert sim.true_twist.vx == pytest.approx(0.2, abs=0.02)
        assert bridge.holder() == f"Zenoh cmd_vel publisher {first.hex()}"
        pub.undeclare()
    finally:
        session.close()


def test_closing_withdraws_the_graph_tokens(
        stepped: tuple[SimClock, SimulatedBase, Chassis], bridge: Any, router: str) -> None:
    from omnican.zenoh.services import SERVICES

    session = client(router)
    try:
        def tokens() -> set[str]:
            return {str(r.ok.key_expr) for r in
                    session.liveliness().get("@ros2_lv/**", timeout=10.0) if r.ok}

        node = bridge.node.token()
        ours = f"/{bridge.node.session_id}/"  # the node's and its endpoints' tokens
        assert wait_real(lambda: node in tokens())
        # the node, its publishers, cmd_vel's subscription and the services
        assert sum(ours in t for t in tokens()) == 2 + len(bridge.publishers) + len(SERVICES)
        bridge.close()
        assert wait_real(lambda: not any(ours in t for t in tokens()))
        bridge.poll()  # closed: takes nothing, raises nothing
    finally:
        session.close()


@pytest.mark.parametrize("type_name", ["nav_msgs/msg/Odometry", "sensor_msgs/msg/JointState",
                                       "diagnostic_msgs/msg/DiagnosticArray",
                                       "sensor_msgs/msg/BatteryState", "geometry_msgs/msg/Twist",
                                       "std_msgs/msg/String"])
def test_type_hashes_match_the_sdks_from_the_msg_files(sdk: Any, type_name: str) -> None:
    """rosbags' Jazzy store (ours) and the SDK's hash of the wheels' .msg files agree
    (tf2_msgs has no wheel on PyPI: its TFMessage is checked by neither)."""
    from zenoh_ros2_sdk.message_registry import get_registry
    from zenoh_ros2_sdk.utils import get_type_hash, load_dependencies_recursive

    registry = get_registry()
    path = registry.get_msg_file_path(type_name)
    assert path is not None and path.is_file()
    text = path.read_text()
    deps = load_dependencies_recursive(type_name, text, registry)
    assert get_type_hash(type_name, msg_definition=text, dependencies=deps) == \
        rmw.type_hash(type_name)


def test_a_flood_costs_one_parsed_sample_per_publisher_and_poll(
        stepped: tuple[SimClock, SimulatedBase, Chassis], bridge: Any, router: str) -> None:
    """Thousands of samples between polls: the ring keeps the newest, the bridge parses
    one a poll (the publisher's newest) and drives with it."""
    from omnican.telemetry import cdr
    from omnican.zenoh.bridge import CMD_VEL_DEPTH

    clock, sim, _ = stepped
    session = client(router)
    try:
        pub = session.declare_publisher(bridge.cmd_key)
        assert wait_real(lambda: pub.matching_status.matching)
        gid = bytes([0xF1]) * 16
        seq = itertools.count(1)

        def flood() -> None:
            for k in range(500):
                vx = 0.3 * k / 499
                pub.put(cdr.encode("geometry_msgs/msg/Twist",
                                   {"linear": {"x": vx, "y": 0.0, "z": 0.0},
                                    "angular": {"x": 0.0, "y": 0.0, "z": 0.0}}),
                        attachment=rmw.Attachment(next(seq), 0, gid).encode())

        assert run_until(clock, bridge, lambda: sim.true_twist.vx > 0.25, each=flood)
        assert bridge.cmd_vel_parsed <= bridge.polls
        assert bridge.cmd_vel_count <= CMD_VEL_DEPTH * bridge.polls
        assert bridge.cmd_vel_rejected == 0
        pub.undeclare()
    finally:
        session.close()


def test_a_stamped_cmd_vel_drives_when_asked_for(
        stepped: tuple[SimClock, SimulatedBase, Chassis], router: str, sdk: Any) -> None:
    from omnican.zenoh.bridge import ZenohBridge, open_session
    from omnican.zenoh.settings import ZenohSettings

    clock, sim, base = stepped
    settings = ZenohSettings(mode="client", connect=(router,), cmd_vel_stamped=True,
                             namespace="/robot1")
    session = open_session(settings)
    try:
        with ZenohBridge(base, settings, session, poll_thread=False) as bridge:
            pub = sdk.ROS2Publisher("/robot1/cmd_vel", "geometry_msgs/msg/TwistStamped",
                                    router_port=int(router.rsplit(":", 1)[1]))
            assert pub.keyexpr == bridge.cmd_key
            types = pub.session_mgr.store.types
            twist = types["geometry_msgs/msg/Twist"](types["geometry_msgs/msg/Vector3"](
                0.0, 0.0, 0.0), types["geometry_msgs/msg/Vector3"](0.0, 0.0, 0.5))
            header = types["std_msgs/msg/Header"](types["builtin_interfaces/msg/Time"](0, 0),
                                                  "base_link")
            try:
                assert run_until(clock, bridge, lambda: sim.true_twist.wz > 0.4,
                                 each=lambda: pub.publish(header=header, twist=twist))
            finally:
                pub.close()
    finally:
        session.close()


def test_the_simulators_truth_goes_along_when_given(
        stepped: tuple[SimClock, SimulatedBase, Chassis], router: str) -> None:
    from omnican.core.kinematics import Twist
    from omnican.telemetry import cdr
    from omnican.zenoh.bridge import TRUE_POSE, ZenohBridge, open_session
    from omnican.zenoh.settings import ZenohSettings

    clock, sim, base = stepped
    settings = ZenohSettings(mode="client", connect=(router,), namespace="/robot2")
    session, watcher = open_session(settings), client(router)
    got: list[bytes] = []
    try:
        with with_truth(base, sim), \
                ZenohBridge(base, settings, session, sim=sim, poll_thread=False) as bridge:
            pub = bridge.publishers[TRUE_POSE]
            assert pub.name == "/robot2/sim/true_pose"
            sub = watcher.declare_subscriber(pub.key,
                                             lambda sample: got.append(sample.payload.to_bytes()))
            forward = Twist(0.2, 0.0, 0.0)
            assert run_until(clock, bridge, lambda: sim.true_pose.x > 0.05 and len(got) > 2,
                             each=lambda: base.set_twist(forward))
            sub.undeclare()
            pose = cdr.decode("geometry_msgs/msg/PoseStamped", got[-1])["pose"]["position"]
            assert 0.0 < pose["x"] <= sim.true_pose.x
    finally:
        watcher.close()
        session.close()
