"""``omnican ros2 --sim`` against real ROS 2 (Jazzy and Kilted: rclpy on Fast DDS, from PyPI
wheels, installed once into cached venvs) and against omnican's own Cyclone DDS peer.

The peer publishes cmd_vel at 20 Hz, checks odom against the simulator's ground truth,
joint_states and diagnostics, sees an injected drive fault there and clears it over ROS
(tests/interop/ros2_interop/scenario.py). PyPI has no tf2_msgs wheel: tf is read by a Cyclone
reader of our own beside the rclpy node.

Hostile and buggy publishers (tests/interop/ros2_interop/abuse_check.py, rclpy on Jazzy): a
10 kHz cmd_vel flood, a TwistStamped on a Twist cmd_vel, 16 MB samples, two publishers.

Loopback only: every DDS process runs in a private network namespace that has nothing
but loopback, with loopback-only DDS configurations on top; without such a namespace
the tests are skipped.
"""

from __future__ import annotations

import math
import re
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.interop.ros2_interop.harness import (
    FASTDDS_PROFILE,
    HERE,
    ROS_PACKAGES,
    NetNs,
    Proc,
    clean_env,
    netns_unavailable,
    ros_venv,
)
from tests.interop.ros2_interop.judge import judge, run_scenario

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


# ------------------------------------------------------------ hostile and buggy publishers


def _abuse(netns: NetNs, tmp_path: Path, domain: int, peer_args: list[str],
           omnican_args: tuple[str, ...] = ()) -> tuple[dict[str, Any], str]:
    """``omnican ros2 --sim`` and one abuse_check.py peer (rclpy, Jazzy) in the namespace:
    what the peer saw, and all omnican said (stdout and its log)."""
    python, note = ros_venv("jazzy")
    if python is None:
        pytest.skip(note)
    env = clean_env(ROS_DOMAIN_ID=str(domain), RMW_IMPLEMENTATION="rmw_fastrtps_cpp",
                    FASTRTPS_DEFAULT_PROFILES_FILE=str(FASTDDS_PROFILE),
                    ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
                    ROS_LOG_DIR=str(tmp_path / "ros-log"))
    omnican = Proc(netns.wrap([sys.executable, "-m", "omnican", "ros2", "--sim",
                               "--config", str(HERE / "robot.toml"), "--domain-id",
                               str(domain), *omnican_args]),
                   env=clean_env(PYTHONUNBUFFERED="1"))
    peer = None
    try:
        assert omnican.read_until(lambda ln: ln.startswith("Ctrl-C to stop"), 60), \
            "omnican ros2 did not start:\n" + "\n".join(omnican.lines)
        with (tmp_path / "rclpy.stderr").open("w") as err:
            peer = Proc(netns.wrap([str(python), str(HERE / "abuse_check.py"), *peer_args]),
                        env=env, stderr=err)
            ready = peer.read_json("ready", 60)
            assert ready and ready["ok"], "peer did not start:\n" + "\n".join(peer.lines)
            done = peer.read_json("done", 120)
            assert done is not None, "\n".join(peer.lines)
        omnican.interrupt()
        code, out = omnican.finish()
        assert code == 0 and "drives disabled" in out and "Traceback" not in out, out
        return dict(done["results"]), out
    finally:
        if peer is not None:
            peer.kill()
        omnican.kill()


@pytest.mark.ros2_interop
def test_a_10khz_cmd_vel_flood_is_taken_newest_first(netns: NetNs, tmp_path: Path) -> None:
    """A node floods cmd_vel as fast as it can (up to 10 kHz): the bridge parses at most
    one sample of it per poll, drops the rest unparsed, and drives with the newest."""
    r, out = _abuse(netns, tmp_path, 43, ["flood", "4", "10000"])
    print({k: r[k] for k in ("sent", "rate_hz", "worst_chassis_level")}, r["after"])
    before, after = r["before"], r["after"]
    received = int(after["cmd_vel_received"]) - int(before["cmd_vel_received"])
    handled = int(after["cmd_vel_parsed"]) - int(before["cmd_vel_parsed"])
    polls = int(after["cmd_vel_polls"]) - int(before["cmd_vel_polls"])
    assert received > 0 and handled > 0
    assert handled <= polls  # one publisher: at most one parsed sample per poll
    assert received > 2 * handled, (received, handled)  # the rest dropped unparsed
    assert r["moving_twist"] == pytest.approx([0.3, 0.0, 0.0], abs=0.05), out
    assert r["after_flood_twist"] == pytest.approx([0.3, 0.0, 0.0], abs=0.05), out


@pytest.mark.ros2_interop
def test_a_twist_stamped_publisher_on_a_twist_cmd_vel_is_named(netns: NetNs,
                                                                tmp_path: Path) -> None:
    r, out = _abuse(netns, tmp_path, 44, ["stamped"])
    assert r["matched"] == 0  # DDS does not connect different types
    assert r["twist"] == pytest.approx([0.0, 0.0, 0.0], abs=1e-3)
    said = [ln for ln in out.splitlines() if "geometry_msgs/msg/TwistStamped" in ln
            and "WARNING" in ln]
    assert len(said) == 1, out  # once, not per sample or per discovery
    assert "/cmd_vel: publisher" in said[0] and "--cmd-vel-stamped" in said[0], said
    assert "reads geometry_msgs/msg/Twist" in said[0]


@pytest.mark.ros2_interop
def test_a_16mb_cmd_vel_is_dropped_before_python_sees_it(netns: NetNs, tmp_path: Path) -> None:
    """16 MB TwistStamped samples (a Twist is under 1 KB): Cyclone drops them as they
    arrive (omnican's MaxSampleSize), nothing moves, and sane samples drive after."""
    r, out = _abuse(netns, tmp_path, 46, ["oversized"], ("--cmd-vel-stamped",))
    assert r["huge_acked"] == [True, True, True], out  # they reached omnican
    assert r["after_huge_twist"] == pytest.approx([0.0, 0.0, 0.0], abs=1e-3), out
    assert r["sane_twist"] == pytest.approx([0.2, 0.0, 0.0], abs=0.05), out
    assert "dropping oversize" in out and "> 65536" in out, out


@pytest.mark.ros2_interop
def test_two_cmd_vel_publishers_one_drives(netns: NetNs, tmp_path: Path) -> None:
    """Two publishers on cmd_vel: the first drives; the second is ignored until the first
    has been silent for the command timeout, and the log names who drives."""
    r, out = _abuse(netns, tmp_path, 45, ["two"])
    assert r["both_twist"] == pytest.approx([0.2, 0.0, 0.0], abs=0.05), out
    assert r["second_twist"] == pytest.approx([0.0, 0.2, 0.0], abs=0.05), out
    ignored = [ln for ln in out.splitlines() if "ignored:" in ln and "is driving" in ln]
    assert ignored, out
    assert re.search(r"cmd_vel from ROS 2 cmd_vel publisher [0-9a-f]{32} ignored: ROS 2 "
                     r"cmd_vel publisher [0-9a-f]{32} is driving the base", ignored[0]), ignored
    assert int(r["bridge"]["cmd_vel_ignored"]) > 0
