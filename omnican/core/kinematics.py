"""Omni-wheel base kinematics: body twist <-> wheel rim speeds.

Frames follow REP-103: x forward, y left, angles counter-clockwise positive.
Wheel ``i`` sits at ``(x_i, y_i)`` in the body frame and its rollers let it move
freely sideways, so only the component of the contact-point velocity along its
drive direction ``beta_i`` is driven (Modern Robotics, section 13.2)::

    v_i = cos(beta_i) * (vx - wz * y_i) + sin(beta_i) * (vy + wz * x_i)

For the usual layout, wheel ``i`` sits at angle ``phi_i`` on a circle of radius
``R`` and rolls along the counter-clockwise tangent (``beta_i = phi_i + 90 deg``),
which gives ``v_i = -sin(phi_i) vx + cos(phi_i) vy + R wz``.

Pure module: no I/O, no CAN imports.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from omnican.errors import ConfigError

FloatArray = npt.NDArray[np.float64]

#: Wheel angles (degrees from +x, CCW) of the presets, in wheel order.
LAYOUTS: dict[str, tuple[float, ...]] = {
    # SLAMWARE "b21" = SIT AThreeChassis: back, right, left.
    "b21": (180.0, -60.0, 60.0),
    # SLAMWARE "a12": front, rear-left, rear-right.
    "a12": (0.0, 120.0, -120.0),
}


@dataclass(frozen=True)
class Twist:
    """Body velocity in the body frame: ``vx``, ``vy`` in m/s, ``wz`` in rad/s (as
    WPILib's ``ChassisSpeeds``). A displacement (m, m, rad) is a
    :class:`~omnican.core.odometry.Displacement`."""

    vx: float = 0.0
    vy: float = 0.0
    wz: float = 0.0

    def as_array(self) -> FloatArray:
        return np.array([self.vx, self.vy, self.wz], dtype=np.float64)

    @classmethod
    def from_array(cls, values: Sequence[float] | FloatArray) -> Twist:
        vx, vy, wz = (float(v) for v in values)
        return cls(vx, vy, wz)

    def is_finite(self) -> bool:
        return math.isfinite(self.vx) and math.isfinite(self.vy) and math.isfinite(self.wz)

    def scaled(self, factor: float) -> Twist:
        return Twist(self.vx * factor, self.vy * factor, self.wz * factor)

    @property
    def linear_speed(self) -> float:
        """Norm of the linear part, m/s."""
        return math.hypot(self.vx, self.vy)

    def is_zero(self) -> bool:
        return self.vx == 0.0 and self.vy == 0.0 and self.wz == 0.0


def _finite_array(values: Any, name: str, shape_last: int | None = None) -> FloatArray:
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be numbers: {exc}") from None
    if shape_last is not None and (arr.ndim == 0 or arr.shape[-1] != shape_last):
        raise ValueError(f"{name} must have {shape_last} values per row, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains a non-finite value (NaN or inf): {values!r}")
    return arr


class OmniKinematics:
    """Kinematics of a base with N >= 3 omni wheels.

    Args:
        angles_deg: angle of each wheel's position from +x, CCW, degrees.
        base_radius: distance from the base centre to each wheel's contact point, m;
            one value for all wheels or one per wheel.
        drive_angles_deg: direction each wheel drives when its rim speed is positive,
            degrees from +x; default is the CCW tangent (``angle + 90``).

    Raises:
        ConfigError: fewer than 3 wheels, non-finite or non-positive numbers, or a
            geometry that cannot produce every body motion (rank < 3).
    """

    def __init__(
        self,
        angles_deg: Sequence[float],
        base_radius: float | Sequence[float],
        drive_angles_deg: Sequence[float] | None = None,
    ) -> None:
        angles = self._check_vector(angles_deg, "angles_deg")
        n = angles.size
        if n < 3:
            raise ConfigError(f"an omni base needs at least 3 wheels, got {n}")
        radii = self._check_vector(
            [base_radius] * n if np.isscalar(base_radius) else base_radius,
            "base_radius",
        )
        if radii.size != n:
            raise ConfigError(f"base_radius has {radii.size} values for {n} wheels")
        if np.any(radii <= 0):
            raise ConfigError(f"base_radius must be positive, got {radii.tolist()}")
        if drive_angles_deg is None:
            betas = angles + 90.0
        else:
            betas = self._check_vector(drive_angles_deg, "drive_angles_deg")
            if betas.size != n:
                raise ConfigError(f"drive_angles_deg has {betas.size} values for {n} wheels")
        phi = np.radians(angles)
        beta = np.radians(betas)
        x, y = radii * np.cos(phi), radii * np.sin(phi)
        matrix = np.column_stack(
            [np.cos(beta), np.sin(beta), x * np.sin(beta) - y * np.cos(beta)]
        )
        # Clean the round-off of cos(90 deg) and friends so presets match the seeds exactly.
        matrix[np.abs(matrix) < 1e-15] = 0.0
        if np.linalg.matrix_rank(matrix) < 3:
            raise ConfigError(
                f"degenerate wheel geometry (angles {angles.tolist()} deg, drive directions "
                f"{betas.tolist()} deg): the wheels cannot produce every body motion"
            )
        self.angles_deg: tuple[float, ...] = tuple(float(a) for a in angles)
        self.drive_angles_deg: tuple[float, ...] = tuple(float(b) for b in betas)
        self.base_radius: tuple[float, ...] = tuple(float(r) for r in radii)
        self._matrix: FloatArray = matrix
        self._matrix.setflags(write=False)
        self._inverse: FloatArray = np.linalg.pinv(matrix)
        self._inverse.setflags(write=False)
        # The same two maps as plain floats: per-cycle work on three to six numbers is
        # several times cheaper in Python than through numpy (see wheel_speeds_of).
        self.rows: tuple[tuple[float, float, float], ...] = tuple(
            (float(a), float(b), float(c)) for a, b, c in matrix.tolist())
        rx, ry, rw = self._inverse.tolist()
        self.forward_rows: tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...]] = (
            tuple(rx), tuple(ry), tuple(rw))
        # By wheel: what one wheel's value adds to (vx, vy, wz).
        self.forward_cols: tuple[tuple[float, float, float], ...] = tuple(
            zip(rx, ry, rw, strict=True))

    @staticmethod
    def _check_vector(values: Any, name: str) -> FloatArray:
        try:
            arr = np.asarray(values, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            raise ConfigError(f"{name} must be a list of numbers, got {values!r}") from None
        if not np.all(np.isfinite(arr)):
            raise ConfigError(f"{name} contains a non-finite number: {values!r}")
        return arr

    @classmethod
    def from_layout(cls, layout: str, base_radius: float | Sequence[float]) -> OmniKinematics:
        """A preset three-wheel layout: ``"b21"`` (= SIT) or ``"a12"`` (see :data:`LAYOUTS`)."""
        try:
            angles = LAYOUTS[layout]
        except KeyError:
            raise ConfigError(
                f"unknown layout {layout!r}; known layouts: {', '.join(sorted(LAYOUTS))}"
            ) from None
        return cls(angles, base_radius)

    @property
    def num_wheels(self) -> int:
        return int(self._matrix.shape[0])

    @property
    def matrix(self) -> FloatArray:
        """The N x 3 inverse-kinematics matrix: wheel speeds = matrix @ [vx, vy, wz]."""
        return self._matrix

    @property
    def forward_matrix(self) -> FloatArray:
        """The 3 x N (pseudo-)inverse: [vx, vy, wz] = forward_matrix @ wheel speeds."""
        return self._inverse

    def to_wheel_speeds(self, twist: Twist) -> FloatArray:
        """Wheel rim speeds (m/s, shape (N,)) that produce ``twist``."""
        if not twist.is_finite():
            raise ValueError(f"twist contains a non-finite value: {twist}")
        return self._matrix @ twist.as_array()

    def wheel_speeds_of(self, vx: float, vy: float, wz: float) -> list[float]:
        """:meth:`to_wheel_speeds` on plain floats, unchecked: the control loop's form."""
        return [a * vx + b * vy + c * wz for a, b, c in self.rows]

    def body_of(self, wheel_values: Sequence[float]) -> tuple[float, float, float]:
        """:meth:`to_twist` on plain floats, unchecked: (vx, vy, wz) from wheel speeds,
        or a body displacement from wheel travel deltas."""
        x = y = w = 0.0
        for (a, b, c), v in zip(self.forward_cols, wheel_values, strict=True):
            x += a * v
            y += b * v
            w += c * v
        return x, y, w

    def body_of_change(self, now: Sequence[float],
                       before: Sequence[float]) -> tuple[float, float, float]:
        """``body_of(now - before)`` without the list: the body displacement between two
        sets of cumulative wheel travel (odometry's step, the measured speed's window)."""
        x = y = w = 0.0
        for (a, b, c), v1, v0 in zip(self.forward_cols, now, before, strict=True):
            d = v1 - v0
            x += a * d
            y += b * d
            w += c * d
        return x, y, w

    def to_twist(self, wheel_speeds: Sequence[float] | FloatArray) -> Twist:
        """Body twist from wheel rim speeds (least squares when N > 3).

        Linear, so wheel travel deltas (m) map the same way, to a body displacement's
        dx, dy, dtheta (m, m, rad: :class:`~omnican.core.odometry.Displacement`)."""
        speeds = _finite_array(wheel_speeds, "wheel_speeds")
        if speeds.shape != (self.num_wheels,):
            raise ValueError(
                f"expected {self.num_wheels} wheel values, got shape {speeds.shape}"
            )
        return Twist.from_array(self._inverse @ speeds)

    def to_wheel_speeds_array(self, twists: npt.ArrayLike) -> FloatArray:
        """Vectorised :meth:`to_wheel_speeds`: (M, 3) twists -> (M, N) wheel speeds."""
        arr = _finite_array(twists, "twists", shape_last=3)
        out: FloatArray = arr @ self._matrix.T
        return out

    def to_twist_array(self, wheel_speeds: npt.ArrayLike) -> FloatArray:
        """Vectorised :meth:`to_twist`: (M, N) wheel speeds -> (M, 3) twists."""
        arr = _finite_array(wheel_speeds, "wheel_speeds", shape_last=self.num_wheels)
        out: FloatArray = arr @ self._inverse.T
        return out

    @staticmethod
    def desaturate(wheel_speeds: npt.ArrayLike, max_speed: float) -> FloatArray:
        """Scale all wheel speeds by one common factor so none exceeds ``max_speed``.

        The ratios between wheels (hence the direction of body motion) are kept.
        Accepts (N,) or (M, N); each row is scaled on its own."""
        if not math.isfinite(max_speed) or max_speed <= 0:
            raise ValueError(f"max_speed must be a positive number, got {max_speed!r}")
        speeds = _finite_array(wheel_speeds, "wheel_speeds")
        peak = np.max(np.abs(speeds), axis=-1, keepdims=True) if speeds.size else speeds
        # Only peaks above max_speed are divided by (a subnormal peak would overflow).
        scale = np.where(peak > max_speed, max_speed / np.where(peak > max_speed, peak, 1.0),
                         1.0)
        out: FloatArray = speeds * scale
        return out

    def __repr__(self) -> str:
        return (
            f"OmniKinematics(angles_deg={list(self.angles_deg)}, "
            f"base_radius={list(self.base_radius)})"
        )
