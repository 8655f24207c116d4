"""Every message a front end publishes about the base, built from one
:class:`TelemetrySample`.

Pure: a sample in, plain values out. ROS 2 messages (``nav_msgs/msg/Odometry``,
``tf2_msgs/msg/TFMessage``, ``sensor_msgs/msg/JointState``,
``diagnostic_msgs/msg/DiagnosticArray``, ``sensor_msgs/msg/BatteryState``,
``geometry_msgs/msg/PoseStamped``, ``nav_msgs/msg/Path``, ``can_msgs/msg/Frame``) are
nested dicts with the
message's field names; the rest are JSON objects with a JSON schema each (Foxglove's
plot and state-transition panels read any field of them). The ROS 2 bridge, the live
view and the MCAP recorder serialize these and build nothing of their own, so they say
the same thing at the same moment.

Frames follow REP-103/REP-105: ``odom`` is the fixed odometry frame, ``base_link`` the
body; twists are in the body frame. SI units throughout. Stamps are the sample's: the
time of the clock the base runs on (wall time in real time, the simulated clock's under
``--fast``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from omnican.chassis.state import ChassisStatus, WheelState
from omnican.core.kinematics import Twist
from omnican.core.odometry import Pose2D
from omnican.plan.health_fields import HEALTH_FIELDS
from omnican.protocol.cia402 import State
from omnican.telemetry.fused import FUSED_TOPICS, FUSION_SCHEMA
from omnican.telemetry.settings import TelemetrySettings

# diagnostic_msgs/msg/DiagnosticStatus levels
OK, WARN, ERROR, STALE = 0, 1, 2, 3
LEVEL_NAMES = {OK: "OK", WARN: "WARN", ERROR: "ERROR", STALE: "STALE"}
#: Bus load above this fraction of the bitrate is a warning.
BUS_LOAD_WARN = 0.7
#: What the drives report that varies over time (not a register): the /wheels topic's
#: numbers, each absent when the drive does not give it.
_SERIES = tuple(f for f in HEALTH_FIELDS if not f.register)


@dataclass(frozen=True)
class TelemetrySample:
    """The base at one control cycle, stamped: what every message of it is made from.
    ``stamp_ns``: ns since the epoch on the base's clock. Without a base (the simulator
    alone) only the truth is set."""

    stamp_ns: int
    pose: Pose2D | None
    twist: Twist | None  # measured, body frame
    command: Twist | None  # applied this cycle (after the limits), body frame
    wheels: tuple[WheelState, ...]
    status: ChassisStatus | None
    true_pose: Pose2D | None = None  # the simulator's ground truth
    true_twist: Twist | None = None
    fused: tuple[float, float, float, float, float, float, float, bool, bool] | None = None  # IMU


# ------------------------------------------------------------------ pieces


def stamp(ns: int) -> dict[str, int]:
    """builtin_interfaces/msg/Time of a time in ns since the epoch."""
    return {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}


def json_time(ns: int) -> dict[str, int]:
    """Foxglove's JSON time (sec, nsec)."""
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def yaw_quaternion(theta: float) -> dict[str, float]:
    """A rotation of ``theta`` about z."""
    half = 0.5 * theta
    return {"x": 0.0, "y": 0.0, "z": math.sin(half), "w": math.cos(half)}


def quaternion_yaw(x: float, y: float, z: float, w: float) -> float:
    """The yaw (rotation about z) of a quaternion, in (-pi, pi]."""
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def _vector(x: float = 0.0, y: float = 0.0, z: float = 0.0) -> dict[str, float]:
    return {"x": x, "y": y, "z": z}


def _header(ns: int, frame: str) -> dict[str, Any]:
    return {"stamp": stamp(ns), "frame_id": frame}


def _pose(p: Pose2D) -> dict[str, Any]:
    return {"position": _vector(p.x, p.y), "orientation": yaw_quaternion(p.theta)}


# ------------------------------------------------------------------ ROS 2 messages


def odometry(s: TelemetrySample, settings: TelemetrySettings, pose_covariance: Sequence[float],
             twist_covariance: Sequence[float]) -> dict[str, Any]:
    """nav_msgs/msg/Odometry: pose in the odom frame, twist in the body frame, with the
    dead-reckoning covariances (:mod:`omnican.telemetry.covariance`)."""
    assert s.pose is not None and s.twist is not None
    t = s.twist
    return {
        "header": _header(s.stamp_ns, settings.odom_frame),
        "child_frame_id": settings.base_frame,
        "pose": {"pose": _pose(s.pose), "covariance": list(pose_covariance)},
        "twist": {"twist": {"linear": _vector(t.vx, t.vy), "angular": _vector(z=t.wz)},
                  "covariance": list(twist_covariance)},
    }


