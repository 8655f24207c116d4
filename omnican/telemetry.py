"""The robot's state as messages, for the live view (Foxglove) and MCAP recordings.

Pure: a :class:`Sample` (one poll of a running base, plus the simulator's ground truth)
in, plain dicts out. ROS 2 messages (``nav_msgs/msg/Odometry``, ``tf2_msgs/msg/TFMessage``,
``sensor_msgs/msg/JointState``, ``diagnostic_msgs/msg/DiagnosticArray``,
``geometry_msgs/msg/PoseStamped``) are nested dicts with the message's field names, for
:mod:`omnican.rosmsg` to serialize; the rest are JSON objects with a JSON schema each
(Foxglove's plot and state-transition panels read any field of them).

Frames follow REP-103/REP-105: ``odom`` is the fixed odometry frame, ``base_link`` the
body; twists are in the body frame. SI units throughout.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from omnican.cia402 import State
from omnican.kinematics import Twist
from omnican.odometry import Pose2D

if TYPE_CHECKING:  # types only: this module stays free of bus code
    from omnican.chassis import ChassisStatus, WheelState

# diagnostic_msgs/msg/DiagnosticStatus levels
OK, WARN, ERROR, STALE = 0, 1, 2, 3

# A planar base measures x, y and yaw; z, roll and pitch are held by the floor. These are
# fixed variances (m^2, rad^2), as ROS's diff_drive_controller publishes by default: wheel
# odometry has no noise model of its own.
POSE_VARIANCE = (1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 1e-2)
TWIST_VARIANCE = (1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 1e-2)


@dataclass(frozen=True)
class Frames:
    odom: str = "odom"
    base: str = "base_link"


@dataclass(frozen=True)
class Sample:
    """One poll of a running base. ``stamp_ns``: wall-clock time, ns since the epoch."""

    stamp_ns: int
    pose: Pose2D
    twist: Twist  # measured, body frame
    command: Twist  # applied this cycle (after the limits), body frame
    wheels: tuple[WheelState, ...]
    status: ChassisStatus
    true_pose: Pose2D | None = None  # the simulator's ground truth
    true_twist: Twist | None = None


def sample(base: Any, truth: Any = None) -> Sample:
    """Poll a running base (an :class:`omnican.Chassis`) and, under simulation, the
    simulated base's ground truth. Reads snapshots only; costs the control loop nothing."""
    return Sample(stamp_ns=time.time_ns(), pose=base.pose, twist=base.twist,
                  command=base.command, wheels=base.wheels, status=base.status,
                  true_pose=truth.true_pose if truth is not None else None,
                  true_twist=truth.true_twist if truth is not None else None)


def stamp(ns: int) -> dict[str, int]:
    """builtin_interfaces/msg/Time of a wall-clock time in ns."""
    return {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}


def yaw_quaternion(theta: float) -> dict[str, float]:
    return {"x": 0.0, "y": 0.0, "z": math.sin(theta / 2.0), "w": math.cos(theta / 2.0)}


def _diagonal(values: Sequence[float]) -> list[float]:
    out = [0.0] * 36
    for i, v in enumerate(values):
        out[7 * i] = v
    return out


def _vector(x: float = 0.0, y: float = 0.0, z: float = 0.0) -> dict[str, float]:
    return {"x": x, "y": y, "z": z}


def _header(ns: int, frame: str) -> dict[str, Any]:
    return {"stamp": stamp(ns), "frame_id": frame}


def _pose(p: Pose2D) -> dict[str, Any]:
    return {"position": _vector(p.x, p.y), "orientation": yaw_quaternion(p.theta)}


