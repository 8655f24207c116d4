"""The fleet's credentials on real Zenoh sessions, everything on 127.0.0.1, multicast off:
a simulated base in lock-step with its Zenoh front end under a base's certificate, alone
(peers link to it directly) or behind a router under a router's; raw eclipse-zenoh
sessions as the hostile peers (no certificate, another CA's, a viewer's, a removed
member's) and as the operator; zenoh-ros2-sdk as an independent rmw_zenoh peer given an
operator's certificate. Waits have a generous real-time deadline for the state they
check; what is denied is shown by a later message of the same link that gets through
(Zenoh keeps a link's order) or by a query that ends unanswered."""

from __future__ import annotations

import contextlib
import itertools
import json
import shutil
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import pytest

from omnican.chassis import Chassis
from omnican.clock import SimClock
from omnican.config import ImuSettings
from omnican.sim import SimulatedBase
from omnican.zenoh import rmw
from omnican.zenoh.security import Identity, tls_entries
from tests.support.helpers import lockstep_rig, sim_config
from tests.zenoh.conftest import free_port, wait_real
from tests.zenoh.test_bridge import run_until

zenoh = pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed "
                            "(pip install 'omnican[zenoh]')")
pytest.importorskip("cryptography", reason="cryptography is not installed "
                    "(pip install 'omnican[zenoh-security]')")

TWIST = "geometry_msgs/msg/Twist"
NO_ANSWER_S = 3.0  # how long a refused query waits before it ends unanswered


@dataclass(frozen=True)
class Creds:
    root: Path  # the fleet: robot1, robot2, operator alice, viewer bob, router router
    removed: Path  # a folder holding mallory's files, a member since removed
    foreign: Path  # another fleet (another CA) that also has an operator alice


@pytest.fixture(scope="module")
def creds(tmp_path_factory: pytest.TempPathFactory) -> Creds:
    from omnican.zenoh.credentials import make

    base = tmp_path_factory.mktemp("fleets")
    root = base / "fleet"
    members = [Identity("base", "robot1"), Identity("base", "robot2"),
               Identity("operator", "alice"), Identity("viewer", "bob"),
               Identity("router", "router")]
    make(root, [*members, Identity("operator", "mallory")])
    removed = base / "mallory"
    shutil.copytree(root / "operator" / "mallory", removed)
    make(root, [], remove=("mallory",))
    foreign = base / "foreign"
    make(foreign, [Identity("operator", "alice")])
    return Creds(root, removed, foreign)


def member(root: Path | None, who: str | None, endpoint: str, *,
           folder: Path | None = None, tls: bool = True) -> Any:
    """A raw client session linked to ``endpoint`` presenting ``who``'s certificate
    (``folder``: its cert.pem and key.pem from there); ``who`` None: over TLS with the
    CA's certificate but none of its own, or (``tls`` False) a plain TCP link."""
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", "[]")
    if not tls:
        endpoint = endpoint.replace("tls/", "tcp/", 1)
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    if root is not None:
        if who is not None:
            place = folder or root / Identity.parse(who).folder
            for path, value in tls_entries(str(root / "ca.pem"), str(place / "cert.pem"),
                                           str(place / "key.pem")):
                conf.insert_json5(path, value)
        else:
            conf.insert_json5("transport/link/tls", json.dumps(
                {"root_ca_certificate": str(root / "ca.pem"), "enable_mtls": True,
                 "verify_name_on_connect": False}))
    return zenoh.open(conf)


def twist(vx: float) -> bytes:
    from omnican.telemetry import cdr

    return cdr.encode(TWIST, {"linear": {"x": vx, "y": 0.0, "z": 0.0},
                              "angular": {"x": 0.0, "y": 0.0, "z": 0.0}})


class Driver:
    """A cmd_vel publisher on ``session`` sending ``vx`` each time it is called."""

    def __init__(self, session: Any, key: str, vx: float, gid: bytes) -> None:
        self.pub = session.declare_publisher(key)
        self.payload = twist(vx)
        self.gid = gid
        self.seq = itertools.count(1)
        self.sent = 0

    def __call__(self) -> None:
        self.pub.put(self.payload, attachment=rmw.Attachment(
            next(self.seq), time.time_ns(), self.gid).encode())
        self.sent += 1