def transforms(s: TelemetrySample, settings: TelemetrySettings) -> dict[str, Any]:
    """tf2_msgs/msg/TFMessage: the one transform odom -> base_link (/odom's pose)."""
    assert s.pose is not None
    p = s.pose if s.fused is None else Pose2D(*s.fused[:3])
    return {"transforms": [{
        "header": _header(s.stamp_ns, settings.odom_frame),
        "child_frame_id": settings.base_frame,
        "transform": {"translation": _vector(p.x, p.y), "rotation": yaw_quaternion(p.theta)},
    }]}


def pose_stamped(ns: int, pose: Pose2D, frame: str) -> dict[str, Any]:
    """geometry_msgs/msg/PoseStamped (the 3D panel draws it as an arrow)."""
    return {"header": _header(ns, frame), "pose": _pose(pose)}


def path(ns: int, points: Sequence[tuple[int, Pose2D]], frame: str) -> dict[str, Any]:
    """nav_msgs/msg/Path of stamped poses (the 3D panel draws it as a line)."""
    return {"header": _header(ns, frame),
            "poses": [pose_stamped(t, p, frame) for t, p in points]}


def joint_states(s: TelemetrySample, settings: TelemetrySettings) -> dict[str, Any] | None:
    """sensor_msgs/msg/JointState, one revolute joint per wheel (the configured names):
    angle (rad) and angular speed (rad/s) from rim travel and rim speed, positive in the
    wheel's drive direction. None when the wheel radius is unknown."""
    radii = settings.wheel_radii
    if radii is None or len(radii) != len(s.wheels):
        return None
    return {
        "header": _header(s.stamp_ns, ""),
        "name": [settings.joint_names[w.index] for w in s.wheels],
        "position": [w.travel / r for w, r in zip(s.wheels, radii, strict=True)],
        "velocity": [w.actual_speed / r for w, r in zip(s.wheels, radii, strict=True)],
        "effort": [],
    }


def _text(value: Any, spec: str = ".6g") -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return format(value, spec)
    return str(value)


def _status(level: int, name: str, message: str, hardware_id: str,
            values: Sequence[tuple[str, Any]]) -> dict[str, Any]:
    return {"level": level, "name": name, "message": message, "hardware_id": hardware_id,
            "values": [{"key": k, "value": _text(v)} for k, v in values]}


def chassis_status(st: ChassisStatus, prefix: str) -> dict[str, Any]:
    """The base as a whole: enabled, why it is held stopped, loop rate, command age."""
    reason = st.stopped_reason
    if reason:
        level, message = ERROR, f"stopped: {reason} (recover to clear)"
    elif not st.enabled:
        level, message = WARN, "drives not enabled"
    elif st.warnings:
        level, message = WARN, "; ".join(st.warnings)
    else:
        level, message = OK, "enabled"
    values: list[tuple[str, Any]] = [
        ("enabled", st.enabled), ("stopped_reason", reason), ("loop_hz", st.loop_hz),
        ("late_fraction", st.late_fraction), ("cycles", st.cycles),
        ("command_age_s", min(st.command_age_s, 1e9)), ("estop", st.estop),
        ("battery_v", st.battery_v), ("battery", st.battery)]
    values += [(f"warning_{i}", w) for i, w in enumerate(st.warnings)]
    # No hardware id: Foxglove shows "hardware_id: name", and the name says it all.
    return _status(level, f"{prefix}: chassis", message, "", values)


def bus_status(st: ChassisStatus, prefix: str, channel: str) -> dict[str, Any]:
    """The CAN bus: up or down, load, bit rate, the last error."""
    load, error = st.bus_load, st.bus_error
    controller = _controller_text(st)
    if not st.bus_up:
        level, message = ERROR, f"bus down: {error or 'reopening'}"
    elif st.can_state == "bus-off":
        level, message = ERROR, f"CAN {controller}"
    elif st.can_state in ("error-warning", "error-passive"):
        level, message = WARN, f"CAN {controller}"
    elif load is not None and load > BUS_LOAD_WARN:
        level, message = WARN, f"bus load {load:.0%}"
    elif load is not None:
        level, message = OK, f"bus load {load:.0%}"
    else:  # e.g. a virtual bus (--sim): the traffic is known, its share of nothing
        level, message = OK, f"{st.bus_bits_per_s / 1000:.1f} kbit/s (no bitrate set)"
    return _status(level, f"{prefix}: CAN bus", message, channel or "can",
                   [("bus_up", st.bus_up), ("bus_load", load),
                    ("bus_bits_per_s", st.bus_bits_per_s), ("bus_error", error),
                    ("controller_state", st.can_state), ("tx_error_counter", st.can_tx_errors),
                    ("rx_error_counter", st.can_rx_errors),
                    ("error_frames", st.can_error_frames)])


