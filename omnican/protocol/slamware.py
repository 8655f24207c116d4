"""SLAMWARE base protocol: command 0x41 (set velocity and get dead reckoning).

Wire formats (little-endian, packed), as in SLAMWARE's base integration note:

* ``base_set_velocity_request_t``: int32 Q16 ``vx`` (m/s), ``vy`` (m/s),
  ``omega`` (rad/s); 12 bytes.
* ``base_deadreckon_response_t``: int32 Q16 ``dx`` (mm), ``dy`` (mm),
  ``dtheta`` (degrees), uint8 status bitmap; 13 bytes.

The functions here take and return SI units (m, m/s, rad, rad/s). Values are
rounded to the nearest Q16 step (the note truncates, losing up to one step), and
values beyond the int32 range saturate instead of wrapping.

The dead-reckoning bookkeeping (:class:`DeadReckoner`) fixes the note's ``Dy``
formula, which reports a lateral drift of ``R * dtheta`` for a pure spin: it maps
wheel travel through the kinematics and the SE(2) exponential instead.

Pure module: no I/O, no CAN imports.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from omnican.core.kinematics import OmniKinematics, Twist
from omnican.core.odometry import Displacement, Pose2D

CMD_SET_V_AND_GET_DEADRECKON = 0x41

_VELOCITY_REQUEST = struct.Struct("<iii")
_DEADRECKON_RESPONSE = struct.Struct("<iiiB")
VELOCITY_REQUEST_SIZE = _VELOCITY_REQUEST.size  # 12
DEADRECKON_RESPONSE_SIZE = _DEADRECKON_RESPONSE.size  # 13

_Q16 = 65536.0
_INT32_MIN, _INT32_MAX = -(2**31), 2**31 - 1


def to_q16(value: float) -> int:
    """A real number as a saturated int32 Q16.16 value."""
    if math.isnan(value):
        raise ValueError("cannot encode NaN as Q16")
    if math.isinf(value):
        return _INT32_MAX if value > 0 else _INT32_MIN
    return max(_INT32_MIN, min(_INT32_MAX, round(value * _Q16)))


def from_q16(raw: int) -> float:
    return raw / _Q16


def _check_length(data: bytes | bytearray | memoryview, size: int, what: str) -> bytes:
    buf = bytes(data)
    if len(buf) != size:
        raise ValueError(f"{what} must be {size} bytes, got {len(buf)}")
    return buf


def encode_velocity_request(vx: float, vy: float, omega: float) -> bytes:
    """Encode a velocity request: vx, vy in m/s, omega in rad/s."""
    return _VELOCITY_REQUEST.pack(to_q16(vx), to_q16(vy), to_q16(omega))


def decode_velocity_request(data: bytes | bytearray | memoryview) -> tuple[float, float, float]:
    """Decode a velocity request -> (vx m/s, vy m/s, omega rad/s)."""
    raw = _VELOCITY_REQUEST.unpack(
        _check_length(data, VELOCITY_REQUEST_SIZE, "base_set_velocity_request_t")
    )
    return from_q16(raw[0]), from_q16(raw[1]), from_q16(raw[2])


def encode_deadreckon_response(dx: float, dy: float, dtheta: float, status: int = 0) -> bytes:
    """Encode a dead-reckoning response: dx, dy in m, dtheta in rad, status bitmap 0-255."""
    if not 0 <= status <= 0xFF:
        raise ValueError(f"status must be 0-255, got {status}")
    return _DEADRECKON_RESPONSE.pack(
        to_q16(dx * 1000.0), to_q16(dy * 1000.0), to_q16(math.degrees(dtheta)), status
    )


def decode_deadreckon_response(
    data: bytes | bytearray | memoryview,
) -> tuple[float, float, float, int]:
    """Decode a dead-reckoning response -> (dx m, dy m, dtheta rad, status)."""
    dx, dy, dth, status = _DEADRECKON_RESPONSE.unpack(
        _check_length(data, DEADRECKON_RESPONSE_SIZE, "base_deadreckon_response_t")
    )
    return from_q16(dx) / 1000.0, from_q16(dy) / 1000.0, math.radians(from_q16(dth)), status


@dataclass(frozen=True)
class DeadReckonStep:
    """Answer to one 0x41 request.

    ``displacement`` is the base's motion since the previous request, expressed in
    the base frame at the previous request (x, y in m, theta in rad); ``velocity`` is
    the twist requested; ``wheel_speeds`` the rim speeds (m/s) that produce it."""

    displacement: Pose2D
    velocity: Twist
    wheel_speeds: npt.NDArray[np.float64]
    response: bytes


class DeadReckoner:
    """Serves SLAMWARE's set-velocity-and-get-dead-reckoning command.

    Call :meth:`handle` with each request and the current cumulative wheel travel
    (m per wheel). The first call reports zero displacement (it seeds the travel
    reference), so encoders that start anywhere cause no jump."""

    def __init__(self, kinematics: OmniKinematics) -> None:
        self._kin = kinematics
        self._last: npt.NDArray[np.float64] | None = None

    def displacement(self, wheel_travel_m: Sequence[float] | npt.NDArray[np.float64]) -> Pose2D:
        """Motion since the previous call, in the base frame at the previous call."""
        travel = np.array(wheel_travel_m, dtype=np.float64)
        if travel.shape != (self._kin.num_wheels,):
            raise ValueError(
                f"expected {self._kin.num_wheels} wheel travels, got shape {travel.shape}"
            )
        if self._last is None:
            self._last = travel
            return Pose2D()
        moved = self._kin.to_twist(travel - self._last)  # travel maps as speeds do
        self._last = travel
        return Pose2D.exp(Displacement(moved.vx, moved.vy, moved.wz))

    def handle(
        self,
        request: bytes | bytearray | memoryview,
        wheel_travel_m: Sequence[float] | npt.NDArray[np.float64],
        status: int = 0,
    ) -> DeadReckonStep:
        vx, vy, omega = decode_velocity_request(request)
        velocity = Twist(vx, vy, omega)
        moved = self.displacement(wheel_travel_m)
        return DeadReckonStep(
            displacement=moved,
            velocity=velocity,
            wheel_speeds=self._kin.to_wheel_speeds(velocity),
            response=encode_deadreckon_response(moved.x, moved.y, moved.theta, status),
        )