def call(clock: SimClock, bridge: Any, session: Any, name: str, *,
         each: Callable[[], None] | None = None) -> tuple[bool, str] | None:
    """Call the base's ``~/name`` from ``session``, stepping the base until the query
    ends: (success, message) of its answer, or None when it ended unanswered."""
    from omnican.zenoh.services import TRIGGER_REQUEST, read_trigger_response, service_key

    replies: list[Any] = []
    ended = threading.Event()
    session.get(service_key(bridge.node, name),
                zenoh.handlers.Callback(replies.append, ended.set),
                payload=TRIGGER_REQUEST,
                attachment=rmw.Attachment(1, 0, bytes(range(16))).encode(),
                timeout=NO_ANSWER_S)
    assert run_until(clock, bridge, ended.is_set, each=each)
    answers = [r.ok for r in replies if r.ok is not None]
    return read_trigger_response(answers[0].payload.to_bytes()) if answers else None


@dataclass
class Rig:
    clock: SimClock
    sim: SimulatedBase
    base: Chassis
    bridge: Any
    endpoint: str  # where members link: the base's own listener, or the router's


@contextlib.contextmanager
def secured_base(channel: str, root: Path, *, behind_router: bool,
                 imu_topic: str | None = None) -> Iterator[Rig]:
    """The base robot1 under its certificate: alone (a peer listening on TLS, members
    link to it) or a client of a router under the router's certificate; ``imu_topic``:
    with ``[imu] source = "zenoh"`` on that topic."""
    from omnican.zenoh.bridge import ZenohBridge, open_session
    from omnican.zenoh.settings import ZenohSettings

    endpoint = f"tls/127.0.0.1:{free_port()}"
    creds = {"credentials": str(root)}
    with contextlib.ExitStack() as stack:
        if behind_router:
            router = open_session(ZenohSettings(mode="router", listen=(endpoint,),
                                                identity="router/router", **creds))
            stack.callback(router.close)
            settings = ZenohSettings(mode="client", connect=(endpoint,), namespace="/robot1",
                                     identity="base/robot1", **creds)
        else:
            settings = ZenohSettings(mode="peer", listen=(endpoint,), namespace="/robot1",
                                     identity="base/robot1", **creds)
        if imu_topic is None:
            clock, sim, base = stack.enter_context(lockstep_rig(channel))
        else:
            cfg = replace(sim_config(channel), imu=ImuSettings("zenoh", topic=imu_topic))
            clock = SimClock()
            sim = stack.enter_context(SimulatedBase.from_config(cfg, clock=clock))
            base = stack.enter_context(Chassis.open(cfg, clock=clock))
        session = open_session(settings)
        stack.callback(session.close)
        bridge = stack.enter_context(ZenohBridge(base, settings, session, poll_thread=False))
        yield Rig(clock, sim, base, bridge, endpoint)


def at_rest(rig: Rig) -> bool:
    t = rig.sim.true_twist
    return abs(t.vx) < 1e-3 and abs(t.vy) < 1e-3 and abs(t.wz) < 1e-3


def linked(rig: Rig, session: Any) -> None:
    """``session`` hears of the base's cmd_vel subscriber (its link is up, its
    declarations through): what it sends from now on reaches the base's side."""
    pub = session.declare_publisher(rig.bridge.cmd_key)
    try:
        assert wait_real(lambda: pub.matching_status.matching)
    finally:
        pub.undeclare()


@pytest.mark.parametrize("behind_router", [False, True], ids=["alone", "behind a router"])
def test_no_certificate_no_link(channel: str, creds: Creds, behind_router: bool) -> None:
    """Without a certificate of the fleet's CA nothing links at all: plain TCP, TLS with
    no certificate of its own, or the certificate of another CA (of a same-named member)."""
    with secured_base(channel, creds.root, behind_router=behind_router) as rig:
        for root, who, tls in ((creds.root, "operator/alice", False), (creds.root, None, True),
                               (creds.foreign, "operator/alice", True)):
            with pytest.raises(zenoh.ZError, match="Unable to connect"):
                member(root, who, rig.endpoint, tls=tls).close()
        assert rig.bridge.cmd_vel_count == 0


