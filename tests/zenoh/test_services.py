"""The base's services in rmw_zenoh's request/reply form: stop, recover, reset odometry."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from omnican.chassis import Chassis
from omnican.clock import SimClock
from omnican.sim import SimulatedBase
from omnican.zenoh import rmw
from omnican.zenoh.services import trigger_response
from tests.support.helpers import lockstep_rig
from tests.zenoh.conftest import client

TRIGGER_HASH = "RIHS01_eeff2cd6fa5ad9d27cdf4dec64818317839b62f212a91e6b5304b634b2062c5f"


def _zenoh() -> Any:
    return pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed "
                               "(pip install 'omnican[zenoh]')")


def _rosbags_trigger() -> Any:
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(get_types_from_msg("bool success\nstring message",
                                      "std_srvs/msg/Trigger_Response"))
    return store


@given(st.booleans(), st.text(max_size=40))
def test_trigger_responses_read_back_with_rosbags(success: bool, message: str) -> None:
    store = _rosbags_trigger()
    got = store.deserialize_cdr(trigger_response(success, message),
                                "std_srvs/msg/Trigger_Response")
    assert got.success is success
    assert got.message == message.encode("utf-8", "replace").decode()


@pytest.fixture
def stepped(channel: str) -> Iterator[tuple[SimClock, SimulatedBase, Chassis]]:
    with lockstep_rig(channel) as r:
        yield r


def test_stop_recover_and_reset_odometry_as_services(
        stepped: tuple[SimClock, SimulatedBase, Chassis], router: str) -> None:
    from omnican.zenoh.bridge import ZenohBridge, open_session
    from omnican.zenoh.services import service_key
    from omnican.zenoh.settings import ZenohSettings
    from tests.zenoh.test_bridge import run_until

    clock, sim, base = stepped
    settings = ZenohSettings(mode="client", connect=(router,), namespace="/robot1")
    ours = open_session(settings)
    session = client(router)
    store = _rosbags_trigger()
    gid = bytes(range(100, 116))
    try:
        with ZenohBridge(base, settings, ours, poll_thread=False) as bridge:
            replies: list[Any] = []

            def call(name: str, seq: int) -> Any:
                replies.clear()
                key = service_key(bridge.node, name)
                assert key.startswith("0/robot1/omnican/" + name + "/std_srvs::srv::dds_::")
                handler = session.get(key, payload=b"\x00\x01\x00\x00\x00",
                                      attachment=rmw.Attachment(seq, 0, gid).encode(),
                                      handler=_zenoh().handlers.FifoChannel(4))

                def answered() -> bool:
                    got = handler.try_recv()
                    if got is not None:
                        replies.append(got)
                    return bool(replies)

                assert run_until(clock, bridge, answered)
                reply = replies[0]
                assert reply.ok is not None, reply
                att = rmw.Attachment.decode(reply.ok.attachment.to_bytes())
                assert (att.sequence, att.gid) == (seq, gid)  # how a client matches it
                return store.deserialize_cdr(reply.ok.payload.to_bytes(),
                                             "std_srvs/msg/Trigger_Response")

            base.set_velocity(0.2, 0.0, 0.0)
            clock.sleep(0.3)
            assert call("stop", 1).success
            assert run_until(clock, bridge, lambda: abs(sim.true_twist.vx) < 1e-3)
            assert base.pose.x > 0.03
            got = call("reset_odometry", 2)
            assert got.success and abs(base.pose.x) < 1e-3  # it was ~0.05 m
            sim.drives[1].inject_fault(0x2310)
            assert run_until(clock, bridge, lambda: not base.status.enabled)
            got = call("recover", 3)
            assert got.success, got.message
            assert base.status.enabled
            tokens = {str(r.ok.key_expr) for r in
                      session.liveliness().get("@ros2_lv/**", timeout=10.0) if r.ok}
            assert sum("/SS/%/%robot1/omnican/%robot1%omnican%" in t for t in tokens) == 3
    finally:
        session.close()
        ours.close()


def test_the_sdks_service_client_stops_the_base(
        stepped: tuple[SimClock, SimulatedBase, Chassis], router: str, sdk: Any) -> None:
    """zenoh-ros2-sdk's client (its own request, query and attachment) calls ~/stop and
    reads the reply."""
    import threading

    from omnican.zenoh.bridge import ZenohBridge, open_session
    from omnican.zenoh.services import service_key
    from omnican.zenoh.settings import ZenohSettings
    from tests.zenoh.conftest import wait_real
    from tests.zenoh.test_bridge import run_until

    clock, sim, base = stepped
    settings = ZenohSettings(mode="client", connect=(router,))
    ours = open_session(settings)
    try:
        with ZenohBridge(base, settings, ours, poll_thread=False) as bridge:
            # The SDK refuses a service with an empty request (Trigger's): its request
            # is given as the one byte CDR carries for an empty struct, and its hash as
            # ROS 2 Jazzy publishes it.
            caller = sdk.ROS2ServiceClient(
                "/omnican/stop", "std_srvs/srv/Trigger",
                request_definition="uint8 structure_needs_at_least_one_member",
                response_definition="bool success\nstring message", type_hash=TRIGGER_HASH,
                router_port=int(router.rsplit(":", 1)[1]))
            try:
                assert caller.keyexpr == service_key(bridge.node, "stop")
                # A query before this session heard of the queryable goes nowhere.
                assert wait_real(lambda: caller.querier.matching_status.matching)
                base.set_velocity(0.2, 0.0, 0.0)
                clock.sleep(0.3)
                got: list[Any] = []
                done = threading.Event()
                caller.call_async(lambda response: (got.append(response), done.set()))
                assert run_until(clock, bridge, done.is_set)
                assert got[0] is not None and got[0].success and got[0].message == "stopped: held until recover"
                assert run_until(clock, bridge, lambda: abs(sim.true_twist.vx) < 1e-3)
            finally:
                caller.close()
    finally:
        ours.close()


def test_recover_waits_for_the_driver_and_a_stop_takes_control(
        stepped: tuple[SimClock, SimulatedBase, Chassis], router: str) -> None:
    from omnican.telemetry import cdr
    from omnican.zenoh.bridge import ZenohBridge, open_session
    from omnican.zenoh.services import service_key
    from omnican.zenoh.settings import ZenohSettings
    from tests.zenoh.conftest import wait_real
    from tests.zenoh.test_bridge import run_until

    clock, sim, base = stepped
    settings = ZenohSettings(mode="client", connect=(router,))
    ours = open_session(settings)
    session = client(router)
    store = _rosbags_trigger()
    twist = cdr.encode("geometry_msgs/msg/Twist", {"linear": {"x": 0.2, "y": 0.0, "z": 0.0},
                                                   "angular": {"x": 0.0, "y": 0.0, "z": 0.0}})
    driver = bytes([0xD1]) * 16
    try:
        with ZenohBridge(base, settings, ours, poll_thread=False) as bridge:
            pub = session.declare_publisher(bridge.cmd_key)
            assert wait_real(lambda: pub.matching_status.matching)

            def drive() -> None:
                pub.put(twist, attachment=rmw.Attachment(1, 0, driver).encode())

            def call(name: str) -> Any:
                got: list[Any] = []
                handler = session.get(service_key(bridge.node, name), payload=b"\x00\x01\x00\x00\x00",
                                      attachment=rmw.Attachment(7, 0, bytes(16)).encode(),
                                      handler=_zenoh().handlers.FifoChannel(4))

                def answered() -> bool:
                    reply = handler.try_recv()
                    if reply is not None:
                        got.append(reply)
                    return bool(got)

                assert run_until(clock, bridge, answered, each=drive)
                return store.deserialize_cdr(got[0].ok.payload.to_bytes(),
                                             "std_srvs/msg/Trigger_Response")

            assert run_until(clock, bridge, lambda: sim.true_twist.vx > 0.15, each=drive)
            refused = call("recover")
            assert not refused.success and driver.hex() in refused.message
            assert call("stop").success
            # The driver keeps sending: ignored until it lets go; the base stays stopped.
            assert run_until(clock, bridge, lambda: abs(sim.true_twist.vx) < 1e-3, each=drive)
            before = bridge.cmd_vel_refused
            assert run_until(clock, bridge, lambda: bridge.cmd_vel_refused > before + 10,
                             each=drive)
            assert abs(sim.true_twist.vx) < 1e-3
            pub.undeclare()
    finally:
        session.close()
        ours.close()