def odometry(s: Sample, frames: Frames = Frames()) -> dict[str, Any]:
    """nav_msgs/msg/Odometry: pose in ``odom``, twist in ``base_link``."""
    t = s.twist
    return {
        "header": _header(s.stamp_ns, frames.odom),
        "child_frame_id": frames.base,
        "pose": {"pose": _pose(s.pose), "covariance": _diagonal(POSE_VARIANCE)},
        "twist": {"twist": {"linear": _vector(t.vx, t.vy), "angular": _vector(z=t.wz)},
                  "covariance": _diagonal(TWIST_VARIANCE)},
    }


def transforms(s: Sample, frames: Frames = Frames()) -> dict[str, Any]:
    """tf2_msgs/msg/TFMessage: the one transform odom -> base_link."""
    p = s.pose
    return {"transforms": [{
        "header": _header(s.stamp_ns, frames.odom),
        "child_frame_id": frames.base,
        "transform": {"translation": _vector(p.x, p.y), "rotation": yaw_quaternion(p.theta)},
    }]}


def pose_stamped(ns: int, pose: Pose2D, frame: str) -> dict[str, Any]:
    """geometry_msgs/msg/PoseStamped (the 3D panel draws it as an arrow)."""
    return {"header": _header(ns, frame), "pose": _pose(pose)}


def joint_name(index: int) -> str:
    return f"wheel_{index}_joint"


def joint_states(s: Sample, wheel_radius: Sequence[float | None]) -> dict[str, Any] | None:
    """sensor_msgs/msg/JointState, one revolute joint per wheel: angle (rad) and angular
    speed (rad/s) from rim travel and rim speed. None when a wheel's radius is unknown
    (the config gave scales instead of gear ratio, encoder and radius)."""
    radii = [wheel_radius[w.index] if w.index < len(wheel_radius) else None for w in s.wheels]
    if not radii or any(r is None or r <= 0 for r in radii):
        return None
    return {
        "header": _header(s.stamp_ns, ""),
        "name": [joint_name(w.index) for w in s.wheels],
        "position": [w.travel / r for w, r in zip(s.wheels, radii, strict=True)],  # type: ignore[operator]
        "velocity": [w.actual_speed / r for w, r in zip(s.wheels, radii, strict=True)],  # type: ignore[operator]
        "effort": [],
    }


def _kv(key: str, value: Any) -> dict[str, str]:
    if isinstance(value, float):
        text = f"{value:.6g}"
    elif value is None:
        text = ""
    else:
        text = str(value)
    return {"key": key, "value": text}


def wheel_level(w: WheelState) -> int:
    if not w.online or w.fault or w.state in (State.FAULT, State.FAULT_REACTION_ACTIVE):
        return ERROR
    if w.stale:
        return STALE
    if w.error or w.state is not State.OPERATION_ENABLED:
        return WARN
    return OK


def diagnostics(s: Sample, prefix: str = "omnican") -> dict[str, Any]:
    """diagnostic_msgs/msg/DiagnosticArray: one status per wheel (drive state, faults with
    their EMCY text) and one for the base (loop rate, bus load, why it is stopped)."""
    statuses = []
    for w in s.wheels:
        node = f"node {w.node_id}" + (f" axis {w.axis}" if w.axis else "")
        level = wheel_level(w)
        message = ("offline (no heartbeat)" if not w.online
                   else w.fault or w.error or str(w.state))
        statuses.append({
            "level": level,
            "name": f"{prefix}: wheel {w.index} ({node})",
            "message": message,
            "hardware_id": f"canopen node {w.node_id}",
            "values": [_kv("state", str(w.state)),
                       _kv("statusword", f"0x{w.statusword:04X}" if w.statusword is not None
                           else None),
                       _kv("mode", w.mode),
                       _kv("target_speed_m_s", w.target_speed),
                       _kv("actual_speed_m_s", w.actual_speed),
                       _kv("travel_m", w.travel),
                       _kv("online", w.online),
                       _kv("fault", w.fault),
                       _kv("error", w.error)],
        })
    st = s.status
    if st.stopped_reason:
        level, message = ERROR, f"stopped: {st.stopped_reason}"
    elif st.bus_error or not st.bus_up:
        level, message = ERROR, f"bus down: {st.bus_error or 'reopening'}"
    elif not st.enabled:
        level, message = WARN, "not enabled"
    elif st.warnings:
        level, message = WARN, "; ".join(st.warnings)
    else:
        level, message = OK, "running"
    statuses.append({
        "level": level,
        "name": f"{prefix}: base",
        "message": message,
        "hardware_id": "omnican",
        "values": [_kv("enabled", st.enabled),
                   _kv("stopped_reason", st.stopped_reason),
                   _kv("loop_hz", st.loop_hz),
                   _kv("late_fraction", st.late_fraction),
                   _kv("cycles", st.cycles),
                   _kv("bus_load", st.bus_load),
                   _kv("bus_bits_per_s", st.bus_bits_per_s),
                   _kv("bus_error", st.bus_error),
                   _kv("bus_up", st.bus_up),
                   _kv("command_age_s", st.command_age_s)],
    })
    return {"header": _header(s.stamp_ns, ""), "status": statuses}