@pytest.mark.parametrize("behind_router", [False, True], ids=["alone", "behind a router"])
@pytest.mark.parametrize("hostile", ["viewer/bob", "removed"])
def test_a_denied_peer_neither_drives_nor_recovers(channel: str, creds: Creds,
                                                  behind_router: bool, hostile: str) -> None:
    """A viewer (or a member since removed) that publishes cmd_vel and calls ~/recover: no
    sample reaches the base, the recover ends unanswered, the wheels stay at rest. What
    shows its link carried them: its ~/stop, sent after them on the same link, is
    answered (a viewer's), and an operator's cmd_vel then drives."""
    viewer = hostile == "viewer/bob"
    with secured_base(channel, creds.root, behind_router=behind_router) as rig:
        session = (member(creds.root, hostile, rig.endpoint) if viewer else
                   member(creds.root, "operator/mallory", rig.endpoint, folder=creds.removed))
        operator = member(creds.root, "operator/alice", rig.endpoint)
        try:
            if viewer:
                linked(rig, session)
            hostile_driver = Driver(session, rig.bridge.cmd_key, 0.3, bytes([0xBA]) * 16)
            for _ in range(50):
                hostile_driver()
                rig.clock.sleep(0.02)
                rig.bridge.poll()
            assert call(rig.clock, rig.bridge, session, "recover", each=hostile_driver) is None
            stop = call(rig.clock, rig.bridge, session, "stop", each=hostile_driver)
            if viewer:
                assert stop == (True, "stopped: held until recover")
            else:
                assert stop is None  # a removed member may not even stop
            assert rig.bridge.cmd_vel_count == 0 and rig.bridge.cmd_vel_parsed == 0
            assert at_rest(rig) and abs(rig.base.pose.x) < 1e-6
            assert hostile_driver.sent > 50

            linked(rig, operator)
            if viewer:  # the viewer's stop holds until recovered: the operator may
                assert call(rig.clock, rig.bridge, operator, "recover") == (True, "recovered")
            drive = Driver(operator, rig.bridge.cmd_key, 0.2, bytes([0xA1]) * 16)
            assert run_until(rig.clock, rig.bridge, lambda: rig.sim.true_twist.vx > 0.15,
                             each=drive)
        finally:
            operator.close()
            session.close()


@pytest.mark.parametrize("behind_router", [False, True], ids=["alone", "behind a router"])
def test_an_operator_drives_and_a_viewer_stops_it(channel: str, creds: Creds,
                                                  behind_router: bool) -> None:
    with secured_base(channel, creds.root, behind_router=behind_router) as rig:
        operator = member(creds.root, "operator/alice", rig.endpoint)
        viewer = member(creds.root, "viewer/bob", rig.endpoint)
        try:
            linked(rig, operator)
            drive = Driver(operator, rig.bridge.cmd_key, 0.2, bytes([0xA1]) * 16)
            assert run_until(rig.clock, rig.bridge, lambda: rig.sim.true_twist.vx > 0.15,
                             each=drive)
            stop = call(rig.clock, rig.bridge, viewer, "stop", each=drive)
            assert stop == (True, "stopped: held until recover")
            assert run_until(rig.clock, rig.bridge, lambda: at_rest(rig), each=drive)
            held_at = rig.base.pose.x
            for _ in range(50):  # the operator keeps sending: the stop holds
                drive()
                rig.clock.sleep(0.02)
                rig.bridge.poll()
            assert at_rest(rig) and abs(rig.base.pose.x - held_at) < 1e-3
            assert rig.bridge.cmd_vel_count > 0
        finally:
            viewer.close()
            operator.close()