def _controller_text(st: ChassisStatus) -> str:
    """e.g. ``error-passive (tx 130, rx 0)``."""
    counters = (f" (tx {st.can_tx_errors}, rx {st.can_rx_errors})"
                if st.can_tx_errors is not None and st.can_rx_errors is not None else "")
    return f"{st.can_state}{counters}"


def wheel_level(w: WheelState) -> tuple[int, str]:
    """A wheel's diagnostic level and message."""
    if w.fault or w.state in (State.FAULT, State.FAULT_REACTION_ACTIVE):
        return ERROR, f"fault: {w.fault or w.state}"
    if not w.online:
        return ERROR, "offline (no heartbeat)"
    if w.error:
        return ERROR, w.error
    if w.state is not State.OPERATION_ENABLED:
        return WARN, str(w.state)
    if w.stale:
        return WARN, "no fresh encoder sample"
    return OK, str(w.state)


def wheel_status(w: WheelState, prefix: str, joint: str) -> dict[str, Any]:
    """One wheel's drive: CiA 402 state, faults (with the EMCY text), speeds, travel,
    and every value the drive reports (omnican.plan.health_fields)."""
    level, message = wheel_level(w)
    hardware = f"canopen node {w.node_id}" + (f" axis {w.axis}" if w.axis else "")
    return _status(level, f"{prefix}: wheel {w.index}", message, hardware, [
        ("joint", joint), ("state", str(w.state)),
        ("statusword", f"0x{w.statusword:04X}" if w.statusword is not None else None),
        ("mode", w.mode), ("target_speed_m_s", w.target_speed),
        ("actual_speed_m_s", w.actual_speed), ("travel_m", w.travel), ("online", w.online),
        ("stale", w.stale), ("fault", w.fault), ("error", w.error),
        *((f.name, f.text(getattr(w, f.name))) for f in HEALTH_FIELDS)])


def diagnostics(s: TelemetrySample, settings: TelemetrySettings) -> dict[str, Any]:
    """diagnostic_msgs/msg/DiagnosticArray: the base, the CAN bus, one status per wheel."""
    assert s.status is not None
    prefix = settings.prefix
    statuses = [chassis_status(s.status, prefix),
                bus_status(s.status, prefix, settings.channel)]
    statuses += [wheel_status(w, prefix, settings.joint_names[w.index]) for w in s.wheels]
    return {"header": _header(s.stamp_ns, ""), "status": statuses}


#: sensor_msgs/msg/BatteryState constants
POWER_SUPPLY_STATUS_UNKNOWN = 0
POWER_SUPPLY_HEALTH_UNKNOWN, POWER_SUPPLY_HEALTH_GOOD, POWER_SUPPLY_HEALTH_DEAD = 0, 1, 3
POWER_SUPPLY_TECHNOLOGY_UNKNOWN = 0


def battery_state(s: TelemetrySample, settings: TelemetrySettings) -> dict[str, Any] | None:
    """sensor_msgs/msg/BatteryState of the DC link the drives measure (the median of
    theirs); None when no drive reports one. What the drives cannot know (the battery's
    current, charge, temperature) is NaN, as the message says for unmeasured values;
    health is GOOD, or DEAD below [power]'s cutoff (UNKNOWN without a [power] table)."""
    st = s.status
    if st is None or st.battery_v is None:
        return None
    nan = math.nan
    health = {None: POWER_SUPPLY_HEALTH_UNKNOWN, "cutoff": POWER_SUPPLY_HEALTH_DEAD}.get(
        st.battery, POWER_SUPPLY_HEALTH_GOOD)
    return {"header": _header(s.stamp_ns, settings.base_frame), "voltage": st.battery_v,
            "temperature": nan, "current": nan, "charge": nan, "capacity": nan,
            "design_capacity": nan, "percentage": nan,
            "power_supply_status": POWER_SUPPLY_STATUS_UNKNOWN,
            "power_supply_health": health,
            "power_supply_technology": POWER_SUPPLY_TECHNOLOGY_UNKNOWN, "present": True,
            "cell_voltage": [], "cell_temperature": [],
            "location": "DC link (the drives' median)", "serial_number": ""}


