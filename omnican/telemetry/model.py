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
from dataclasses import dataclass, field
from typing import Any

from omnican.core.kinematics import OmniKinematics
from omnican.telemetry import messages as m
from omnican.telemetry.covariance import OdomCovariance
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
            if wants("/odom"):
                speeds = [w.actual_speed for w in s.wheels]
                out.append(state_message("/odom", ns, m.odometry(
                    s, settings, cov.pose_covariance(), cov.twist_covariance(speeds))))
            self.trail.add(ns, s.pose)  # every sample: the trail is whole when a viewer comes
            if wants("/odom/pose"):
                out.append(state_message("/odom/pose", ns, m.pose_stamped(
                    ns, s.pose, settings.odom_frame)))
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
            pose = s.pose
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
