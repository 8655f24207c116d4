"""Planar poses and odometry integrated from wheel travel.

Odometry takes *cumulative* rim travel per wheel (m), as read from the encoders,
turns each step's travel deltas into a body displacement through the kinematics,
and composes it onto the pose with the SE(2) exponential, which is exact when the
body twist is constant over the step.

Theta is kept continuous (not wrapped): after two full turns it reads about
``4 * pi``. Use :attr:`Pose2D.heading` for the angle wrapped to (-pi, pi].

Pure module: no I/O, no CAN imports.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from omnican.kinematics import OmniKinematics, Twist


def wrap_angle(angle: float) -> float:
    """Wrap an angle (rad) to (-pi, pi]."""
    wrapped = math.remainder(angle, math.tau)
    return math.pi if wrapped == -math.pi else wrapped


def _sinc_terms(theta: float) -> tuple[float, float]:
    """(sin t / t, (1 - cos t) / t) with series near 0 to stay accurate."""
    if abs(theta) < 1e-4:
        t2 = theta * theta
        return 1.0 - t2 / 6.0 + t2 * t2 / 120.0, theta / 2.0 - theta * t2 / 24.0
    return math.sin(theta) / theta, (1.0 - math.cos(theta)) / theta


@dataclass(frozen=True)
class Pose2D:
    """A planar pose: position ``x``, ``y`` (m) and heading ``theta`` (rad, CCW)."""

    x: float = 0.0
    y: float = 0.0
    theta: float = 0.0

    @property
    def heading(self) -> float:
        """theta wrapped to (-pi, pi]."""
        return wrap_angle(self.theta)

    def compose(self, other: Pose2D) -> Pose2D:
        """``self * other``: ``other`` expressed in this pose's frame, mapped to the world."""
        c, s = math.cos(self.theta), math.sin(self.theta)
        return Pose2D(
            self.x + c * other.x - s * other.y,
            self.y + s * other.x + c * other.y,
            self.theta + other.theta,
        )

    def inverse(self) -> Pose2D:
        c, s = math.cos(self.theta), math.sin(self.theta)
        return Pose2D(-c * self.x - s * self.y, s * self.x - c * self.y, -self.theta)

    def relative_to(self, origin: Pose2D) -> Pose2D:
        """This pose expressed in the frame of ``origin``."""
        return origin.inverse().compose(self)

    @classmethod
    def exp(cls, delta: Twist) -> Pose2D:
        """SE(2) exponential: the pose reached by moving with constant body twist
        ``delta`` (m, m, rad over one unit of time) from the origin."""
        a, b = _sinc_terms(delta.wz)
        return cls(a * delta.vx - b * delta.vy, b * delta.vx + a * delta.vy, delta.wz)

    def log(self) -> Twist:
        """Inverse of :meth:`exp` (theta taken as is, not wrapped)."""
        a, b = _sinc_terms(self.theta)
        det = a * a + b * b
        return Twist((a * self.x + b * self.y) / det, (-b * self.x + a * self.y) / det, self.theta)

    def distance_to(self, other: Pose2D) -> float:
        return math.hypot(self.x - other.x, self.y - other.y)

    def is_finite(self) -> bool:
        return math.isfinite(self.x) and math.isfinite(self.y) and math.isfinite(self.theta)


class Odometry:
    """Dead reckoning from cumulative wheel travel.

    ``update(travel)`` takes the cumulative rim travel of each wheel (m). The first
    call only seeds the reference, so encoders that start at any value cause no jump.
    After that, each call integrates the travel since the previous call.
    """

    def __init__(self, kinematics: OmniKinematics, pose: Pose2D | None = None) -> None:
        self._kin = kinematics
        # Rows of the forward map as plain floats: per-step work on 3-6 numbers is
        # several times faster in Python than through numpy.
        self._rows = tuple(tuple(float(v) for v in row) for row in kinematics.forward_matrix)
        self._pose = pose if pose is not None else Pose2D()
        self._last: list[float] | None = None
        self._delta = Twist()
        self._twist = Twist()

    @property
    def pose(self) -> Pose2D:
        return self._pose

    @property
    def delta(self) -> Twist:
        """Body displacement of the last step (m, m, rad), in the body frame at its start."""
        return self._delta

    @property
    def twist(self) -> Twist:
        """Body velocity of the last step (m/s, rad/s); zero unless ``dt_s`` was given."""
        return self._twist

    @property
    def seeded(self) -> bool:
        return self._last is not None

    def reset(self, pose: Pose2D | None = None) -> None:
        """Set the pose (default: origin); keeps the travel reference so nothing jumps."""
        self._pose = pose if pose is not None else Pose2D()
        self._delta = Twist()
        self._twist = Twist()

    def reseed(self) -> None:
        """Forget the travel reference: the next update only seeds (after an encoder reset)."""
        self._last = None

    def update(
        self, wheel_travel_m: Sequence[float] | npt.NDArray[np.float64], dt_s: float | None = None
    ) -> Pose2D:
        """Integrate cumulative wheel travel (m, one value per wheel); returns the new pose.

        ``dt_s`` (s) is the time the step took; it is only used for :attr:`twist`."""
        travel = [float(v) for v in wheel_travel_m]
        if len(travel) != self._kin.num_wheels:
            raise ValueError(f"expected {self._kin.num_wheels} wheel travels, got {len(travel)}")
        if not all(math.isfinite(v) for v in travel):
            raise ValueError(f"wheel travel contains a non-finite value: {travel}")
        last = self._last
        self._last = travel
        if last is None:
            return self._pose
        d = [a - b for a, b in zip(travel, last, strict=True)]
        rx, ry, rw = self._rows
        delta = Twist(sum(k * v for k, v in zip(rx, d, strict=True)),
                      sum(k * v for k, v in zip(ry, d, strict=True)),
                      sum(k * v for k, v in zip(rw, d, strict=True)))
        self._delta = delta
        self._pose = self._pose.compose(Pose2D.exp(delta))
        if dt_s is not None and dt_s > 0:
            self._twist = delta.scaled(1.0 / dt_s)
        return self._pose