def diagnostics_signature(message: dict[str, Any]) -> tuple[tuple[int, str], ...]:
    """What a change of is published at once: each status's level and message."""
    return tuple((st["level"], st["message"]) for st in message["status"])


# ------------------------------------------------------------------ JSON topics


def _twist_json(t: Twist) -> dict[str, float]:
    return {"vx": t.vx, "vy": t.vy, "wz": t.wz}


def pose2d(ns: int, p: Pose2D) -> dict[str, Any]:
    """The 2D pose as numbers to plot: theta continuous (rad), heading wrapped (deg)."""
    return {"timestamp": json_time(ns), "x": p.x, "y": p.y, "theta": p.theta,
            "heading_deg": math.degrees(p.heading)}


def twist(s: TelemetrySample) -> dict[str, Any]:
    """Commanded (applied after the limits) against measured body velocity."""
    assert s.command is not None and s.twist is not None
    out: dict[str, Any] = {"timestamp": json_time(s.stamp_ns), "command": _twist_json(s.command),
                           "measured": _twist_json(s.twist)}
    if s.true_twist is not None:
        out["true"] = _twist_json(s.true_twist)
    return out


def _given(out: dict[str, Any], **maybe: Any) -> dict[str, Any]:
    """``out`` with the fields of ``maybe`` that are not None: a reading a drive or the bus
    does not give is absent from the message (Foxglove plots a gap; JSON has no NaN and the
    app's schema parser no type unions)."""
    out.update((k, v) for k, v in maybe.items() if v is not None)
    return out


def wheels(s: TelemetrySample) -> dict[str, Any]:
    """Each wheel's drive; ``statusword`` and what the drive reports (``current_a``,
    ``torque_pct``, ``voltage_v``, ``temperature_c``: omnican.plan.health_fields, but for a
    register) only when the drive gives them."""
    return {"timestamp": json_time(s.stamp_ns), "wheels": [_given({
        "index": w.index, "node_id": w.node_id, "axis": w.axis,
        "state": "OFFLINE" if not w.online else str(w.state),
        "target_speed": w.target_speed, "actual_speed": w.actual_speed, "travel": w.travel,
        "online": w.online, "stale": w.stale,
        "fault": w.fault or "", "error": w.error or ""},
        statusword=w.statusword, **{f.name: getattr(w, f.name) for f in _SERIES})
        for w in s.wheels]}


def status(s: TelemetrySample) -> dict[str, Any]:
    """The base as a whole; ``bus_load`` (a fraction of the bitrate) only when the
    bitrate is known, the CAN error counters and ``battery_v`` only when measured."""
    st = s.status
    assert st is not None
    return _given({
        "timestamp": json_time(s.stamp_ns), "enabled": st.enabled,
        "state": "STOPPED" if st.stopped_reason else "RUNNING" if st.enabled else "STARTING",
        "stopped_reason": st.stopped_reason or "", "loop_hz": st.loop_hz,
        "late_fraction": st.late_fraction, "cycles": st.cycles,
        "bus_bits_per_s": st.bus_bits_per_s, "bus_error": st.bus_error or "",
        "bus_up": st.bus_up, "command_age_s": min(st.command_age_s, 1e9),
        "can_state": st.can_state or "", "estop": st.estop, "warnings": list(st.warnings)},
        bus_load=st.bus_load, can_tx_errors=st.can_tx_errors, can_rx_errors=st.can_rx_errors,
        battery_v=st.battery_v)


# What Foxglove's JSON schema parser accepts (the app's parseJsonSchema, as in Foxglove
# Studio and Lichtblick): one "type" per field, of boolean, string, number, integer, object
# or array; no "null", no unions. A field a message may leave out is simply not required.
_NUM = {"type": "number"}
_STR = {"type": "string"}
_INT = {"type": "integer"}
_BOOL = {"type": "boolean"}
_TIME = {"type": "object", "properties": {"sec": _INT, "nsec": _INT}}
_TWIST = {"type": "object", "properties": {"vx": _NUM, "vy": _NUM, "wz": _NUM}}


def _object(title: str, **props: Any) -> dict[str, Any]:
    return {"title": title, "type": "object", "properties": {"timestamp": _TIME, **props}}


def _maybe(schema: dict[str, Any], why: str) -> dict[str, Any]:
    """A field that is absent when there is no reading."""
    return {**schema, "description": f"absent when {why}"}


