"""``[imu] source = "ros2"``: the bridge reads a sensor_msgs/Imu topic into the base's IMU
inbox (its mounting applied, its header stamp on the host's clock where believable);
without that table it subscribes to nothing."""

from __future__ import annotations

import math
import time
from dataclasses import replace

import pytest

from omnican import Chassis
from omnican.config import ImuSettings
from omnican.sim import SimulatedBase
from tests.ros2.test_bridge import MemoryTransport
from tests.support.helpers import sim_config

pytest.importorskip("cyclonedds")

from omnican.ros2 import msgs
from omnican.ros2.bridge import Bridge
from omnican.ros2.settings import Ros2Settings


def _imu(wz: float, stamp: float = 0.0, ax: float = 0.0, ay: float = 0.0,
         rate_cov0: float = 0.0) -> msgs.Imu:
    sec = int(stamp)
    return msgs.Imu(
        header=msgs.Header(stamp=msgs.Time(sec, round((stamp - sec) * 1e9))),
        angular_velocity=msgs.Vector3(0.0, 0.0, wz),
        angular_velocity_covariance=[rate_cov0] + [0.0] * 8,
        linear_acceleration=msgs.Vector3(ax, ay, 9.81))


def test_a_ros2_imu_reaches_the_inbox_mounted(channel: str) -> None:
    imu = ImuSettings("ros2", topic="/base/imu", upside_down=True, mount_yaw_deg=90.0)
    cfg = replace(sim_config(channel), imu=imu)
    t = MemoryTransport()
    with SimulatedBase.from_config(cfg), Chassis.open(cfg) as base, \
            Bridge(base, Ros2Settings(), t, poll_thread=False) as bridge:
        inbox = base.imu
        assert inbox is not None and bridge.imu is not None
        assert t.qos["/base/imu"].reliable is False  # a sensor-data publisher matches too
        before = time.monotonic()
        stamped = time.time() - 0.05  # measured 50 ms ago on this host's clock
        t.deliver("/base/imu", _imu(0.25, stamped, ax=1.0, ay=0.5))
        t.deliver("/base/imu", _imu(0.5))  # no stamp: its arrival
        t.deliver("/base/imu", _imu(9.0, rate_cov0=-1.0))  # "no angular velocity"
        t.deliver("/base/imu", _imu(math.nan))
        bridge.poll()
        after = time.monotonic()
        got = inbox.drain()
        assert [s.yaw_rate for s in got] == [-0.25, -0.5]  # upside down
        assert got[0].accel_x == pytest.approx(0.5) and got[0].accel_y == pytest.approx(1.0)
        assert before - 0.05 - 0.01 <= got[0].t <= after - 0.05 + 0.01
        assert before <= got[1].t <= after
        assert (bridge.imu.received, bridge.imu.rejected) == (4, 2)
        values = {v["key"]: v["value"] for v in bridge.bridge_status()["values"]}
        assert values["imu_received"] == "4" and values["imu_yaw_rate"] == "-0.500000"
        t.deliver_raw("/base/imu", b"\x00\x01\x00\x00garbage")
        bridge.poll()
        assert bridge.imu.rejected == 3 and inbox.received == 2


def test_no_imu_table_no_imu_topic(channel: str) -> None:
    cfg = sim_config(channel)
    t = MemoryTransport()
    with SimulatedBase.from_config(cfg), Chassis.open(cfg) as base, \
            Bridge(base, Ros2Settings(), t, poll_thread=False) as bridge:
        assert bridge.imu is None and base.imu is None
        assert "/imu/data" not in t.readers
        keys = {v["key"] for v in bridge.bridge_status()["values"]}
        assert not any(k.startswith("imu_") for k in keys)