def test_through_the_router_no_member_speaks_for_a_base(channel: str, creds: Creds) -> None:
    """Behind the router, a viewer cannot announce a node in robot1's namespace, and
    robot2's certificate can neither announce one there nor publish robot1's summary:
    an operator hears robot1's own tokens and summaries only."""
    from omnican.zenoh.bridge import SUMMARY

    with secured_base(channel, creds.root, behind_router=True) as rig:
        operator = member(creds.root, "operator/alice", rig.endpoint)
        viewer = member(creds.root, "viewer/bob", rig.endpoint)
        robot2 = member(creds.root, "base/robot2", rig.endpoint)
        tokens: list[str] = []
        summaries: list[bytes] = []
        sessions = {str(s.info.zid()) for s in (viewer, robot2)}
        try:
            watch = [operator.liveliness().declare_subscriber(
                f"{rmw.ADMIN_SPACE}/0/**", lambda s: tokens.append(str(s.key_expr)),
                history=True)]
            summary_key = rig.bridge.publishers[SUMMARY].key
            watch.append(operator.declare_subscriber(
                summary_key, lambda s: summaries.append(s.payload.to_bytes())))
            fakes = []
            for liar in (viewer, robot2):
                node = rmw.RosNode(0, str(liar.info.zid()), 0, "omnican", namespace="/robot1")
                fakes.append(liar.liveliness().declare_token(node.token()))
            fake = robot2.declare_publisher(summary_key)
            # robot2's own namespace goes through: the positive control for its link
            own = rmw.RosNode(0, str(robot2.info.zid()), 0, "omnican", namespace="/robot2")
            fakes.append(robot2.liveliness().declare_token(own.token()))

            def heard() -> bool:
                fake.put(b"FAKE")
                return own.token() in tokens and len(summaries) >= 3

            assert run_until(rig.clock, rig.bridge, heard)
            assert rig.bridge.node.token() in tokens
            assert not [t for t in tokens if t.split("/")[2] in sessions and "%robot1" in t]
            assert b"FAKE" not in summaries
            for w in watch:
                w.undeclare()
        finally:
            for s in (robot2, viewer, operator):
                s.close()


@pytest.mark.parametrize("behind_router", [False, True], ids=["alone", "behind a router"])
def test_an_imu_on_the_robot_under_the_bases_certificate_is_heard(
        channel: str, creds: Creds, behind_router: bool) -> None:
    """``[imu] source = "zenoh"`` with the fleet's certificates: an IMU driver on the robot
    publishing under the base's own certificate reaches the base's IMU inbox, linked to
    the base itself or through the router; an operator's and a viewer's Imu samples on the
    same key never do (only the base's name may publish in its namespace, and an
    operator only cmd_vel). The operator's and viewer's samples go first on their links,
    each followed by a cmd_vel or ~/stop that is heard: their links carried them."""
    from tests.zenoh.test_imu import _imu_cdr

    with secured_base(channel, creds.root, behind_router=behind_router,
                      imu_topic="imu/data") as rig:
        inbox, imu = rig.base.imu, rig.bridge.imu
        assert inbox is not None and imu is not None
        assert imu.key.startswith("0/robot1/imu/data/sensor_msgs::msg::dds_::Imu_/")
        operator = member(creds.root, "operator/alice", rig.endpoint)
        viewer = member(creds.root, "viewer/bob", rig.endpoint)
        driver = member(creds.root, "base/robot1", rig.endpoint)
        try:
            linked(rig, operator)
            for session in (operator, viewer):
                pub = session.declare_publisher(imu.key)
                # It hears of the base's subscriber (declarations reach every member):
                # its samples go out, and are refused where they come in.
                assert wait_real(lambda p=pub: p.matching_status.matching)
                for _ in range(20):
                    pub.put(_imu_cdr(0.5, time.time()))
                pub.undeclare()
            drive = Driver(operator, rig.bridge.cmd_key, 0.2, bytes([0xA1]) * 16)
            assert run_until(rig.clock, rig.bridge, lambda: rig.sim.true_twist.vx > 0.15,
                             each=drive)
            assert call(rig.clock, rig.bridge, viewer, "stop") == \
                (True, "stopped: held until recover")
            assert inbox.received == 0 and imu.received == 0

            pub = driver.declare_publisher(imu.key)
            assert wait_real(lambda: pub.matching_status.matching)
            for _ in range(20):
                pub.put(_imu_cdr(0.5, time.time()))
            assert wait_real(lambda: inbox.received == 20)
            assert imu.rejected == 0
        finally:
            for s in (driver, viewer, operator):
                s.close()


