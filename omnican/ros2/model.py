"""What the ROS 2 bridge says about the base, as plain values: timestamps, quaternions,
odometry covariances, joint states and diagnostic statuses. Pure: no DDS, no I/O; the
bridge turns these into messages.

Odometry uncertainty (what the covariances mean). Each wheel's travel is off by slip
that is independent from one metre of travel to the next, with a standard deviation of
``slip`` times the metre: after a wheel rolled ``d`` metres its error has the variance
``slip**2 * d``. Through the base's forward kinematics that is a covariance of the body
displacement of every step, which is carried into the odom frame and summed (the usual
dead-reckoning propagation: the pose covariance grows with the distance driven and never
shrinks). The twist covariance has the same slip, proportional to each wheel's speed, on
top of the speed resolution of the encoders: one count within the window the speeds are
measured over. Height, roll and pitch are not measured by wheel odometry; they get a
large variance, as ROS 2 drivers of planar bases report them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from omnican.cia402 import State
from omnican.kinematics import OmniKinematics, Twist
from omnican.odometry import Pose2D

if TYPE_CHECKING:
    from omnican.chassis import ChassisStatus, WheelState

FloatArray = npt.NDArray[np.float64]

#: Variance for the degrees of freedom wheel odometry does not observe (z, roll, pitch).
UNOBSERVED_VARIANCE = 1e6

# diagnostic_msgs/DiagnosticStatus levels.
OK, WARN, ERROR, STALE = 0, 1, 2, 3
LEVEL_NAMES = {OK: "OK", WARN: "WARN", ERROR: "ERROR", STALE: "STALE"}

#: Bus load above this fraction of the bitrate is a warning.
BUS_LOAD_WARN = 0.7


def ros_time(t: float) -> tuple[int, int]:
    """Seconds since the epoch -> builtin_interfaces/Time (sec, nanosec)."""
    ns = round(t * 1e9)
    sec, nanosec = divmod(ns, 1_000_000_000)
    return int(sec), int(nanosec)


def yaw_quaternion(theta: float) -> tuple[float, float, float, float]:
    """A rotation of ``theta`` about z as (x, y, z, w)."""
    half = 0.5 * theta
    return 0.0, 0.0, math.sin(half), math.cos(half)


def quaternion_yaw(x: float, y: float, z: float, w: float) -> float:
    """The yaw (rotation about z) of a quaternion, in (-pi, pi]."""
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


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


def joint_values(travel: Sequence[float], speeds: Sequence[float],
                 radii: Sequence[float]) -> tuple[list[float], list[float]]:
    """Wheel joint positions (rad) and velocities (rad/s) from rim travel (m) and rim
    speeds (m/s): angle = travel / radius. Positive is the wheel's drive direction."""
    pos = [t / r for t, r in zip(travel, radii, strict=True)]
    vel = [v / r for v, r in zip(speeds, radii, strict=True)]
    return pos, vel


@dataclass(frozen=True)
class Status:
    """One diagnostic_msgs/DiagnosticStatus, as plain values."""

    level: int
    name: str
    message: str
    hardware_id: str
    values: tuple[tuple[str, str], ...]


def _fmt(value: float | None, spec: str = ".3f") -> str:
    return "-" if value is None else format(value, spec)


def chassis_status(prefix: str, status: ChassisStatus, recover_note: str | None = None
                   ) -> Status:
    """The base as a whole: enabled, latched stop, loop rate, command age."""
    enabled = status.enabled
    reason = status.stopped_reason
    if reason:
        level, message = ERROR, f"stopped: {reason} (send to recover to clear)"
    elif not enabled:
        level, message = WARN, "drives not enabled"
    else:
        level, message = OK, "enabled"
    values = [
        ("enabled", str(enabled).lower()),
        ("stopped_reason", reason or ""),
        ("loop_hz", _fmt(status.loop_hz, ".1f")),
        ("late_fraction", _fmt(status.late_fraction, ".4f")),
        ("cycles", str(status.cycles)),
        ("command_age_s", _fmt(status.command_age_s, ".3f")),
    ]
    if recover_note:
        values.append(("last_recover", recover_note))
    values += [(f"warning_{i}", w) for i, w in enumerate(status.warnings)]
    return Status(level, f"{prefix}: chassis", message, "", tuple(values))


def bus_status(prefix: str, status: ChassisStatus, channel: str) -> Status:
    """The CAN bus: load, bit rate, errors."""
    load, error = status.bus_load, status.bus_error
    up = bool(getattr(status, "bus_up", True))  # ChassisStatus.bus_up is newer than this code
    if not up:
        level, message = ERROR, f"bus down: {error or 'no frames sent'}"
    elif load is not None and load > BUS_LOAD_WARN:
        level, message = WARN, f"bus load {load:.0%}"
    else:
        level = OK
        message = "bus load " + (f"{load:.0%}" if load is not None else "unknown (no bitrate)")
    values = (
        ("bus_load", _fmt(load, ".4f")),
        ("bits_per_s", _fmt(status.bus_bits_per_s, ".0f")),
        ("bus_up", str(up).lower()),
        ("last_error", error or ""),
    )
    return Status(level, f"{prefix}: CAN bus", message, channel, values)


def wheel_status(prefix: str, wheel: WheelState, joint: str) -> Status:
    """One wheel's drive: CiA 402 state, faults (with the EMCY text), speeds, travel."""
    state, fault, error, online = wheel.state, wheel.fault, wheel.error, wheel.online
    stale = bool(getattr(wheel, "stale", False))  # WheelState.stale is newer than this code
    node, axis = wheel.node_id, wheel.axis
    if fault or state in (State.FAULT, State.FAULT_REACTION_ACTIVE):
        level, message = ERROR, f"fault: {fault or state}"
    elif not online:
        level, message = ERROR, "offline (no heartbeat)"
    elif error:
        level, message = ERROR, error
    elif state is not State.OPERATION_ENABLED:
        level, message = WARN, str(state)
    elif stale:
        level, message = WARN, "no fresh encoder sample"
    else:
        level, message = OK, str(state)
    sw = wheel.statusword
    values = (
        ("state", str(state)),
        ("statusword", "-" if sw is None else f"0x{sw:04X}"),
        ("mode", "-" if wheel.mode is None else str(wheel.mode)),
        ("target_speed_mps", _fmt(wheel.target_speed, ".4f")),
        ("actual_speed_mps", _fmt(wheel.actual_speed, ".4f")),
        ("travel_m", _fmt(wheel.travel, ".4f")),
        ("online", str(online).lower()),
        ("fault", fault or ""),
        ("error", error or ""),
    )
    hw = f"canopen node {node}" + (f" axis {axis}" if axis else "")
    return Status(level, f"{prefix}: wheel {wheel.index} ({joint})", message, hw, values)


def bridge_status(prefix: str, rates: dict[str, float], cmd_vel_count: int,
                  cmd_vel_rejected: int) -> Status:
    """The bridge itself: achieved publish rates, cmd_vel received."""
    values = tuple((f"{name}_hz", f"{hz:.1f}") for name, hz in rates.items())
    values += (("cmd_vel_received", str(cmd_vel_count)),
               ("cmd_vel_rejected", str(cmd_vel_rejected)))
    return Status(OK, f"{prefix}: ros2 bridge", "running", "", values)


def twist_from_msg(linear: Sequence[float], angular: Sequence[float]) -> Twist:
    """The planar part of a geometry_msgs/Twist (x, y linear; z angular)."""
    return Twist(float(linear[0]), float(linear[1]), float(angular[2]))