# ------------------------------------------------------------------ JSON channels


def json_time(ns: int) -> dict[str, int]:
    """Foxglove's JSON time (sec, nsec)."""
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def _twist_json(t: Twist) -> dict[str, float]:
    return {"vx": t.vx, "vy": t.vy, "wz": t.wz}


def pose2d(ns: int, p: Pose2D) -> dict[str, Any]:
    """The 2D pose as numbers to plot: theta continuous (rad), heading wrapped (deg)."""
    return {"timestamp": json_time(ns), "x": p.x, "y": p.y, "theta": p.theta,
            "heading_deg": math.degrees(p.heading)}


def twist(s: Sample) -> dict[str, Any]:
    """Commanded (applied after the limits) against measured body velocity."""
    out: dict[str, Any] = {"timestamp": json_time(s.stamp_ns), "command": _twist_json(s.command),
                           "measured": _twist_json(s.twist)}
    if s.true_twist is not None:
        out["true"] = _twist_json(s.true_twist)
    return out


def wheels(s: Sample) -> dict[str, Any]:
    return {"timestamp": json_time(s.stamp_ns), "wheels": [{
        "index": w.index, "node_id": w.node_id, "axis": w.axis,
        "state": "OFFLINE" if not w.online else str(w.state),
        "statusword": w.statusword if w.statusword is not None else -1,
        "target_speed": w.target_speed, "actual_speed": w.actual_speed, "travel": w.travel,
        "online": w.online, "stale": w.stale,
        "fault": w.fault or "", "error": w.error or "",
    } for w in s.wheels]}


def status(s: Sample) -> dict[str, Any]:
    st = s.status
    return {"timestamp": json_time(s.stamp_ns), "enabled": st.enabled,
            "state": "STOPPED" if st.stopped_reason else "RUNNING" if st.enabled else "STARTING",
            "stopped_reason": st.stopped_reason or "", "loop_hz": st.loop_hz,
            "late_fraction": st.late_fraction, "cycles": st.cycles,
            "bus_load": st.bus_load if st.bus_load is not None else -1.0,
            "bus_bits_per_s": st.bus_bits_per_s, "bus_error": st.bus_error or "",
            "bus_up": st.bus_up,
            "command_age_s": min(st.command_age_s, 1e9)}


_NUM = {"type": "number"}
_STR = {"type": "string"}
_INT = {"type": "integer"}
_BOOL = {"type": "boolean"}
_TIME = {"type": "object", "properties": {"sec": _INT, "nsec": _INT}}
_TWIST = {"type": "object", "properties": {"vx": _NUM, "vy": _NUM, "wz": _NUM}}


def _object(title: str, **props: Any) -> dict[str, Any]:
    return {"title": title, "type": "object", "properties": {"timestamp": _TIME, **props}}


