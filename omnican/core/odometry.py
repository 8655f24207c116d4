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
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from omnican.core.kinematics import OmniKinematics, Twist


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
class Displacement:
    """A body displacement in the body frame at its start: ``dx``, ``dy`` in m, ``dtheta``
    in rad, what :meth:`Pose2D.exp` maps to a pose and :meth:`Pose2D.log` from one (as
    WPILib's ``Twist2d``). A velocity is a :class:`~omnican.core.kinematics.Twist`; one
    held for a time moves a :meth:`of` it."""

    dx: float = 0.0
    dy: float = 0.0
    dtheta: float = 0.0

    @classmethod
    def of(cls, twist: Twist, dt_s: float) -> Displacement:
        """The displacement of body velocity ``twist`` held for ``dt_s`` seconds (its
        exponential is the pose reached, :meth:`Pose2D.exp`)."""
        return cls(twist.vx * dt_s, twist.vy * dt_s, twist.wz * dt_s)

    def is_finite(self) -> bool:
        return math.isfinite(self.dx) and math.isfinite(self.dy) and math.isfinite(self.dtheta)

    # One release: log() and Odometry.delta gave a Twist, read as vx, vy, wz.
    @property
    def vx(self) -> float:
        """Deprecated: :attr:`dx` (the next release drops it)."""
        _moved("vx", "dx")
        return self.dx

    @property
    def vy(self) -> float:
        """Deprecated: :attr:`dy` (the next release drops it)."""
        _moved("vy", "dy")
        return self.dy

    @property
    def wz(self) -> float:
        """Deprecated: :attr:`dtheta` (the next release drops it)."""
        _moved("wz", "dtheta")
        return self.dtheta


