"""``omnican ros2 --sim`` against real ROS 2 (Jazzy and Kilted: rclpy on Fast DDS, from PyPI
wheels, installed once into cached venvs) and against omnican's own Cyclone DDS peer.

The peer publishes cmd_vel at 20 Hz, checks odom against the simulator's ground truth,
joint_states and diagnostics, sees an injected drive fault there and clears it over ROS
(tests/ros2_interop/scenario.py). PyPI has no tf2_msgs wheel: tf is read by a Cyclone
reader of our own beside the rclpy node.

Loopback only: every DDS process runs in a private network namespace that has nothing
but loopback, with loopback-only DDS configurations on top; without such a namespace
the tests are skipped.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from .ros2_interop.harness import (
    FASTDDS_PROFILE,
    HERE,
    ROS_PACKAGES,
    NetNs,
    clean_env,
    netns_unavailable,
    ros_venv,
)
from .ros2_interop.judge import judge, run_scenario

pytest.importorskip("cyclonedds", reason="needs the ros2 extra: pip install '.[ros2]'")

pytestmark = pytest.mark.timeout(900)  # the first run installs the ROS 2 wheels


@pytest.fixture
def netns() -> Iterator[NetNs]:
    why = netns_unavailable()
    if why:
        pytest.skip(why)
    with NetNs() as ns:
        yield ns


def test_omnican_peer_over_cyclone_loopback(netns: NetNs) -> None:
    run = run_scenario(netns, 7, [sys.executable, str(HERE / "cyclone_check.py"), "scenario",
                                  "7"], clean_env())
    judge(run)


@pytest.mark.ros2_interop
@pytest.mark.parametrize("distro", sorted(ROS_PACKAGES))
def test_rclpy_over_fast_dds(distro: str, netns: NetNs, tmp_path: Path) -> None:
    python, note = ros_venv(distro)
    if python is None:
        pytest.skip(note)
    print(f"ROS 2 {distro}: {note}")
    # The profile's variable is FASTRTPS_... for Fast DDS 2 (Jazzy), FASTDDS_... for Fast
    # DDS 3 (Kilted). LOCALHOST also stops rmw_fastrtps from adding a multicast
    # announcement to the profile's unicast initial peer.
    env = clean_env(ROS_DOMAIN_ID="42", RMW_IMPLEMENTATION="rmw_fastrtps_cpp",
                    FASTRTPS_DEFAULT_PROFILES_FILE=str(FASTDDS_PROFILE),
                    FASTDDS_DEFAULT_PROFILES_FILE=str(FASTDDS_PROFILE),
                    ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
                    ROS_LOG_DIR=str(tmp_path / "ros-log"))
    with (tmp_path / "rclpy.stderr").open("w") as err:
        run = run_scenario(netns, 42, [str(python), str(HERE / "rclpy_check.py")], env,
                           tf_reader=True, stderr=err)
    r = run.results
    print({k: round(r[k], 1) for k in ("odom_rate_hz", "joint_states_rate_hz",
                                       "diagnostics_rate_hz")})
    # The ROS graph sees omnican's topics under ROS 2 type names.
    graph = r["graph"]
    assert graph["/odom"] == ["nav_msgs/msg/Odometry"]
    assert graph["/cmd_vel"] == ["geometry_msgs/msg/Twist"]
    assert graph["/joint_states"] == ["sensor_msgs/msg/JointState"]
    assert graph["/diagnostics"] == ["diagnostic_msgs/msg/DiagnosticArray"]
    assert graph["/tf"] == ["tf2_msgs/msg/TFMessage"]
    assert graph["/omnican/recover"] == ["std_msgs/msg/Empty"]
    assert graph["/battery_state"] == ["sensor_msgs/msg/BatteryState"]
    # The DC link voltage the simulated drives report, as rclpy decodes the message.
    battery = r["battery"]
    assert battery["count"] >= 1 and battery["present"] is True
    assert battery["voltage"] == pytest.approx(24.0, abs=1.0)
    assert math.isnan(battery["current"]) and battery["location"].startswith("DC link")
    assert battery["frame_id"] == "base_link"
    judge(run)