@pytest.fixture
def sdk_as(creds: Creds, monkeypatch: pytest.MonkeyPatch) -> Iterator[Callable[[str, str], Any]]:
    """zenoh-ros2-sdk's session presenting a member's certificate over TLS (its session
    config takes them through ZENOH_CONFIG_OVERRIDE), on the downloaded message
    definitions; closed after the test."""
    sdk = pytest.importorskip("zenoh_ros2_sdk", reason="zenoh-ros2-sdk is not installed "
                              "(pip install zenoh-ros2-sdk)")
    from zenoh_ros2_sdk import message_registry
    from zenoh_ros2_sdk.session import ZenohSession

    from tests.zenoh.conftest import message_dir

    where, why = message_dir()
    if where is None:
        pytest.skip(why)
    monkeypatch.setattr(message_registry, "_registry",
                        message_registry.MessageRegistry(str(where)))
    opened: list[Any] = []

    def start(who: str, endpoint: str) -> Any:
        folder = creds.root / Identity.parse(who).folder
        tls = dict(json.loads(tls_entries(str(creds.root / "ca.pem"),
                                          str(folder / "cert.pem"),
                                          str(folder / "key.pem"))[1][1]))
        monkeypatch.setenv("ZENOH_CONFIG_OVERRIDE", ";".join((
            f"connect/endpoints={json.dumps([endpoint])}",
            'listen/endpoints=["tls/127.0.0.1:0"]', "scouting/multicast/enabled=false",
            'transport/link/protocols=["tls"]',
            f"transport/link/tls={json.dumps(tls)}")))
        opened.append(ZenohSession.get_instance("127.0.0.1", 1))
        return sdk

    try:
        yield start
    finally:
        for session in opened:
            session.close()


def test_the_sdk_under_an_operators_certificate_drives_through_the_router(
        channel: str, creds: Creds, sdk_as: Callable[[str, str], Any]) -> None:
    """rmw_zenoh's format from an independent implementation, over mutual TLS: its
    Twist publisher drives the base behind the router, and its subscriber reads odom."""
    with secured_base(channel, creds.root, behind_router=True) as rig:
        sdk = sdk_as("operator/alice", rig.endpoint)
        odom: list[Any] = []
        sub = sdk.ROS2Subscriber("/robot1/odom", "nav_msgs/msg/Odometry", odom.append,
                                 router_port=1)
        pub = sdk.ROS2Publisher("/robot1/cmd_vel", TWIST, router_port=1)
        try:
            assert pub.keyexpr == rig.bridge.cmd_key
            types = pub.session_mgr.store.types
            vec = types["geometry_msgs/msg/Vector3"]
            forward = {"linear": vec(0.2, 0.0, 0.0), "angular": vec(0.0, 0.0, 0.0)}
            assert run_until(rig.clock, rig.bridge,
                             lambda: rig.sim.true_twist.vx > 0.15 and len(odom) > 2,
                             each=lambda: pub.publish(**forward))
        finally:
            pub.close()
            sub.close()


def test_the_sdk_under_a_viewers_certificate_stops_but_does_not_drive(
        channel: str, creds: Creds, sdk_as: Callable[[str, str], Any]) -> None:
    """zenoh-ros2-sdk as a viewer behind the router: its Twists never reach the base; its
    service client's ~/stop, sent after them, is answered and stops the base."""
    from tests.zenoh.test_services import TRIGGER_HASH

    with secured_base(channel, creds.root, behind_router=True) as rig:
        sdk = sdk_as("viewer/bob", rig.endpoint)
        pub = sdk.ROS2Publisher("/robot1/cmd_vel", TWIST, router_port=1)
        caller = sdk.ROS2ServiceClient(
            "/robot1/omnican/stop", "std_srvs/srv/Trigger",
            request_definition="uint8 structure_needs_at_least_one_member",
            response_definition="bool success\nstring message", type_hash=TRIGGER_HASH,
            router_port=1)
        try:
            assert wait_real(lambda: caller.querier.matching_status.matching)
            types = pub.session_mgr.store.types
            vec = types["geometry_msgs/msg/Vector3"]
            forward = {"linear": vec(0.2, 0.0, 0.0), "angular": vec(0.0, 0.0, 0.0)}
            for _ in range(50):
                pub.publish(**forward)
                rig.clock.sleep(0.02)
                rig.bridge.poll()
            got: list[Any] = []
            done = threading.Event()
            caller.call_async(lambda response: (got.append(response), done.set()))
            assert run_until(rig.clock, rig.bridge, done.is_set)
            assert got[0] is not None and got[0].success, got
            assert got[0].message == "stopped: held until recover"
            assert rig.bridge.cmd_vel_count == 0 and at_rest(rig)
        finally:
            caller.close()
            pub.close()
