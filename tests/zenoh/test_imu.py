"""``[imu] source = "zenoh"``: a sensor_msgs/Imu published by a raw eclipse-zenoh session in
rmw_zenoh's format (its data key, CDR) reaches the base's IMU inbox, mounted, stamped on
the host's clock; what is not an Imu is counted, never put. On a loopback router."""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Iterator
from dataclasses import replace
from typing import Any

import pytest

from omnican import Chassis
from omnican.clock import SimClock
from omnican.config import ImuSettings
from omnican.sim import SimulatedBase
from omnican.zenoh import rmw
from tests.support.helpers import sim_config
from tests.zenoh.conftest import client, wait_real

pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed "
                    "(pip install 'omnican[zenoh]')")


def _imu_cdr(wz: float, stamp: float = 0.0, ax: float = 0.0, ay: float = 0.0,
             rate_cov0: float = 0.0) -> bytes:
    from omnican.telemetry import cdr

    sec = int(stamp)
    vec = lambda x, y, z: {"x": x, "y": y, "z": z}  # noqa: E731
    return cdr.encode("sensor_msgs/msg/Imu", {
        "header": {"stamp": {"sec": sec, "nanosec": round((stamp - sec) * 1e9)},
                   "frame_id": "imu_link"},
        "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
        "orientation_covariance": [-1.0] + [0.0] * 8,
        "angular_velocity": vec(0.0, 0.0, wz),
        "angular_velocity_covariance": [rate_cov0] + [0.0] * 8,
        "linear_acceleration": vec(ax, ay, 9.81),
        "linear_acceleration_covariance": [0.0] * 9})


@pytest.fixture
def imu_bridge(channel: str, router: str) -> Iterator[tuple[Chassis, Any]]:
    from omnican.zenoh.bridge import ZenohBridge, open_session
    from omnican.zenoh.settings import ZenohSettings

    cfg = replace(sim_config(channel), imu=ImuSettings("zenoh", topic="/imu/data",
                                                       mount_yaw_deg=180.0))
    clock = SimClock()
    settings = ZenohSettings(mode="client", connect=(router,))
    with SimulatedBase.from_config(cfg, clock=clock), Chassis.open(cfg, clock=clock) as base:
        session = open_session(settings)
        try:
            with ZenohBridge(base, settings, session, poll_thread=False) as bridge:
                yield base, bridge
        finally:
            session.close()


def test_a_zenoh_imu_at_100hz_reaches_the_inbox(imu_bridge: tuple[Chassis, Any],
                                                router: str) -> None:
    base, bridge = imu_bridge
    inbox = base.imu
    assert inbox is not None and bridge.imu is not None
    assert bridge.imu.key == rmw.data_key(0, "/imu/data", "sensor_msgs/msg/Imu",
                                          rmw.type_hash("sensor_msgs/msg/Imu"))
    assert bridge.imu.key.startswith("0/imu/data/sensor_msgs::msg::dds_::Imu_/RIHS01_")
    session = client(router)
    try:
        pub = session.declare_publisher(bridge.imu.key)
        assert wait_real(lambda: pub.matching_status.matching)
        before = time.monotonic()
        for i in range(100):  # a second of a 100 Hz IMU, stamped as it measured
            pub.put(_imu_cdr(0.01 * i, time.time(), ax=1.0, ay=-0.5))
            time.sleep(0.01)
        assert wait_real(lambda: inbox.received == 100)
        after = time.monotonic()
        got = inbox.drain()
        assert [s.yaw_rate for s in got] == pytest.approx([0.01 * i for i in range(100)])
        # turned half round about z: its x points back, its y right
        assert got[0].accel_x == pytest.approx(-1.0) and got[0].accel_y == pytest.approx(0.5)
        assert all(before - 0.01 <= s.t <= after for s in got)
        assert all(a.t <= b.t for a, b in itertools.pairwise(got))
        # not an Imu, no angular velocity, not finite: counted, never put
        pub.put(b"\x00\x01\x00\x00\xff\xff")
        pub.put(_imu_cdr(1.0, rate_cov0=-1.0))
        pub.put(_imu_cdr(math.inf))
        pub.put(_imu_cdr(0.7))  # no stamp: its arrival time
        assert wait_real(lambda: bridge.imu.received == 104)
        assert bridge.imu.rejected == 3
        (last,) = inbox.drain()
        assert last.yaw_rate == pytest.approx(0.7) and last.t >= after
        pub.undeclare()
    finally:
        session.close()


def test_no_imu_table_no_imu_subscriber(channel: str, router: str) -> None:
    from omnican.zenoh.bridge import ZenohBridge, open_session
    from omnican.zenoh.settings import ZenohSettings

    cfg = sim_config(channel)
    clock = SimClock()
    settings = ZenohSettings(mode="client", connect=(router,))
    with SimulatedBase.from_config(cfg, clock=clock), Chassis.open(cfg, clock=clock) as base:
        session = open_session(settings)
        try:
            with ZenohBridge(base, settings, session, poll_thread=False) as bridge:
                assert bridge.imu is None and base.imu is None
        finally:
            session.close()
