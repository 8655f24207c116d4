"""The fused odometry on the wire: /odom and /odometry/filtered carry the fused pose and
the filter's yaw variances, /odom/wheels the wheels' own; without an IMU all three are
the wheels'; /fusion puts the two headings side by side."""

from __future__ import annotations

import math
from dataclasses import replace

from hypothesis import given, settings
from hypothesis import strategies as st

from omnican import telemetry
from omnican.core.odometry import Pose2D
from omnican.telemetry import Telemetry
from tests.telemetry.test_telemetry import CFG, SETTINGS, decoder, sample

angle = st.floats(-20.0, 20.0)


def yaw(odom: dict[str, object]) -> float:
    q = odom["pose"]["pose"]["orientation"]  # type: ignore[index]
    return 2.0 * math.atan2(q["z"], q["w"])  # type: ignore[index]


@settings(deadline=None, max_examples=30)
@given(angle, angle, st.floats(0.0, 0.1), st.booleans())
def test_odom_is_the_fused_and_odom_wheels_the_wheels(wheels_theta: float, fused_theta: float,
                                                      var: float, slipping: bool) -> None:
    fused = (1.0, 2.0, fused_theta, var, 0.01, 1e-6, 0.3, True, slipping)
    s = replace(sample(Pose2D(0.5, 0.5, wheels_theta)), fused=fused)
    msgs = {m.topic: m for m in Telemetry(SETTINGS, CFG.kinematics()).messages(s)}
    odom = msgs["/odom"].decoded()
    assert abs(math.remainder(yaw(odom) - fused_theta, math.tau)) < 1e-9
    assert odom["pose"]["pose"]["position"]["x"] == 1.0
    assert odom["pose"]["covariance"][35] == var
    assert odom["twist"]["twist"]["angular"]["z"] == 0.3
    assert msgs["/odometry/filtered"].decoded() == odom
    wheels = msgs["/odom/wheels"].decoded()
    assert abs(math.remainder(yaw(wheels) - wheels_theta, math.tau)) < 1e-9
    assert wheels["pose"]["pose"]["position"]["x"] == 0.5
    for topic in ("/odom", "/odom/wheels", "/odometry/filtered"):
        assert decoder("nav_msgs/msg/Odometry")(msgs[topic].payload()) is not None
    tf = msgs["/tf"].decoded()["transforms"][0]["transform"]
    assert tf["translation"]["x"] == 1.0
    f = msgs["/fusion"].decoded()
    assert f["heading_deg"] == math.degrees(fused_theta)
    assert f["wheels_heading_deg"] == math.degrees(wheels_theta)
    assert f["imu"] is True and f["slipping"] is slipping
    assert set(f) <= set(telemetry.JSON_SCHEMAS["omnican.Fusion"]["properties"])


def test_without_an_imu_every_odometry_is_the_wheels() -> None:
    s = sample(Pose2D(0.5, -0.5, 1.0))
    msgs = {m.topic: m.decoded() for m in Telemetry(SETTINGS, CFG.kinematics()).messages(s)}
    assert msgs["/odom"] == msgs["/odom/wheels"] == msgs["/odometry/filtered"]
    assert msgs["/fusion"]["imu"] is False
    assert "heading_sigma_deg" not in msgs["/fusion"]  # absent, not null
    assert msgs["/fusion"]["heading_deg"] == msgs["/fusion"]["wheels_heading_deg"]
