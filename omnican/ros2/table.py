"""The ``[ros2]`` table of a config: its keys (their types, defaults, ranges and meaning:
README's reference) and the frozen :class:`Ros2Table` it becomes
(:func:`omnican.ros2.settings.from_table` checks the values). Its frames, joint names,
wheel radius, slip and rates are what every front end's telemetry says too
(:data:`TELEMETRY_KEYS`), so a recording names its joints as the robot published them.

Pure: no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from omnican.config.front_ends import FrontEndTable, TableSpec
from omnican.config.reader import Reader
from omnican.config.schema import NUMBER, TOPIC_RATE_HZ, WAIT_S, Key, defaults_of

#: Read by `omnican ros2` (omnican/ros2/settings.py checks the values).
KEYS: dict[str, Key] = {
    "namespace": Key((str,), "", "ROS 2 namespace of the node and its relative topics"),
    "node_name": Key((str,), "omnican", "ROS 2 node name (~/ topics live under it)"),
    "domain_id": Key((int,), None, "DDS domain 0-232; default: ROS_DOMAIN_ID, else 0",
                     range=(0, 232)),
    "cmd_vel_topic": Key((str,), "cmd_vel", "velocity commands in (Twist)"),
    "cmd_vel_stamped": Key((bool,), False, "cmd_vel carries TwistStamped instead of Twist"),
    "cmd_vel_timeout_s": Key(NUMBER, None, "no cmd_vel for this long -> stop; default "
                             "[chassis] cmd_timeout_s", range=WAIT_S),
    "odom_topic": Key((str,), "odom", "nav_msgs/Odometry out"),
    "odom_frame": Key((str,), "odom", "frame of the odometry pose"),
    "base_frame": Key((str,), "base_link", "frame of the base (odometry child frame)"),
    "odom_rate_hz": Key(NUMBER, 50.0, "odom and tf publish rate", range=TOPIC_RATE_HZ),
    "publish_tf": Key((bool,), True, "publish the odom -> base_link transform"),
    "tf_topic": Key((str,), "/tf", "tf2_msgs/TFMessage out"),
    "joint_states_topic": Key((str,), "joint_states", "sensor_msgs/JointState out"),
    "joint_states_rate_hz": Key(NUMBER, 50.0, "joint_states publish rate",
                                range=TOPIC_RATE_HZ),
    "joint_names": Key((list,), None, "one joint name per wheel; default wheel_0_joint, "
                       "wheel_1_joint, ..."),
    "wheel_radius": Key(NUMBER, None, "m, for joint angles; default the wheels' "
                        "wheel_radius (no joint_states without one)", range=(0.001, 10.0)),
    "diagnostics_topic": Key((str,), "/diagnostics", "diagnostic_msgs/DiagnosticArray out"),
    "diagnostics_rate_hz": Key(NUMBER, 1.0, "diagnostics rate (and at once on a change)",
                               range=TOPIC_RATE_HZ),
    "battery_state_topic": Key((str,), "battery_state", "sensor_msgs/BatteryState out: the "
                               "drives' DC link (when they report one)"),
    "battery_state_rate_hz": Key(NUMBER, 1.0, "battery_state publish rate",
                                 range=TOPIC_RATE_HZ),
    "recover_topic": Key((str,), "~/recover", "std_msgs/Empty in: clear a latched stop"),
    "odom_slip": Key(NUMBER, 0.02, "1-sigma wheel slip per metre rolled, a fraction "
                     "(covariances)", range=(0.0, 0.99)),
    "interface": Key((str,), None, "DDS network interface name or address; default all"),
    "peers": Key((list,), None, "unicast discovery peers (addresses or host names)"),
    "multicast": Key((bool,), True, "DDS multicast discovery"),
}

#: The keys every front end's telemetry reads (omnican.telemetry.settings): the frames,
#: the joints, the slip, the diagnostics' name and the rates the base is sampled at.
TELEMETRY_KEYS = ("odom_frame", "base_frame", "joint_names", "wheel_radius", "odom_slip",
                  "node_name", "odom_rate_hz", "joint_states_rate_hz", "diagnostics_rate_hz")

_D = defaults_of(KEYS)


@dataclass(frozen=True)
class Ros2Table(FrontEndTable):
    """The ``[ros2]`` table, its types checked (None: not given; arrays as tuples)."""

    namespace: str = _D["namespace"]
    node_name: str = _D["node_name"]
    domain_id: int | None = _D["domain_id"]
    cmd_vel_topic: str = _D["cmd_vel_topic"]
    cmd_vel_stamped: bool = _D["cmd_vel_stamped"]
    cmd_vel_timeout_s: float | None = _D["cmd_vel_timeout_s"]
    odom_topic: str = _D["odom_topic"]
    odom_frame: str = _D["odom_frame"]
    base_frame: str = _D["base_frame"]
    odom_rate_hz: float = _D["odom_rate_hz"]
    publish_tf: bool = _D["publish_tf"]
    tf_topic: str = _D["tf_topic"]
    joint_states_topic: str = _D["joint_states_topic"]
    joint_states_rate_hz: float = _D["joint_states_rate_hz"]
    joint_names: tuple[str, ...] | None = _D["joint_names"]
    wheel_radius: float | None = _D["wheel_radius"]
    diagnostics_topic: str = _D["diagnostics_topic"]
    diagnostics_rate_hz: float = _D["diagnostics_rate_hz"]
    battery_state_topic: str = _D["battery_state_topic"]
    battery_state_rate_hz: float = _D["battery_state_rate_hz"]
    recover_topic: str = _D["recover_topic"]
    odom_slip: float = _D["odom_slip"]
    interface: str | None = _D["interface"]
    peers: tuple[str, ...] | None = _D["peers"]
    multicast: bool = _D["multicast"]


def read(r: Reader, t: dict[str, Any], given: frozenset[str],
         base_dir: Path | None) -> Ros2Table:
    """The ``[ros2]`` table: its arrays of strings (omnican.ros2.settings checks the
    rest)."""
    for key in ("joint_names", "peers"):
        if t[key] is not None:
            if not all(isinstance(v, str) for v in t[key]):
                raise r.fail(f"ros2.{key}", "must be an array of strings")
            t[key] = tuple(t[key])
    return Ros2Table(**t)


TABLE = TableSpec(KEYS, read, telemetry=TELEMETRY_KEYS)
