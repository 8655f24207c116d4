"""A real ROS 2 IMU (rclpy on Fast DDS, ROS 2 Jazzy's PyPI wheels) publishing
sensor_msgs/Imu at 100 Hz reaches ``omnican ros2 --sim``'s IMU inbox, mounted as its
``[imu]`` table says, and goes silent when it stops; and it drives the fused heading:
driving straight while the gyro reads a turn, /odom turns and /odom/wheels does not.
Loopback only: both processes run in a private network namespace with nothing but
loopback (as tests/interop/test_ros2_interop.py; skipped where none can be made)."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.interop.ros2_interop.harness import (
    FASTDDS_PROFILE,
    HERE,
    NetNs,
    Proc,
    clean_env,
    netns_unavailable,
    ros_venv,
)

pytest.importorskip("cyclonedds", reason="needs the ros2 extra: pip install '.[ros2]'")

pytestmark = pytest.mark.timeout(900)  # the first run installs the ROS 2 wheels

IMU_TABLE = """
[imu]
source = "ros2"
topic = "/imu/data"
upside_down = true
"""


@pytest.fixture
def netns() -> Iterator[NetNs]:
    why = netns_unavailable()
    if why:
        pytest.skip(why)
    with NetNs() as ns:
        yield ns


def run_peer(netns: NetNs, tmp_path: Path, script: str, *args: str) -> dict[str, Any]:
    """``omnican ros2 --sim`` with :data:`IMU_TABLE` and the rclpy ``script`` beside it in
    the namespace; the script's results (after omnican stopped cleanly on Ctrl-C)."""
    python, note = ros_venv("jazzy")
    if python is None:
        pytest.skip(note)
    domain = 47
    config = tmp_path / "robot.toml"
    config.write_text((HERE / "robot.toml").read_text() + IMU_TABLE)
    env = clean_env(ROS_DOMAIN_ID=str(domain), RMW_IMPLEMENTATION="rmw_fastrtps_cpp",
                    FASTRTPS_DEFAULT_PROFILES_FILE=str(FASTDDS_PROFILE),
                    ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
                    ROS_LOG_DIR=str(tmp_path / "ros-log"))
    omnican = Proc(netns.wrap([sys.executable, "-m", "omnican", "ros2", "--sim", "--config",
                               str(config), "--domain-id", str(domain)]),
                   env=clean_env(PYTHONUNBUFFERED="1"))
    peer = None
    try:
        assert omnican.read_until(lambda ln: ln.startswith("Ctrl-C to stop"), 60), \
            "omnican ros2 did not start:\n" + "\n".join(omnican.lines)
        with (tmp_path / "rclpy.stderr").open("w") as err:
            peer = Proc(netns.wrap([str(python), str(HERE / script), *args]), env=env,
                        stderr=err)
            ready = peer.read_json("ready", 90)
            assert ready and ready["ok"], "peer did not start:\n" + "\n".join(peer.lines)
            done = peer.read_json("done", 300)
            assert done is not None, "\n".join(peer.lines)
        omnican.interrupt()
        code, out = omnican.finish()
        assert code == 0 and "Traceback" not in out, out
    finally:
        if peer is not None:
            peer.kill()
        omnican.kill()
    return dict(done["results"])


@pytest.mark.ros2_interop
def test_an_rclpy_imu_at_100hz_reaches_the_inbox(netns: NetNs, tmp_path: Path) -> None:
    r = run_peer(netns, tmp_path, "imu_check.py", "3", "100", "0.3")
    print({k: r.get(k) for k in ("sent", "rate_hz")}, r.get("after"), r.get("silent"))
    assert r["sent"] >= 250  # 100 Hz for 3 s
    after, silent = r["after"], r["silent"]
    # Every sample over loopback, none refused, the yaw rate turned over (upside down).
    assert int(after["imu_received"]) == r["sent"]
    assert after["imu_rejected"] == "0"
    assert float(after["imu_yaw_rate"]) == pytest.approx(-0.3)
    # It stopped: the base's IMU has been silent for a while since, and says so.
    assert int(silent["imu_received"]) == r["sent"]
    assert float(silent["imu_silent_s"]) > 0.5


@pytest.mark.ros2_interop
def test_an_rclpy_imu_turns_the_fused_heading_the_wheels_do_not(netns: NetNs,
                                                                tmp_path: Path) -> None:
    """The base drives straight ahead while the rclpy IMU (100 Hz) reads a turn the wheels
    do not see: /odom, the fused odometry, turns as the gyro says (mounted upside down:
    the other way), /odom/wheels does not. With the IMU ignored /odom is the wheels'."""
    yaw_rate = 0.5  # rad/s in the IMU's frame: -0.5 on the base (upside down)
    r = run_peer(netns, tmp_path, "imu_fusion_check.py", "2", str(yaw_rate))
    print({k: r.get(k) for k in ("fused_turn", "wheels_turn", "gyro_turn_sent", "imu_sent",
                                 "cmd_sent", "distance_x")})
    print("while driving, /odom yaw rate", r.get("odom_yaw_rate_driving"),
          "/odom/wheels", r.get("wheels_yaw_rate_driving"))
    assert r["rest_before"] and r["moving"] and r["rest_after"], r
    assert r["distance_x"] > 0.2  # it drove (0.2 m/s for 2 s at least)
    # The wheels saw no turn: their heading and yaw rate stayed at zero.
    assert abs(r["wheels_turn"]) < 0.02
    assert all(abs(w) < 0.02 for w in r["wheels_yaw_rate_driving"])
    # The fused yaw rate while driving is the gyro's, mounted (bias learnt at rest: ~0) ...
    assert all(w == pytest.approx(-yaw_rate, abs=0.05) for w in r["odom_yaw_rate_driving"])
    # ... and the fused heading turned by what the gyro measured, the other way round:
    # the gyro's turn as sent (none of it lost to a stale IMU, up to half under load).
    sent = r["gyro_turn_sent"]
    assert sent > 0.9  # 0.5 rad/s for 2 s at least
    assert -1.2 * sent < r["fused_turn"] < -0.5 * sent
