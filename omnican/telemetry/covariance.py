"""The covariances of wheel odometry: how far off the pose and the measured twist may be.

Odometry uncertainty (what the covariances mean). Each wheel's travel is off by slip
that is independent from one metre of travel to the next, with a standard deviation of
``slip`` times the metre: after a wheel rolled ``d`` metres its error has the variance
``slip**2 * d``. Through the base's forward kinematics that is a covariance of the body
displacement of every step, which is carried into the odom frame and summed (the usual
dead-reckoning propagation: the pose covariance grows with the distance driven and never
shrinks). The twist covariance has the same slip, proportional to each wheel's speed, on
top of the speed resolution of the encoders: one count within the window the speeds are
measured over. Height, roll and pitch are not measured by wheel odometry; they get a
large variance, as ROS 2 drivers of planar bases report them. Pure: no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from omnican.core.kinematics import OmniKinematics
from omnican.core.odometry import Pose2D

FloatArray = npt.NDArray[np.float64]

#: Variance for the degrees of freedom wheel odometry does not observe (z, roll, pitch).
UNOBSERVED_VARIANCE = 1e6


def _embed(cov3: FloatArray) -> list[float]:
    """A 3x3 (x, y, yaw) covariance as ROS 2's row-major 6x6 (x, y, z, roll, pitch, yaw)."""
    out = np.zeros((6, 6))
    idx = [0, 1, 5]
    out[np.ix_(idx, idx)] = cov3
    for i in (2, 3, 4):
        out[i, i] = UNOBSERVED_VARIANCE
    return [float(v) for v in out.reshape(36)]


class OdomCovariance:
    """Pose and twist covariances of wheel odometry (see the module docstring).

    Feed it every pose the bridge publishes (:meth:`update`); it carries the pose
    covariance along. The wheel geometry comes from ``kinematics``; ``counts_per_m`` is
    each wheel's encoder resolution (position_scale) and ``speed_window_s`` the window
    measured speeds average over."""

    def __init__(self, kinematics: OmniKinematics, slip: float,
                 counts_per_m: Sequence[float], speed_window_s: float) -> None:
        self._inverse = np.asarray(kinematics.matrix, dtype=np.float64)  # N x 3
        self._forward = np.asarray(kinematics.forward_matrix, dtype=np.float64)  # 3 x N
        self.slip = float(slip)
        # One count within the speed window: the speed resolution, as a standard deviation
        # of a uniform quantisation error (width / sqrt(12)).
        self._speed_floor = np.array([1.0 / (abs(c) * speed_window_s) / math.sqrt(12.0)
                                      for c in counts_per_m])
        self.pose_cov3 = np.zeros((3, 3))
        self._last: Pose2D | None = None

    def reset(self, pose: Pose2D | None = None) -> None:
        self.pose_cov3 = np.zeros((3, 3))
        self._last = pose

    def update(self, pose: Pose2D) -> FloatArray:
        """Carry the pose covariance to ``pose`` (from the previous one); returns it (3x3)."""
        last = self._last
        self._last = pose
        if last is None:
            return self.pose_cov3
        step = pose.relative_to(last)  # body-frame displacement (dx, dy, dtheta)
        travel = self._inverse @ np.array([step.x, step.y, step.theta])
        wheel_var = self.slip ** 2 * np.abs(travel)  # m^2 per wheel
        q_body = (self._forward * wheel_var) @ self._forward.T
        c, s = math.cos(last.theta), math.sin(last.theta)
        dx_w, dy_w = pose.x - last.x, pose.y - last.y
        f = np.array([[1.0, 0.0, -dy_w], [0.0, 1.0, dx_w], [0.0, 0.0, 1.0]])
        g = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        cov = f @ self.pose_cov3 @ f.T + g @ q_body @ g.T
        self.pose_cov3 = 0.5 * (cov + cov.T)  # keep it exactly symmetric
        return self.pose_cov3

    def pose_covariance(self) -> list[float]:
        return _embed(self.pose_cov3)

    def twist_cov3(self, wheel_speeds: Sequence[float]) -> FloatArray:
        """Covariance (3x3, body frame) of the twist measured from these wheel speeds."""
        v = np.abs(np.asarray(wheel_speeds, dtype=np.float64))
        var = self._speed_floor ** 2 + (self.slip * v) ** 2
        cov = (self._forward * var) @ self._forward.T
        return np.asarray(0.5 * (cov + cov.T), dtype=np.float64)

    def twist_covariance(self, wheel_speeds: Sequence[float]) -> list[float]:
        return _embed(self.twist_cov3(wheel_speeds))
