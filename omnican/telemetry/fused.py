"""The topics of the odometry fused with an IMU's gyro: ``/odometry/filtered`` and
``/odom/wheels`` beside ``/odom``, and ``/fusion``, the fused heading beside the wheels'.

A sample's ``fused`` (:attr:`omnican.chassis.state.Snapshot.fused`; None without an IMU)
is the filter's state (:mod:`omnican.core.fusion`). Pure: a sample in, plain values out.
``messages`` takes the topics and the schema from here (this module imports none of
telemetry's); :mod:`~omnican.telemetry.model` makes ``/odom`` of the fused state.
"""

from __future__ import annotations

import math
from typing import Any, Protocol

from omnican.core.odometry import Pose2D

Fused = tuple[float, float, float, float, float, float, float, bool, bool]


class FusedSample(Protocol):
    """What these read of a sample (:class:`omnican.telemetry.messages.TelemetrySample`)."""

    @property
    def stamp_ns(self) -> int: ...
    @property
    def pose(self) -> Pose2D | None: ...
    @property
    def fused(self) -> Fused | None: ...


#: The topics of the fused odometry beside /odom (in messages.TOPICS): the same by
#: robot_localization's name, the wheels' own, its pose for the 3D panel, the headings.
ROS2, JSON = "ros2", "json"  # the message kinds, as messages.ROS2 and messages.JSON
FUSED_TOPICS: dict[str, tuple[str, str]] = {
    "/odometry/filtered": ("nav_msgs/msg/Odometry", ROS2),
    "/odom/wheels": ("nav_msgs/msg/Odometry", ROS2),
    "/odom/wheels/pose": ("geometry_msgs/msg/PoseStamped", ROS2),
    "/fusion": ("omnican.Fusion", JSON),
}

_NUM = {"type": "number"}
_BOOL = {"type": "boolean"}
_ABSENT = {"type": "number", "description": "absent when no IMU is fused"}
#: /fusion's JSON schema (messages.JSON_SCHEMAS; Foxglove's parser: one type a field)
FUSION_SCHEMA: dict[str, Any] = {"title": "omnican.Fusion", "type": "object", "properties": {
    "timestamp": {"type": "object", "properties": {"sec": {"type": "integer"},
                                                   "nsec": {"type": "integer"}}},
    "imu": _BOOL, "heading_deg": _NUM, "wheels_heading_deg": _NUM, "slipping": _BOOL,
    "heading_sigma_deg": _ABSENT, "gyro_bias_deg_s": _ABSENT, "yaw_rate": _ABSENT}}


def fused_pose(s: FusedSample) -> Pose2D | None:
    """The pose fused with the IMU's gyro; the wheels' (``s.pose``) without an IMU."""
    f = s.fused
    return s.pose if f is None else Pose2D(f[0], f[1], f[2])


def fusion(s: FusedSample) -> dict[str, Any]:
    """omnican.Fusion: the fused heading beside the wheels' (degrees, continuous, for
    plots), its 1-sigma, the gyro's bias, the IMU live, the wheels slipping. Without an
    IMU: the wheels' alone, ``imu`` false, the filter's figures absent (the app's JSON
    schemas have no null)."""
    assert s.pose is not None
    wheels = math.degrees(s.pose.theta)
    f = s.fused
    ns = s.stamp_ns
    out = {"timestamp": {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000},
           "wheels_heading_deg": wheels}
    if f is None:
        return {**out, "imu": False, "heading_deg": wheels, "slipping": False}
    return {**out, "imu": bool(f[7]), "heading_deg": math.degrees(f[2]),
            "heading_sigma_deg": math.degrees(math.sqrt(max(f[3], 0.0))),
            "gyro_bias_deg_s": math.degrees(f[4]), "yaw_rate": f[6], "slipping": bool(f[8])}