#: JSON schema of each JSON message kind (Foxglove wants one per channel).
JSON_SCHEMAS: dict[str, dict[str, Any]] = {
    "omnican.Pose2D": _object("omnican.Pose2D", x=_NUM, y=_NUM, theta=_NUM, heading_deg=_NUM),
    "omnican.Twist": _object("omnican.Twist", command=_TWIST, measured=_TWIST, true=_TWIST),
    "omnican.Wheels": _object("omnican.Wheels", wheels={"type": "array", "items": {
        "type": "object", "properties": {
            "index": _INT, "node_id": _INT, "axis": _INT, "state": _STR, "statusword": _INT,
            "target_speed": _NUM, "actual_speed": _NUM, "travel": _NUM, "online": _BOOL,
            "stale": _BOOL, "fault": _STR, "error": _STR}}}),
    "omnican.Status": _object("omnican.Status", enabled=_BOOL, state=_STR, stopped_reason=_STR,
                              loop_hz=_NUM, late_fraction=_NUM, cycles=_INT, bus_load=_NUM,
                              bus_bits_per_s=_NUM, bus_error=_STR, bus_up=_BOOL,
                              command_age_s=_NUM),
}


# ------------------------------------------------------------------ the topics

ROS2, JSON = "ros2", "json"

#: topic -> (schema name, kind): what the live view publishes and a recording holds.
TOPICS: dict[str, tuple[str, str]] = {
    "/odom": ("nav_msgs/msg/Odometry", ROS2),
    "/tf": ("tf2_msgs/msg/TFMessage", ROS2),
    "/joint_states": ("sensor_msgs/msg/JointState", ROS2),
    "/diagnostics": ("diagnostic_msgs/msg/DiagnosticArray", ROS2),
    "/pose2d": ("omnican.Pose2D", JSON),
    "/twist": ("omnican.Twist", JSON),
    "/wheels": ("omnican.Wheels", JSON),
    "/status": ("omnican.Status", JSON),
    "/sim/true_pose": ("geometry_msgs/msg/PoseStamped", ROS2),
    "/sim/pose2d": ("omnican.Pose2D", JSON),
}
#: raw CAN frames, named as ROS 2's socketcan bridge names them (received / sent by us)
CAN_RX, CAN_TX = "/from_can_bus", "/to_can_bus"
CAN_FRAME = "can_msgs/msg/Frame"


def messages(s: Sample, frames: Frames = Frames(),
             wheel_radius: Sequence[float | None] = ()) -> list[tuple[str, dict[str, Any]]]:
    """(topic, message) for every state topic of one sample."""
    out: list[tuple[str, dict[str, Any]]] = [
        ("/odom", odometry(s, frames)),
        ("/tf", transforms(s, frames)),
        ("/diagnostics", diagnostics(s)),
        ("/pose2d", pose2d(s.stamp_ns, s.pose)),
        ("/twist", twist(s)),
        ("/wheels", wheels(s)),
        ("/status", status(s)),
    ]
    joints = joint_states(s, wheel_radius)
    if joints is not None:
        out.append(("/joint_states", joints))
    if s.true_pose is not None:
        out.append(("/sim/true_pose", pose_stamped(s.stamp_ns, s.true_pose, frames.odom)))
        out.append(("/sim/pose2d", pose2d(s.stamp_ns, s.true_pose)))
    return out


def can_frame(timestamp_s: float, can_id: int, data: bytes, *, extended: bool = False,
              remote: bool = False, error: bool = False, channel: str = "") -> dict[str, Any]:
    """can_msgs/msg/Frame (8 data bytes, zero-padded; ``dlc`` says how many count)."""
    ns = round(timestamp_s * 1e9)
    payload = bytes(data[:8])
    return {"header": _header(ns, channel), "id": can_id, "is_rtr": remote,
            "is_extended": extended, "is_error": error, "dlc": len(payload),
            "data": list(payload.ljust(8, b"\0"))}