#: Each reading of what a drive reports rides on the /wheels messages made while it is
#: fresh (a reading a few times a second, chassis.health_rate_hz; /wheels at the state
#: rate): a message after it went stale, or before the first, has no field for it. Left
#: out rather than repeated (a repeated value would claim a reading there was not) or
#: null (Foxglove's schema parser takes no unions): a plot reads the messages that have
#: the field, as Foxglove's Plot panel does (it skips a message without the path).
_READING = ("the drive does not give it, or no fresh reading of it came (a few a second: "
            "chassis.health_rate_hz); a plot of it reads the messages that have it and "
            "skips the others")

#: JSON schema of each JSON message kind (Foxglove wants one per channel).
JSON_SCHEMAS: dict[str, dict[str, Any]] = {
    "omnican.Pose2D": _object("omnican.Pose2D", x=_NUM, y=_NUM, theta=_NUM, heading_deg=_NUM),
    "omnican.Twist": _object("omnican.Twist", command=_TWIST, measured=_TWIST,
                             true=_maybe(_TWIST, "there is no simulator")),
    "omnican.Wheels": _object("omnican.Wheels", wheels={"type": "array", "items": {
        "type": "object", "properties": {
            "index": _INT, "node_id": _INT, "axis": _INT, "state": _STR,
            "statusword": _maybe(_INT, "no statusword came yet"),
            "target_speed": _NUM, "actual_speed": _NUM, "travel": _NUM, "online": _BOOL,
            "stale": _BOOL, "fault": _STR, "error": _STR,
            **{f.name: _maybe(_NUM, _READING) for f in _SERIES}}}}),
    "omnican.Status": _object(
        "omnican.Status", enabled=_BOOL, state=_STR, stopped_reason=_STR, loop_hz=_NUM,
        late_fraction=_NUM, cycles=_INT,
        bus_load=_maybe(_NUM, "the bitrate is unknown (a fraction of it; under --sim the "
                        "simulated bus has the config's, or 500 kbit/s)"),
        bus_bits_per_s=_NUM, bus_error=_STR, bus_up=_BOOL, command_age_s=_NUM,
        can_state=_STR, can_tx_errors=_maybe(_INT, "the CAN controller does not say"),
        can_rx_errors=_maybe(_INT, "the CAN controller does not say"), estop=_BOOL,
        battery_v=_maybe(_NUM, "no drive measures its DC link"),
        warnings={"type": "array", "items": _STR}),
    "omnican.Fusion": FUSION_SCHEMA,
}


# ------------------------------------------------------------------ the topics

ROS2, JSON = "ros2", "json"

#: topic -> (schema name, kind): the state topics every front end may carry.
TOPICS: dict[str, tuple[str, str]] = {
    "/odom": ("nav_msgs/msg/Odometry", ROS2),  # fused with an IMU where one is attached
    **FUSED_TOPICS,  # /odometry/filtered, /odom/wheels...: telemetry/fused.py
    # The odometry's pose and the path so far, as Foxglove's 3D panel draws them (it does
    # not draw nav_msgs/msg/Odometry).
    "/odom/pose": ("geometry_msgs/msg/PoseStamped", ROS2),
    "/odom/path": ("nav_msgs/msg/Path", ROS2),
    "/tf": ("tf2_msgs/msg/TFMessage", ROS2),
    "/joint_states": ("sensor_msgs/msg/JointState", ROS2),
    "/diagnostics": ("diagnostic_msgs/msg/DiagnosticArray", ROS2),
    "/pose2d": ("omnican.Pose2D", JSON),
    "/twist": ("omnican.Twist", JSON),
    "/wheels": ("omnican.Wheels", JSON),
    "/status": ("omnican.Status", JSON),
    "/battery_state": ("sensor_msgs/msg/BatteryState", ROS2),
    "/sim/true_pose": ("geometry_msgs/msg/PoseStamped", ROS2),
    "/sim/pose2d": ("omnican.Pose2D", JSON),
}
#: raw CAN frames, named as ROS 2's socketcan bridge names them (received / sent by us)
CAN_RX, CAN_TX = "/from_can_bus", "/to_can_bus"
CAN_FRAME = "can_msgs/msg/Frame"
#: each frame the base's DBC describes, decoded: /can/<message name>
CAN_DECODED_PREFIX = "/can/"


def can_frame(timestamp_s: float, can_id: int, data: bytes, *, extended: bool = False,
              remote: bool = False, error: bool = False, channel: str = "") -> dict[str, Any]:
    """can_msgs/msg/Frame (8 data bytes, zero-padded; ``dlc`` says how many count)."""
    ns = round(timestamp_s * 1e9)
    payload = bytes(data[:8])
    return {"header": _header(ns, channel), "id": can_id, "is_rtr": remote,
            "is_extended": extended, "is_error": error, "dlc": len(payload),
            "data": list(payload.ljust(8, b"\0"))}