def _moved(old: str, new: str) -> None:
    warnings.warn(f"a displacement's {old} moved to Displacement.{new} (a Twist is a "
                  "velocity); the old name goes in the next release", DeprecationWarning,
                  stacklevel=3)


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
    def exp(cls, delta: Displacement | Twist) -> Pose2D:
        """SE(2) exponential: the pose reached from the origin by body displacement
        ``delta`` (m, m, rad), moved along at a constant velocity. (A :class:`Twist`, read
        as a displacement over one second, is deprecated: :meth:`Displacement.of`.)"""
        if isinstance(delta, Twist):
            warnings.warn("Pose2D.exp(Twist) moved to Pose2D.exp(Displacement) (a Twist is "
                          "a velocity: Displacement.of(twist, dt_s)); the old form goes in "
                          "the next release", DeprecationWarning, stacklevel=2)
            delta = Displacement(delta.vx, delta.vy, delta.wz)
        a, b = _sinc_terms(delta.dtheta)
        return cls(a * delta.dx - b * delta.dy, b * delta.dx + a * delta.dy, delta.dtheta)

    def log(self) -> Displacement:
        """Inverse of :meth:`exp` (theta taken as is, not wrapped)."""
        a, b = _sinc_terms(self.theta)
        det = a * a + b * b
        return Displacement((a * self.x + b * self.y) / det, (-b * self.x + a * self.y) / det,
                            self.theta)

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

    __slots__ = ("_cols", "_d", "_dt", "_kin", "_last", "_n", "_pose", "_th", "_x", "_y")

    def __init__(self, kinematics: OmniKinematics, pose: Pose2D | None = None) -> None:
        self._kin = kinematics
        self._n = kinematics.num_wheels
        self._cols = kinematics.forward_cols
        start = pose if pose is not None else Pose2D()
        # The pose as plain floats; Pose2D objects are made when asked for.
        self._x, self._y, self._th = start.x, start.y, start.theta
        self._pose: Pose2D | None = start
        self._last: list[float] | None = None
        self._d = (0.0, 0.0, 0.0)
        self._dt: float | None = None

    @property
    def num_wheels(self) -> int:
        """How many wheel travels :meth:`update` takes."""
        return self._n

    @property
    def pose(self) -> Pose2D:
        pose = self._pose
        if pose is None:
            pose = self._pose = Pose2D(self._x, self._y, self._th)
        return pose

    @property
    def xyt(self) -> tuple[float, float, float]:
        """The pose as plain floats (x, y, theta)."""
        return self._x, self._y, self._th

    @property
    def delta(self) -> Displacement:
        """Body displacement of the last step (m, m, rad), in the body frame at its start."""
        return Displacement(*self._d)

    @property
    def last_step(self) -> tuple[float, float, float]:
        """:attr:`delta` as plain floats (dx, dy, dtheta)."""
        return self._d

    @property
    def twist(self) -> Twist:
        """Body velocity of the last step (m/s, rad/s); zero unless ``dt_s`` was given."""
        dt = self._dt
        if not dt:
            return Twist()
        dx, dy, dw = self._d
        return Twist(dx / dt, dy / dt, dw / dt)

    @property
    def seeded(self) -> bool:
        return self._last is not None

    def reset(self, pose: Pose2D | None = None) -> None:
        """Set the pose (default: origin); keeps the travel reference so nothing jumps."""
        start = pose if pose is not None else Pose2D()
        self._x, self._y, self._th = start.x, start.y, start.theta
        self._pose = start
        self._d, self._dt = (0.0, 0.0, 0.0), None

    def reseed(self) -> None:
        """Forget the travel reference: the next update only seeds (after an encoder reset)."""
        self._last = None

    def update(
        self, wheel_travel_m: Sequence[float] | npt.NDArray[np.float64], dt_s: float | None = None
    ) -> Pose2D:
        """Integrate cumulative wheel travel (m, one value per wheel); returns the new pose.

        ``dt_s`` (s) is the time the step took; it is only used for :attr:`twist`."""
        travel = [float(v) for v in wheel_travel_m]
        if len(travel) != self._n:
            raise ValueError(f"expected {self._n} wheel travels, got {len(travel)}")
        if not all(math.isfinite(v) for v in travel):
            raise ValueError(f"wheel travel contains a non-finite value: {travel}")
        self.step(travel, dt_s)
        return self.pose

    def step(self, travel: list[float],
             dt_s: float | None = None) -> tuple[float, float, float] | None:
        """:meth:`update` for the control loop: ``travel`` is a list of N finite floats
        (unchecked), and no Pose2D is made until :attr:`pose` is read. Returns
        :attr:`last_step`, or None when this call only seeded."""
        last = self._last
        self._last = travel
        if last is None:
            return None
        # kinematics.body_of_change and _sinc_terms, written out (each cycle).
        cols = self._cols
        if len(cols) == 3 and len(travel) == 3 and len(last) == 3:
            # Three wheels (nearly every base): the loop below unrolled, the same sums in
            # the same order.
            (a0, b0, c0), (a1, b1, c1), (a2, b2, c2) = cols
            d0, d1, d2 = travel[0] - last[0], travel[1] - last[1], travel[2] - last[2]
            dx = 0.0 + a0 * d0 + a1 * d1 + a2 * d2
            dy = 0.0 + b0 * d0 + b1 * d1 + b2 * d2
            dw = 0.0 + c0 * d0 + c1 * d1 + c2 * d2
        else:
            dx = dy = dw = 0.0
            for (ca, cb, cc), v1, v0 in zip(cols, travel, last, strict=True):
                d = v1 - v0
                dx += ca * d
                dy += cb * d
                dw += cc * d
        moved = self._d = (dx, dy, dw)
        self._dt = dt_s
        # Compose the SE(2) exponential of the step onto the pose.
        if -1e-4 < dw < 1e-4:
            t2 = dw * dw
            a, b = 1.0 - t2 / 6.0 + t2 * t2 / 120.0, dw / 2.0 - dw * t2 / 24.0
        else:
            a, b = math.sin(dw) / dw, (1.0 - math.cos(dw)) / dw
        lx, ly = a * dx - b * dy, b * dx + a * dy
        th = self._th
        c, s = math.cos(th), math.sin(th)
        self._x += c * lx - s * ly
        self._y += s * lx + c * ly
        self._th = th + dw
        self._pose = None
        return moved
