"""The one model of what the front ends publish: each sample of the base becomes the
same list of :class:`Message` for the ROS 2 bridge, the live view and the MCAP recorder.

:class:`Telemetry` keeps what spans samples: the odometry covariance, carried from
sample to sample (it grows with the distance rolled), the path rolled so far
(:mod:`~omnican.telemetry.trail`, published every ``trail.PERIOD_S``), and when
diagnostics are due (once per ``diagnostics_period_s`` of the base's clock, and at once
when a level or a message changes). A message's bytes (CDR for ROS 2 types, JSON for
the rest) are made once, by the first front end that asks for them, and shared.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

from omnican.core.kinematics import OmniKinematics, Twist
from omnican.core.odometry import Pose2D
from omnican.telemetry import messages as m
from omnican.telemetry.covariance import OdomCovariance
from omnican.telemetry.fused import fused_pose, fusion
from omnican.telemetry.settings import TelemetrySettings
from omnican.telemetry.trail import PERIOD_S as TRAIL_PERIOD_S
from omnican.telemetry.trail import Trail

Wants = Callable[[str], bool]


def _all(topic: str) -> bool:
    return True


@dataclass
class Message:
    """One message on one topic: ``data`` (plain values, the ROS field names) and, once
    asked for, its bytes (``payload()``)."""

    topic: str
    schema: str
    kind: str  # messages.ROS2 (CDR) or messages.JSON
    stamp_ns: int
    data: dict[str, Any] | None  # None for a raw CAN frame: its bytes are made at once
    _payload: bytes | None = field(default=None, repr=False)

    def payload(self) -> bytes:
        """CDR (ROS 2 types) or JSON bytes, made on first use and kept."""
        if self._payload is None:
            assert self.data is not None
            if self.kind == m.JSON:
                self._payload = json.dumps(self.data).encode()
            else:
                from omnican.telemetry import cdr

                self._payload = cdr.encode(self.schema, self.data)
        return self._payload

    def decoded(self) -> dict[str, Any]:
        """The data as plain values (a raw frame's decoded from its bytes)."""
        if self.data is None:
            from omnican.telemetry import cdr

            self.data = cdr.decode(self.schema, self.payload())
        return self.data


def state_message(topic: str, stamp_ns: int, data: dict[str, Any]) -> Message:
    schema, kind = m.TOPICS[topic]
    return Message(topic, schema, kind, stamp_ns, data)


#: rad^2/s^2: the fused yaw rate's variance beyond the bias's: one gyro sample's noise
#: (the [fusion] table's gyro_noise default, 0.005 rad/s)
FUSED_RATE_VAR = 0.005 ** 2


def fused_odometry(s: m.TelemetrySample, settings: TelemetrySettings,
                   pose_covariance: list[float], twist_covariance: list[float]
                   ) -> dict[str, Any]:
    """``/odom`` of a base with an IMU: the fused pose and yaw rate; the covariances the
    wheels' (x, y, vx, vy: the gyro says nothing of them) with the yaw's and the yaw
    rate's the filter's (its heading variance; the bias's variance plus a sample's noise)."""
    f = s.fused
    assert f is not None and s.twist is not None
    pose_cov, twist_cov = list(pose_covariance), list(twist_covariance)
    pose_cov[35] = f[3]
    twist_cov[35] = f[5] + FUSED_RATE_VAR
    t = s.twist
    fused = replace(s, pose=Pose2D(f[0], f[1], f[2]), twist=Twist(t.vx, t.vy, f[6]))
    return m.odometry(fused, settings, pose_cov, twist_cov)


class Telemetry:
    """Samples -> messages, for every front end alike (see the module docstring)."""

    def __init__(self, settings: TelemetrySettings, kinematics: OmniKinematics) -> None:
        self.settings = settings
        self.covariance = OdomCovariance(kinematics, settings.odom_slip, settings.counts_per_m,
                                         settings.speed_window_s)
        self._diag_period_ns = round(settings.diagnostics_period_s * 1e9)
        self._diag_signature: tuple[tuple[int, str], ...] | None = None
        self._diag_ns = 0
        self.trail = Trail()
        self._trail_period_ns = round(TRAIL_PERIOD_S * 1e9)
        self._trail_ns: int | None = None

    def messages(self, s: m.TelemetrySample, wants: Wants = _all, last: bool = False
                 ) -> list[Message]:
        """The messages of sample ``s`` on the topics ``wants`` accepts. ``last``: the
        final sample of a run (its diagnostics go whether due or not)."""
        settings, ns = self.settings, s.stamp_ns
        out: list[Message] = []
        if s.pose is not None:
            cov = self.covariance
            cov.update(s.pose)  # every sample: the covariance follows the distance rolled
            pose = fused_pose(s)  # the base's: fused where an IMU is, else the wheels'
            assert pose is not None
            wants_odom, wants_filtered = wants("/odom"), wants("/odometry/filtered")
            wants_wheels = wants("/odom/wheels")
            if wants_odom or wants_filtered or wants_wheels:
                speeds = [w.actual_speed for w in s.wheels]
                pose_cov, twist_cov = cov.pose_covariance(), cov.twist_covariance(speeds)
                wheels = m.odometry(s, settings, pose_cov, twist_cov)
                odom = wheels if s.fused is None else fused_odometry(s, settings, pose_cov,
                                                                     twist_cov)
                if wants_odom:
                    out.append(state_message("/odom", ns, odom))
                if wants_filtered:
                    out.append(state_message("/odometry/filtered", ns, odom))
                if wants_wheels:
                    out.append(state_message("/odom/wheels", ns, wheels))
            self.trail.add(ns, pose)  # every sample: the trail is whole when a viewer comes
            if wants("/odom/pose"):
                out.append(state_message("/odom/pose", ns, m.pose_stamped(
                    ns, pose, settings.odom_frame)))
            if wants("/odom/wheels/pose"):
                out.append(state_message("/odom/wheels/pose", ns, m.pose_stamped(
                    ns, s.pose, settings.odom_frame)))
            if wants("/fusion"):
                out.append(state_message("/fusion", ns, fusion(s)))
            if wants("/odom/path") and (last or self._trail_ns is None
                                        or ns - self._trail_ns >= self._trail_period_ns):
                self._trail_ns = ns
                out.append(state_message("/odom/path", ns, m.path(
                    ns, self.trail.points, settings.odom_frame)))
            if wants("/tf"):
                out.append(state_message("/tf", ns, m.transforms(s, settings)))
            if wants("/joint_states"):
                joints = m.joint_states(s, settings)
                if joints is not None:
                    out.append(state_message("/joint_states", ns, joints))
            if wants("/diagnostics"):
                diag = m.diagnostics(s, settings)
                if self._diagnostics_due(ns, diag) or last:
                    out.append(state_message("/diagnostics", ns, diag))
            if wants("/battery_state"):
                battery = m.battery_state(s, settings)
                if battery is not None:
                    out.append(state_message("/battery_state", ns, battery))
            for topic, make in (("/pose2d", lambda: m.pose2d(ns, pose)),
                                ("/twist", lambda: m.twist(s)),
                                ("/wheels", lambda: m.wheels(s)),
                                ("/status", lambda: m.status(s))):
                if wants(topic):
                    out.append(state_message(topic, ns, make()))
        if s.true_pose is not None:
            if wants("/sim/true_pose"):
                out.append(state_message("/sim/true_pose", ns, m.pose_stamped(
                    ns, s.true_pose, settings.odom_frame)))
            if wants("/sim/pose2d"):
                out.append(state_message("/sim/pose2d", ns, m.pose2d(ns, s.true_pose)))
        return out

    def _diagnostics_due(self, ns: int, message: dict[str, Any]) -> bool:
        """Once a period, as ROS's diagnostic aggregator expects, and at once when a level
        or a message changes (a fault, the bus down); a change restarts the period."""
        signature = m.diagnostics_signature(message)
        if signature == self._diag_signature and ns - self._diag_ns < self._diag_period_ns:
            return False
        self._diag_signature, self._diag_ns = signature, ns
        return True
