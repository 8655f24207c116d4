"""Robot configuration: TOML -> validated, frozen dataclasses.

The schema (every key, its type, default and meaning) is the table :data:`SCHEMA`;
README's configuration reference is checked against it by a test. Every problem
is a :class:`ConfigError` whose message names the key, e.g.
``robot.toml: wheel[2].node_id: must be 1-127, got 200``.

No I/O beyond reading the TOML file and parsing the EDS files it names.
"""

from __future__ import annotations

import difflib
import math
import sys
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from omnican.core.kinematics import LAYOUTS, OmniKinematics
from omnican.core.limits import (
    MAX_ACCEL_SENSE,
    MAX_SPEED_SENSE,
    MAX_STOP_S,
    VelocityLimits,
    stop_decel_floor,
    top_speeds,
)
from omnican.errors import ConfigError
from omnican.protocol import heartbeat
from omnican.protocol.cia402 import Mode

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib  # type: ignore[import-not-found,unused-ignore]

#: The bundled generic wheel-drive EDS (inside the installed package).
WHEEL_EDS: Path = Path(__file__).resolve().parents[1] / "eds" / "omnican_wheel.eds"

#: Velocity units of a drive's target/actual velocity, as multiples of motor rev/s.
VELOCITY_UNITS: dict[str, float] = {
    "counts/s": 0.0,  # special: encoder counts per second
    "rpm": 1.0 / 60.0,
    "0.1rpm": 1.0 / 600.0,
    "0.01rpm": 1.0 / 6000.0,
    "rev/s": 1.0,
}


@dataclass(frozen=True)
class Key:
    """One configuration key: its TOML type(s), default (None: none, or see ``required``
    and ``scaled``) and meaning. The one place a default is written: the dataclasses the
    tables parse into take theirs from here (:func:`schema_defaults`)."""

    types: tuple[type, ...]
    default: Any
    doc: str
    required: bool = False
    #: (other key, factor): left out, the key is ``factor`` x the other key's value.
    scaled: tuple[str, float] | None = None
    #: (lowest, highest) a number may be, both allowed; None: any finite number. Beyond
    #: it a value has no physical sense for a base (or overflows what it feeds): refused.
    range: tuple[float, float] | None = None
    #: inf is allowed too (no such limit).
    inf_ok: bool = False
    #: ``range`` bounds the magnitude; the sign is free (a polarity), zero is not.
    signed: bool = False

    def range_text(self) -> str:
        """The range as an error message says it: "0.001-60", "-720 to 720"."""
        if self.range is None:
            return "a finite number"
        lo, hi = (_bound_text(x) for x in self.range)
        text = f"{lo}-{hi}" if self.range[0] >= 0 else f"{lo} to {hi}"
        if self.signed:
            text = f"{lo} to {hi} in magnitude (either sign)"
        return text + (" or inf" if self.inf_ok else "")


def _bound_text(x: float) -> str:
    """A range's bound as people write it: 1000000, not 1e+06; 1e+12 stays."""
    return str(int(x)) if x == int(x) and abs(x) < 1e7 else f"{x:g}"


def _scaled(types: tuple[type, ...], doc: str, of: str, factor: float,
            range: tuple[float, float] | None = None) -> Key:
    """A key whose default is ``factor`` x key ``of`` of the same table (said in its doc)."""
    return Key(types, None, f"{doc}; default {factor:g} x {of}", scaled=(of, factor),
               range=range)


# The ranges of the numeric keys (Key.range): what a base can physically have, wide
# enough for any real robot. Speeds and accelerations share omnican.core.limits' bounds of
# sense (a command beyond them is refused too); times go from a millisecond to what a
# person would still wait for; a stop deceleration also has a floor that depends on the
# speed limits (omnican.core.limits.MAX_STOP_S, checked once the wheels are known).
_SPEED = (0.001, MAX_SPEED_SENSE)
_ACCEL = (0.001, MAX_ACCEL_SENSE)
_DECEL = (0.001, 2 * MAX_ACCEL_SENSE)  # the default is twice the acceleration
_WAIT = (0.01, 60.0)  # s: a CAN round trip and a scheduler's tick fit the lowest
_RATE = (0.01, 5000.0)  # Hz
_SCALE = (1e-6, 1e12)  # units per SI unit, either sign
_ROS_RATE = (0.01, 1000.0)  # Hz, a topic's publish rate


_NUM = (int, float)

#: The highest chassis.rt_priority: Linux's highest SCHED_FIFO priority.
MAX_RT_PRIORITY = 99

#: Values of chassis.pdo_mapping (what omnican.plan.pdo does with each).
PDO_MAPPINGS = ("try", "eds", "sdo")
#: Values of chassis.lifted_wheel (what the health checks do with a wheel off the ground).
LIFTED_WHEEL = ("warn", "stop", "off")

#: [chassis] keys a running base takes while it runs (:meth:`omnican.Chassis.set_limits`,
#: Foxglove's parameters): its velocity limiter's.
LIVE_LIMITS = ("max_speed", "max_angular_speed", "max_accel", "max_angular_accel",
               "stop_decel", "stop_angular_decel", "max_wheel_speed")
_UNLIMITED_OK = ("max_speed", "max_angular_speed")  # inf: no such limit


# Tables a front end reads and checks itself (the base ignores them): [gamepad] is
# omnican.command.gamepad's.
FRONT_END_SECTIONS = ("gamepad",)

#: The keys of the free-form [bus] table that omnican reads itself (the bus load): their
#: type and range (CAN's nominal bitrates run from 10 kbit/s down to what some
#: controllers allow, 1 kbit/s, up to 1 Mbit/s; a CAN FD data phase up to 12 Mbit/s).
BUS_KEYS: dict[str, Key] = {
    "bitrate": Key((int,), None, "bit/s of the bus (nominal)", range=(1000, 1_000_000)),
    "data_bitrate": Key((int,), None, "bit/s of a CAN FD data phase",
                        range=(1000, 12_000_000)),
}

# Section -> key -> spec. The [bus] table is free-form (passed to can.Bus).
SCHEMA: dict[str, dict[str, Key]] = {
    "chassis": {
        "layout": Key((str,), None, "wheel preset: \"b21\" (180, -60, 60 deg) or \"a12\" "
                      "(0, 120, -120 deg); omit and give angle_deg per wheel instead"),
        "base_radius": Key(_NUM, None, "m, base centre to wheel contact point", required=True,
                           range=(0.01, 10.0)),
        "rate_hz": Key(_NUM, 100.0, "control loop and SYNC rate", range=(1.0, 5000.0)),
        "rt_priority": Key((int,), 50, "SCHED_FIFO priority 1-99 of the control loop thread "
                           "(its thread alone) where the process may: root, CAP_SYS_NICE or "
                           "RLIMIT_RTPRIO; elsewhere normal priority and a note; 0: never"),
        "cmd_timeout_s": Key(_NUM, 0.5, "no command for this long -> controlled stop",
                             range=_WAIT),
        "max_wheel_speed": Key(_NUM, 1.0, "m/s at the rim; commands are desaturated to it",
                               range=_SPEED),
        "max_speed": Key(_NUM, math.inf, "m/s, body linear speed (vector norm)", range=_SPEED,
                         inf_ok=True),
        "max_angular_speed": Key(_NUM, math.inf, "rad/s, body angular speed", range=_SPEED,
                                 inf_ok=True),
        "max_accel": Key(_NUM, 1.0, "m/s^2, body linear acceleration", range=_ACCEL),
        "max_angular_accel": Key(_NUM, 3.0, "rad/s^2, body angular acceleration",
                                 range=_ACCEL),
        "stop_decel": _scaled(_NUM, "m/s^2 for a stop command (and every other stop); at "
                              "least the top speed / 2 s", "max_accel", 2.0, _DECEL),
        "stop_angular_decel": _scaled(_NUM, "rad/s^2 for a stop; at least the top angular "
                                      "speed / 2 s", "max_angular_accel", 2.0, _DECEL),
        "mode": Key((str,), None, "\"pv\", \"csv\" or \"vl\"; default: pv, or what 6502h offers"),
        "host_node_id": Key((int,), 127, "node id of this host's heartbeat (0x700 + id)",
                            range=(1, 127)),
        "heartbeat_ms": Key((int,), 100, "heartbeat period of host and drives, ms",
                            range=(1, 65535)),
        "heartbeat_timeout_factor": Key(_NUM, 3.0, "a heartbeat is lost after this many "
                                        "periods and half a period more: that many lost in a "
                                        "row stop the base, one fewer never does",
                                        range=(1.0, 100.0)),
        "sdo_timeout_s": Key(_NUM, 0.3, "one SDO request's wait for its answer", range=_WAIT),
        "sdo_retries": Key((int,), 3, "an SDO request unanswered within sdo_timeout_s is sent "
                           "again, up to this many times", range=(0, 20)),
        "boot_timeout_s": Key(_NUM, 2.0, "wait for a drive's boot-up after NMT reset",
                              range=(0.1, 60.0)),
        "enable_timeout_s": Key(_NUM, 1.0, "bring a drive to OPERATION ENABLED within this",
                                range=_WAIT),
        "pdo_mapping": Key((str,), "try", "objects an EDS marks not PDO-mappable: \"try\" maps "
                           "them anyway (warning; a drive that refuses runs on its own mapping, "
                           "and what that lacks goes by SDO every cycle), \"eds\" sends them by "
                           "SDO every cycle, \"sdo\" sends targets and positions by SDO every "
                           "cycle"),
        "health_rate_hz": Key(_NUM, 5.0, "how often each drive's current, torque, voltage, "
                              "temperature, error register and e-stop input are read",
                              range=_RATE),
        "tracking_error": Key(_NUM, 0.1, "m/s: a wheel whose measured speed stays this far "
                              "outside what its target was over the last tracking_lag_s "
                              "latches a stop (inf: never)", range=_SPEED, inf_ok=True),
        "tracking_time_s": Key(_NUM, 0.5, "for this long", range=_WAIT),
        "tracking_lag_s": Key(_NUM, 0.3, "how far a wheel's measured speed may lag its target "
                              "(speed window, drive ramp and velocity loop)", range=_WAIT),
        "lifted_wheel": Key((str,), "warn", "a wheel off the ground (or without its roller), "
                            "found from its current against its siblings': \"warn\" (a status "
                            "warning naming it), \"stop\" (a stop naming it) or \"off\""),
    },
    "wheel": {
        "node_id": Key((int,), None, "CANopen node id 1-127", required=True, range=(1, 127)),
        "axis": Key((int,), 0, "axis on a multi-axis drive (0-based)", range=(0, 7)),
        "eds": Key((str,), None, "EDS file (relative to the config file); default: bundled EDS"),
        "velocity_scale": Key(_NUM, None, "drive velocity units per m/s at the rim; sign = "
                              "polarity", range=_SCALE, signed=True),
        "position_scale": Key(_NUM, None, "encoder position units per m of rim travel",
                              range=_SCALE, signed=True),
        "gear_ratio": Key(_NUM, None, "motor turns per wheel turn (instead of the scales)",
                          range=(0.001, 1e5)),
        "encoder_cpr": Key(_NUM, None, "encoder counts per motor turn (instead of the scales)",
                           range=(1.0, 1e9)),
        "wheel_radius": Key(_NUM, None, "m, wheel radius (instead of the scales)",
                            range=(0.001, 10.0)),
        "velocity_unit": Key((str,), "counts/s", "drive velocity unit when deriving the scales: "
                             + ", ".join(VELOCITY_UNITS)),
        "invert": Key((bool,), False, "reverse the wheel's direction (negates both scales)"),
        "angle_deg": Key(_NUM, None, "wheel position angle from +x, CCW (instead of layout)",
                         range=(-720.0, 720.0)),
        "drive_angle_deg": Key(_NUM, None, "drive direction; default angle_deg + 90",
                               range=(-720.0, 720.0)),
        "base_radius": Key(_NUM, None, "m, this wheel's distance from the centre; default "
                           "[chassis] base_radius", range=(0.01, 10.0)),
        "mode": Key((str,), None, "this wheel's mode; default [chassis] mode"),
        "current": Key((str,), "0x6078", "object with the motor current: \"0xIIII:SS\", "
                       "\"0xIIII\" (this axis's copy) or the EDS entry's name; \"\" for none"),
        "current_scale": Key(_NUM, None, "A per unit of current; default: 6078h's per mille "
                             "of the rated current 6075h, read at startup", range=_SCALE,
                             signed=True),
        "torque": Key((str,), "0x6077", "object with the torque, per mille of the rated "
                      "torque; \"\" for none"),
        "voltage": Key((str,), "0x6079", "object with the DC link voltage; \"\" for none"),
        "voltage_scale": Key(_NUM, 0.001, "V per unit of voltage (6079h: mV)", range=_SCALE,
                             signed=True),
        "temperature": Key((str,), None, "object with a temperature (vendor-specific, e.g. "
                           "\"0x2032:01\" or its EDS name); default none"),
        "temperature_scale": Key(_NUM, 1.0, "degC per unit of temperature", range=_SCALE,
                                 signed=True),
        "sdo": Key((list,), None, "vendor settings: [[wheel.sdo]] tables written in "
                   "PRE-OPERATIONAL at every configuration (below)"),
    },
    # One [[wheel.sdo]] table: a setting the drive gets at startup, after a reboot and
    # after the bus comes back.
    "wheel.sdo": {
        "object": Key((str,), None, "\"0xIIII:SS\" or the EDS entry's name", required=True),
        "value": Key((int, float, bool), None, "the value written", required=True),
        "type": Key((str,), None, "u8, u16, u32, i8, i16, i32 or bool; default: the EDS's "
                    "type (which it must match)"),
    },
    # Read by the base when present: a low battery warns, then stops the base.
    "power": {
        "warn_v": Key(_NUM, None, "V: the DC link below this warns (status, diagnostics)",
                      range=(0.1, 2000.0)),
        "cutoff_v": Key(_NUM, None, "V: below this for delay_s, a controlled stop "
                        "(recover() refuses until it is back above cutoff_v + hysteresis_v)",
                        range=(0.1, 2000.0)),
        "hysteresis_v": Key(_NUM, 0.5, "V a warning or cutoff needs to clear",
                            range=(0.0, 100.0)),
        "delay_s": Key(_NUM, 1.0, "below a threshold this long before it counts (a sag "
                       "while accelerating does not)", range=(0.0, 60.0)),
    },
    # An e-stop (or a drive's safe torque off) as a stop reason.
    "estop": {
        "object": Key((str,), "0x60FD", "object with the e-stop: a digital input (60FDh), "
                      "the statusword (0x6041, a drive's STO bit) or a vendor object"),
        "bit": Key((int,), None, "bit of it that shows the e-stop pressed", required=True,
                   range=(0, 31)),
        "active_low": Key((bool,), False, "pressed when the bit is clear (a normally closed "
                          "loop)"),
        "node_id": Key((int,), None, "the drive whose input it is; default every node",
                       range=(1, 127)),
    },
    # Read by `omnican ros2` (omnican/ros2/settings.py checks the values).
    "ros2": {
        "namespace": Key((str,), "", "ROS 2 namespace of the node and its relative topics"),
        "node_name": Key((str,), "omnican", "ROS 2 node name (~/ topics live under it)"),
        "domain_id": Key((int,), None, "DDS domain 0-232; default: ROS_DOMAIN_ID, else 0",
                         range=(0, 232)),
        "cmd_vel_topic": Key((str,), "cmd_vel", "velocity commands in (Twist)"),
        "cmd_vel_stamped": Key((bool,), False, "cmd_vel carries TwistStamped instead of Twist"),
        "cmd_vel_timeout_s": Key(_NUM, None, "no cmd_vel for this long -> stop; default "
                                 "[chassis] cmd_timeout_s", range=_WAIT),
        "odom_topic": Key((str,), "odom", "nav_msgs/Odometry out"),
        "odom_frame": Key((str,), "odom", "frame of the odometry pose"),
        "base_frame": Key((str,), "base_link", "frame of the base (odometry child frame)"),
        "odom_rate_hz": Key(_NUM, 50.0, "odom and tf publish rate", range=_ROS_RATE),
        "publish_tf": Key((bool,), True, "publish the odom -> base_link transform"),
        "tf_topic": Key((str,), "/tf", "tf2_msgs/TFMessage out"),
        "joint_states_topic": Key((str,), "joint_states", "sensor_msgs/JointState out"),
        "joint_states_rate_hz": Key(_NUM, 50.0, "joint_states publish rate", range=_ROS_RATE),
        "joint_names": Key((list,), None, "one joint name per wheel; default wheel_0_joint, "
                           "wheel_1_joint, ..."),
        "wheel_radius": Key(_NUM, None, "m, for joint angles; default the wheels' "
                            "wheel_radius (no joint_states without one)", range=(0.001, 10.0)),
        "diagnostics_topic": Key((str,), "/diagnostics", "diagnostic_msgs/DiagnosticArray out"),
        "diagnostics_rate_hz": Key(_NUM, 1.0, "diagnostics rate (and at once on a change)",
                                   range=_ROS_RATE),
        "battery_state_topic": Key((str,), "battery_state", "sensor_msgs/BatteryState out: the "
                                   "drives' DC link (when they report one)"),
        "battery_state_rate_hz": Key(_NUM, 1.0, "battery_state publish rate", range=_ROS_RATE),
        "recover_topic": Key((str,), "~/recover", "std_msgs/Empty in: clear a latched stop"),
        "odom_slip": Key(_NUM, 0.02, "1-sigma wheel slip per metre rolled, a fraction "
                         "(covariances)", range=(0.0, 0.99)),
        "interface": Key((str,), None, "DDS network interface name or address; default all"),
        "peers": Key((list,), None, "unicast discovery peers (addresses or host names)"),
        "multicast": Key((bool,), True, "DDS multicast discovery"),
    },
    # Read by the live view (--foxglove; omnican/live/settings.py checks the values).
    "foxglove": {
        "control": Key((bool,), False, "drive from Foxglove (Teleop panel, services, "
                       "parameters); --foxglove-control, off: the view only watches"),
        "cmd_vel_topic": Key((str,), "/cmd_vel", "topic Foxglove's Teleop panel publishes "
                             "geometry_msgs/Twist on"),
        "allow_remote": Key((bool,), False, "control on a server that other hosts can reach "
                            "(a host other than loopback); --foxglove-allow-remote"),
        "tls_cert": Key((str,), None, "PEM certificate (relative to the config file): serve "
                        "wss:// (a phone's browser needs it); with tls_key"),
        "tls_key": Key((str,), None, "PEM private key of tls_cert"),
        "origins": Key((list,), None, "web pages (Origin) whose browsers may connect, e.g. "
                       "[\"https://app.foxglove.dev\"], \"*\" any; default Foxglove's app "
                       "(app. and studio.foxglove.dev) and desktop (file://); "
                       "--foxglove-origin adds one"),
        "token": Key((str,), None, "a secret a client must give to drive (ws://host:port/"
                     "?token=...): without it, it may only watch; --foxglove-token"),
    },
    # The simulated base `omnican calibrate --sim` drives, as it really is: kept apart from
    # the [chassis] and [[wheel]] numbers calibration corrects, so it stays the same base.
    "sim": {
        "base_radius": Key(_NUM, None, "m, the simulated base's true base_radius (per-wheel "
                           "base_radius scale with it); default the configured one",
                           range=(0.01, 10.0)),
        "position_scale": Key((*_NUM, list), None, "true encoder counts per m of rim travel "
                              "of the simulated wheels (magnitude): one number for every "
                              "wheel, or one per wheel; default the configured ones",
                              range=_SCALE),
    },
}


def schema_defaults(section: str) -> dict[str, Any]:
    """Key -> default of every key of a :data:`SCHEMA` section (None: required, scaled or
    no value)."""
    return {name: spec.default for name, spec in SCHEMA[section].items()}


def reference_rows() -> list[tuple[str, str, str]]:
    """(key, default, meaning) for every key of :data:`SCHEMA`: README's reference table."""
    rows = []
    for section, keys in SCHEMA.items():
        for name, spec in keys.items():
            d = spec.default
            if spec.required:
                text = "required"
            elif d is None:
                text = "-"
            elif isinstance(d, bool):
                text = str(d).lower()
            elif isinstance(d, str):
                text = f'"{d}"'
            elif isinstance(d, float) and math.isinf(d):
                text = "inf"
            else:
                text = f"{d:g}"
            rows.append((f"{section}.{name}", text, spec.doc))
    from omnican.command.gamepad import TABLE_DEFAULTS, TABLE_KEYS

    rows += [(f"gamepad.{key}", TABLE_DEFAULTS.get(key, "-"), doc)
             for key, doc in TABLE_KEYS.items()]
    return rows


def _field_defaults(section: str, **overrides: Any) -> dict[str, Any]:
    """A section's defaults as the values of its dataclass's fields (a mode named is a
    :class:`Mode`), ``overrides`` applied."""
    out = {**schema_defaults(section), **overrides}
    if out.get("mode") is not None:
        out["mode"] = Mode.from_name(out["mode"])
    return out


_WHEEL = _field_defaults("wheel")


@dataclass(frozen=True)
class WheelConfig:
    """One wheel: an axis of a CANopen node and its unit conversions. Optional fields
    default as :data:`SCHEMA` says for the ``[[wheel]]`` key of the same name."""

    node_id: int
    axis: int
    eds: Path
    velocity_scale: float  # drive velocity units per m/s at the rim
    position_scale: float  # encoder units per m of rim travel
    angle_deg: float | None = _WHEEL["angle_deg"]
    drive_angle_deg: float | None = _WHEEL["drive_angle_deg"]
    base_radius: float | None = _WHEEL["base_radius"]
    mode: Mode | None = _WHEEL["mode"]
    # m, when the config gave it (omnican ros2's joint angles need it). Not part of equality:
    # the scales define the wheel; a config rewritten with scales only is the same wheel.
    wheel_radius: float | None = field(default=_WHEEL["wheel_radius"], compare=False)
    # What the drive reports of this wheel: objects as the config names them ("" none),
    # resolved against the EDS by omnican.plan.health.
    current: str | None = _WHEEL["current"]
    current_scale: float | None = _WHEEL["current_scale"]
    torque: str | None = _WHEEL["torque"]
    voltage: str | None = _WHEEL["voltage"]
    voltage_scale: float = _WHEEL["voltage_scale"]
    temperature: str | None = _WHEEL["temperature"]
    temperature_scale: float = _WHEEL["temperature_scale"]
    settings: tuple[VendorSetting, ...] = ()  # [[wheel.sdo]]

    @property
    def name(self) -> str:
        return f"node {self.node_id}" + (f" axis {self.axis}" if self.axis else "")


@dataclass(frozen=True)
class VendorSetting:
    """One ``[[wheel.sdo]]`` table: ``value`` written to ``object`` (as the config names
    it) in PRE-OPERATIONAL; ``type`` None: the EDS's."""

    object: str
    value: int | float | bool
    type: str | None = None


#: [[wheel.sdo]] type names -> (bits, signed); bool is one byte.
SDO_TYPES: dict[str, tuple[int, bool]] = {"u8": (8, False), "u16": (16, False),
                                          "u32": (32, False), "i8": (8, True),
                                          "i16": (16, True), "i32": (32, True),
                                          "bool": (8, False)}

_POWER = schema_defaults("power")
_ESTOP = schema_defaults("estop")


@dataclass(frozen=True)
class PowerSettings:
    """The ``[power]`` table: DC link thresholds with hysteresis (V, s)."""

    warn_v: float | None = _POWER["warn_v"]
    cutoff_v: float | None = _POWER["cutoff_v"]
    hysteresis_v: float = _POWER["hysteresis_v"]
    delay_s: float = _POWER["delay_s"]


@dataclass(frozen=True)
class EstopSettings:
    """The ``[estop]`` table: bit ``bit`` of ``object`` on ``node_id`` (None: every
    node) shows the e-stop pressed (clear when ``active_low``)."""

    bit: int
    object: str = _ESTOP["object"]
    active_low: bool = _ESTOP["active_low"]
    node_id: int | None = _ESTOP["node_id"]


@dataclass(frozen=True)
class SimTruth:
    """The ``[sim]`` table: the true geometry of the simulated base ``omnican calibrate
    --sim`` drives; None: as configured."""

    base_radius: float | None = None
    position_scale: tuple[float, ...] | None = None  # one per wheel, counts per m


#: What a ``[chassis]`` table must give (or may leave to the wheels' angle_deg), for a
#: ChassisSettings made in code: the demo base's (:func:`default_config`).
DEMO_CHASSIS: dict[str, Any] = {"layout": "b21", "base_radius": 0.19}
_CHASSIS = _field_defaults("chassis", **DEMO_CHASSIS)
_SCALED = {name: spec.scaled for name, spec in SCHEMA["chassis"].items() if spec.scaled}


@dataclass(frozen=True)
class ChassisSettings:
    """The ``[chassis]`` table. Defaults are :data:`SCHEMA`'s, but for the keys a config
    must give (:data:`DEMO_CHASSIS`); a stop deceleration not given (NaN) is derived from
    the acceleration as SCHEMA says (``Key.scaled``)."""

    layout: str | None = _CHASSIS["layout"]
    base_radius: float = _CHASSIS["base_radius"]
    rate_hz: float = _CHASSIS["rate_hz"]
    rt_priority: int = _CHASSIS["rt_priority"]
    cmd_timeout_s: float = _CHASSIS["cmd_timeout_s"]
    max_wheel_speed: float = _CHASSIS["max_wheel_speed"]
    max_speed: float = _CHASSIS["max_speed"]
    max_angular_speed: float = _CHASSIS["max_angular_speed"]
    max_accel: float = _CHASSIS["max_accel"]
    max_angular_accel: float = _CHASSIS["max_angular_accel"]
    stop_decel: float = math.nan  # not given: scaled from max_accel
    stop_angular_decel: float = math.nan  # not given: scaled from max_angular_accel
    mode: Mode | None = _CHASSIS["mode"]
    host_node_id: int = _CHASSIS["host_node_id"]
    heartbeat_ms: int = _CHASSIS["heartbeat_ms"]
    heartbeat_timeout_factor: float = _CHASSIS["heartbeat_timeout_factor"]
    sdo_timeout_s: float = _CHASSIS["sdo_timeout_s"]
    sdo_retries: int = _CHASSIS["sdo_retries"]
    boot_timeout_s: float = _CHASSIS["boot_timeout_s"]
    enable_timeout_s: float = _CHASSIS["enable_timeout_s"]
    pdo_mapping: str = _CHASSIS["pdo_mapping"]  # see pdoplan.MAPPING_POLICIES
    health_rate_hz: float = _CHASSIS["health_rate_hz"]
    tracking_error: float = _CHASSIS["tracking_error"]
    tracking_time_s: float = _CHASSIS["tracking_time_s"]
    tracking_lag_s: float = _CHASSIS["tracking_lag_s"]
    lifted_wheel: str = _CHASSIS["lifted_wheel"]  # see LIFTED_WHEEL

    def __post_init__(self) -> None:
        for key in _SCALED:
            if math.isnan(getattr(self, key)):
                object.__setattr__(self, key, self.default_of(key))

    def default_of(self, key: str) -> Any:
        """What ``key`` defaults to, the other settings as they are here: SCHEMA's default
        (DEMO_CHASSIS's for a key a config must give), for a scaled key its factor times
        the key it scales."""
        if key in _SCALED:
            of, factor = _SCALED[key]
            return factor * getattr(self, of)
        return _CHASSIS[key]


@dataclass(frozen=True)
class ChassisConfig:
    """The whole robot. ``bus`` is passed to ``can.Bus``; None = python-can's own config."""

    chassis: ChassisSettings
    wheels: tuple[WheelConfig, ...]
    bus: Mapping[str, Any] | None = None
    source: Path | None = field(default=None, compare=False)
    ros2: Mapping[str, Any] | None = None  # the [ros2] table, schema-checked (omnican ros2)
    power: PowerSettings | None = None  # the [power] table
    estop: EstopSettings | None = None  # the [estop] table
    foxglove: Mapping[str, Any] | None = None  # the [foxglove] table, schema-checked (--foxglove)
    # The [sim] table: not the robot's description, so not part of equality.
    sim: SimTruth | None = field(default=None, compare=False)

    def kinematics(self) -> OmniKinematics:
        c = self.chassis
        radii = [w.base_radius if w.base_radius is not None else c.base_radius for w in self.wheels]
        if c.layout is not None:
            angles: list[float] = list(LAYOUTS[c.layout])
        else:
            angles = [float(w.angle_deg) for w in self.wheels if w.angle_deg is not None]
        drive = [w.drive_angle_deg for w in self.wheels]
        drive_angles = (
            None
            if all(d is None for d in drive)
            else [d if d is not None else a + 90.0 for d, a in zip(drive, angles, strict=True)]
        )
        return OmniKinematics(angles, radii, drive_angles)

    def limits(self) -> VelocityLimits:
        c = self.chassis
        return VelocityLimits(
            max_linear=c.max_speed,
            max_angular=c.max_angular_speed,
            max_linear_accel=c.max_accel,
            max_angular_accel=c.max_angular_accel,
            stop_linear_decel=c.stop_decel,
            stop_angular_decel=c.stop_angular_decel,
            max_wheel_speed=c.max_wheel_speed,
        )

    def with_bus(self, **bus: Any) -> ChassisConfig:
        """A copy on another bus (e.g. a virtual channel for the simulator)."""
        return replace(self, bus=dict(bus))

    def nodes(self) -> dict[int, list[WheelConfig]]:
        """Wheels grouped by node id, in wheel order."""
        out: dict[int, list[WheelConfig]] = {}
        for w in self.wheels:
            out.setdefault(w.node_id, []).append(w)
        return out


def derive_scales(
    gear_ratio: float,
    encoder_cpr: float,
    wheel_radius: float,
    velocity_unit: str = _WHEEL["velocity_unit"],
    invert: bool = _WHEEL["invert"],
) -> tuple[float, float]:
    """(velocity_scale, position_scale) from a drive's physical parameters.

    position_scale = counts per m of rim travel = cpr * gear / (2 pi r);
    velocity_scale = drive velocity units per m/s at the rim."""
    if velocity_unit not in VELOCITY_UNITS:
        raise ConfigError(
            f"velocity_unit: unknown unit {velocity_unit!r}; use one of {', '.join(VELOCITY_UNITS)}"
        )
    motor_rev_per_m = gear_ratio / (2.0 * math.pi * wheel_radius)
    position_scale = encoder_cpr * motor_rev_per_m
    per_unit = VELOCITY_UNITS[velocity_unit]
    velocity_scale = position_scale if per_unit == 0.0 else motor_rev_per_m / per_unit
    sign = -1.0 if invert else 1.0
    return sign * velocity_scale, sign * position_scale


# A simulated demo base: the bundled drive, 16:1 gear, 4096-count encoder, 50 mm wheels.
_DEMO_WHEEL_RADIUS = 0.05
_DEMO_SCALES = derive_scales(16.0, 4096.0, _DEMO_WHEEL_RADIUS)


#: The demo base's health wiring: the bundled drive's temperature object (0.1 degC), its
#: e-stop on digital input 1 (60FDh bit 16, where the simulator's e-stop is wired), and a
#: 24 V battery (the simulator's nominal supply) that warns below 22 V and stops the base
#: below 20 V.
DEMO_TEMPERATURE = ("0x2100", 0.1)
DEMO_ESTOP = EstopSettings(bit=16)
DEMO_POWER = PowerSettings(warn_v=22.0, cutoff_v=20.0)


def default_config(bus: Mapping[str, Any] | None = None) -> ChassisConfig:
    """The demo base that ``--sim`` runs without a config: three bundled drives,
    node ids 1-3, the :data:`SCHEMA` defaults and :data:`DEMO_CHASSIS`, the bundled
    drive's temperature, an e-stop and a battery (:data:`DEMO_ESTOP`,
    :data:`DEMO_POWER`)."""
    vs, ps = _DEMO_SCALES
    temperature, scale = DEMO_TEMPERATURE
    wheels = tuple(
        WheelConfig(node_id=n, axis=0, eds=WHEEL_EDS, velocity_scale=vs, position_scale=ps,
                    wheel_radius=_DEMO_WHEEL_RADIUS, temperature=temperature,
                    temperature_scale=scale)
        for n in (1, 2, 3)
    )
    return ChassisConfig(chassis=ChassisSettings(), wheels=wheels, bus=bus, power=DEMO_POWER,
                         estop=DEMO_ESTOP)


def _suggest(word: str, known: Iterable[str]) -> str:
    """" (did you mean 'x'?)" for the closest known key; else where the keys are listed
    (a list of every key makes a line no one reads)."""
    close = difflib.get_close_matches(word, list(known), n=1, cutoff=0.75)
    return f" (did you mean {close[0]!r}?)" if close else \
        " (the keys: omnican check-config --help)"


class _Reader:
    """Checks one TOML table against its schema, collecting nothing: first error raises."""

    def __init__(self, origin: str) -> None:
        self.origin = origin

    def fail(self, where: str, message: str) -> ConfigError:
        return ConfigError(f"{self.origin}: {where}: {message}")

    def table(self, section: str, data: Any, where: str) -> dict[str, Any]:
        if not isinstance(data, dict):
            raise self.fail(where, f"must be a table, got {type(data).__name__}")
        schema = SCHEMA[section]
        for key in data:
            if key not in schema:
                raise self.fail(f"{where}.{key}", f"unknown key {key!r}{_suggest(key, schema)}")
        out: dict[str, Any] = {}
        for key, spec in schema.items():
            if key not in data:
                if spec.required:
                    raise self.fail(f"{where}.{key}", "missing required key")
                out[key] = spec.default
                continue
            value = data[key]
            if isinstance(value, bool) and bool not in spec.types:
                raise self.fail(f"{where}.{key}", f"must be a number, got {value!r}")
            if not isinstance(value, spec.types):
                kind = " or ".join(t.__name__ for t in spec.types)
                raise self.fail(f"{where}.{key}", f"must be {kind}, got {value!r}")
            if isinstance(value, float) and math.isnan(value):
                raise self.fail(f"{where}.{key}", "must be a number, got nan")
            self.in_range(f"{where}.{key}", spec, value)
            out[key] = value
        return out

    def in_range(self, where: str, spec: Key, value: Any) -> None:
        """A number within its key's :attr:`Key.range` (inf where the key allows it)."""
        if spec.range is None or isinstance(value, bool) or not isinstance(value, _NUM):
            return
        lo, hi = spec.range
        v = abs(value) if spec.signed else value
        if math.isinf(value) and spec.inf_ok and value > 0:
            return
        if not lo <= v <= hi:
            shown = f"{value:.6g}" if isinstance(value, float) else str(value)
            raise self.fail(where, f"must be {spec.range_text()}, got {shown}")

    def positive(self, where: str, value: Any, allow_inf: bool = False) -> float:
        v = float(value)
        if not (v > 0) or (math.isinf(v) and not allow_inf):
            raise self.fail(where, f"must be a positive number, got {value!r}")
        return v


def _parse_mode(reader: _Reader, where: str, value: str | None) -> Mode | None:
    if value is None:
        return None
    try:
        return Mode.from_name(value)
    except ValueError as exc:
        raise reader.fail(where, str(exc)) from None


def _chassis_settings(table: Mapping[str, Any]) -> ChassisSettings:
    """The settings of a checked ``[chassis]`` table but its mode: numbers as floats
    (TOML's 100 is an int); a scaled key not given is left to ChassisSettings to derive."""
    values: dict[str, Any] = {}
    for key, spec in SCHEMA["chassis"].items():
        value = table[key]
        if key == "mode" or (value is None and spec.scaled is not None):
            continue
        values[key] = float(value) if spec.types == _NUM and value is not None else value
    return ChassisSettings(**values)


def parse_config(data: Mapping[str, Any], origin: str = "config", base_dir: Path | None = None,
                 check_eds: bool = True) -> ChassisConfig:
    """Validate a parsed TOML document into a :class:`ChassisConfig`."""
    r = _Reader(origin)
    for key in data:
        sections = ("bus", "chassis", "wheel", "power", "estop", "ros2", "foxglove", "sim",
                    *FRONT_END_SECTIONS)
        if key not in sections:
            raise r.fail(key, f"unknown section {key!r}{_suggest(key, sections)}")
    bus = data.get("bus")
    if bus is not None and not isinstance(bus, dict):
        raise r.fail("bus", "must be a table")
    if bus is not None:
        _check_bus_numbers(r, bus)
    if "chassis" not in data:
        raise r.fail("chassis", "missing section")
    c = r.table("chassis", data["chassis"], "chassis")

    r.positive("chassis.base_radius", c["base_radius"])
    rate = r.positive("chassis.rate_hz", c["rate_hz"])
    if rate > 5000:
        raise r.fail("chassis.rate_hz", f"must be at most 5000 Hz, got {rate}")
    if not 0 <= c["rt_priority"] <= MAX_RT_PRIORITY:
        raise r.fail("chassis.rt_priority", f"must be 0 (normal priority) or a SCHED_FIFO "
                     f"priority 1-{MAX_RT_PRIORITY}, got {c['rt_priority']}")
    for key in ("cmd_timeout_s", "heartbeat_timeout_factor", "sdo_timeout_s",
                "boot_timeout_s", "enable_timeout_s", "health_rate_hz", "tracking_time_s",
                "tracking_lag_s"):
        r.positive(f"chassis.{key}", c[key])
    if c["health_rate_hz"] > rate:
        raise r.fail("chassis.health_rate_hz", f"must be at most rate_hz ({rate:g}), got "
                     f"{c['health_rate_hz']}")
    r.positive("chassis.tracking_error", c["tracking_error"], allow_inf=True)
    for key in LIVE_LIMITS:
        if key not in _SCALED:
            _check_limit(r, key, c[key])
    settings = _chassis_settings(c)  # its mode once the rest is checked
    for key in _SCALED:
        _check_limit(r, key, getattr(settings, key))
    if not 1 <= c["host_node_id"] <= 127:
        raise r.fail("chassis.host_node_id", f"must be 1-127, got {c['host_node_id']}")
    if not 1 <= c["heartbeat_ms"] <= 65535:
        raise r.fail("chassis.heartbeat_ms", f"must be 1-65535, got {c['heartbeat_ms']}")
    if 1.0 / rate > heartbeat.max_cycle_s(c["heartbeat_ms"] / 1000.0):
        raise r.fail("chassis.rate_hz", f"a {rate:g} Hz loop cannot send the host's heartbeat "
                     f"every {c['heartbeat_ms']} ms: raise rate_hz to at least "
                     f"{1000.0 / c['heartbeat_ms']:g} or heartbeat_ms")
    if not 0 <= c["sdo_retries"] <= 20:
        raise r.fail("chassis.sdo_retries", f"must be 0-20, got {c['sdo_retries']}")
    if c["lifted_wheel"] not in LIFTED_WHEEL:
        raise r.fail("chassis.lifted_wheel", f"must be one of {', '.join(LIFTED_WHEEL)}, got "
                     f"{c['lifted_wheel']!r}")
    if c["pdo_mapping"] not in PDO_MAPPINGS:
        raise r.fail("chassis.pdo_mapping", f"must be one of {', '.join(PDO_MAPPINGS)}, got "
                     f"{c['pdo_mapping']!r}")
    layout = c["layout"]
    if layout is not None and layout not in LAYOUTS:
        raise r.fail("chassis.layout", f"unknown layout {layout!r} (known: {', '.join(LAYOUTS)})")
    settings = replace(settings, mode=_parse_mode(r, "chassis.mode", c["mode"]))

    raw_wheels = data.get("wheel")
    if raw_wheels is None:
        raise r.fail("wheel", "missing: give one [[wheel]] table per wheel")
    if not isinstance(raw_wheels, list):
        raise r.fail("wheel", "must be an array of tables ([[wheel]])")
    wheels = tuple(
        _parse_wheel(r, i, w, settings, base_dir) for i, w in enumerate(raw_wheels)
    )
    _check_wheels(r, settings, wheels)
    ros2 = r.table("ros2", data["ros2"], "ros2") if "ros2" in data else None
    if ros2 is not None:
        for key in ("joint_names", "peers"):
            if ros2[key] is not None and not all(isinstance(v, str) for v in ros2[key]):
                raise r.fail(f"ros2.{key}", "must be an array of strings")
    if "gamepad" in data:
        _check_gamepad(r, data["gamepad"])
    power = _parse_power(r, data["power"]) if "power" in data else None
    estop = _parse_estop(r, data["estop"], wheels) if "estop" in data else None
    foxglove = _foxglove_table(r, data["foxglove"], base_dir) if "foxglove" in data else None
    sim = _parse_sim(r, data["sim"], len(wheels)) if "sim" in data else None
    cfg = ChassisConfig(chassis=settings, wheels=wheels, bus=bus, ros2=ros2, power=power,
                        estop=estop, foxglove=foxglove, sim=sim)
    try:
        cfg.kinematics()
    except ConfigError as exc:
        raise r.fail("wheel geometry", str(exc)) from None
    _check_stop_bound(r, cfg, data["chassis"].keys())
    if check_eds:
        check_eds_files(cfg, r.origin)
    return cfg


def _parse_sim(r: _Reader, table: Any, n_wheels: int) -> SimTruth:
    t = r.table("sim", table, "sim")
    scale = t["position_scale"]
    if isinstance(scale, list):
        if len(scale) != n_wheels:
            raise r.fail("sim.position_scale", f"give one number for every wheel or one per "
                         f"wheel ({n_wheels}), got {len(scale)}")
        for i, v in enumerate(scale):
            if isinstance(v, bool) or not isinstance(v, _NUM) or math.isnan(v):
                raise r.fail(f"sim.position_scale[{i}]", f"must be a number, got {v!r}")
    values = None if scale is None else [scale] * n_wheels if isinstance(scale, _NUM) else scale
    if values is not None:
        spec = SCHEMA["sim"]["position_scale"]
        for i, v in enumerate(values):
            r.in_range(f"sim.position_scale[{i}]" if isinstance(scale, list)
                       else "sim.position_scale", spec, v)
    radius = t["base_radius"]
    return SimTruth(None if radius is None else float(radius),
                    None if values is None else tuple(float(v) for v in values))


def _parse_power(r: _Reader, table: Any) -> PowerSettings:
    p = r.table("power", table, "power")
    for key in ("warn_v", "cutoff_v"):
        if p[key] is not None:
            r.positive(f"power.{key}", p[key])
    for key in ("hysteresis_v", "delay_s"):
        if not (math.isfinite(p[key]) and p[key] >= 0):
            raise r.fail(f"power.{key}", f"must be 0 or more, got {p[key]!r}")
    if p["warn_v"] is not None and p["cutoff_v"] is not None and p["warn_v"] <= p["cutoff_v"]:
        raise r.fail("power.warn_v", f"must be above cutoff_v ({p['cutoff_v']:g} V), got "
                     f"{p['warn_v']:g}")
    return PowerSettings(
        warn_v=None if p["warn_v"] is None else float(p["warn_v"]),
        cutoff_v=None if p["cutoff_v"] is None else float(p["cutoff_v"]),
        hysteresis_v=float(p["hysteresis_v"]), delay_s=float(p["delay_s"]))


def _parse_estop(r: _Reader, table: Any, wheels: tuple[WheelConfig, ...]) -> EstopSettings:
    e = r.table("estop", table, "estop")
    if not 0 <= e["bit"] < 32:
        raise r.fail("estop.bit", f"must be 0-31, got {e['bit']}")
    if e["node_id"] is not None and e["node_id"] not in {w.node_id for w in wheels}:
        raise r.fail("estop.node_id", f"node {e['node_id']} drives no wheel")
    if not e["object"].strip():
        raise r.fail("estop.object", "must name an object")
    return EstopSettings(bit=e["bit"], object=e["object"], active_low=e["active_low"],
                         node_id=e["node_id"])


def _parse_settings(r: _Reader, where: str, raw: Any) -> tuple[VendorSetting, ...]:
    """A wheel's [[wheel.sdo]] tables (checked against the EDS later)."""
    if raw is None:
        return ()
    if not isinstance(raw, list):
        raise r.fail(f"{where}.sdo", "must be an array of tables ([[wheel.sdo]])")
    out = []
    for k, item in enumerate(raw):
        t = r.table("wheel.sdo", item, f"{where}.sdo[{k}]")
        kind = t["type"]
        if kind is not None and kind not in SDO_TYPES:
            raise r.fail(f"{where}.sdo[{k}].type", f"unknown type {kind!r} (one of "
                         f"{', '.join(SDO_TYPES)})")
        value = t["value"]
        if isinstance(value, float) and not math.isfinite(value):
            raise r.fail(f"{where}.sdo[{k}].value", f"must be finite, got {value!r}")
        out.append(VendorSetting(t["object"], value, kind))
    return tuple(out)


def _check_bus_numbers(r: _Reader, bus: Mapping[str, Any]) -> None:
    """The [bus] keys of :data:`BUS_KEYS`, when given: integers within their range (the
    rest of the table is python-can's to check)."""
    for key, spec in BUS_KEYS.items():
        if key not in bus:
            continue
        value = bus[key]
        if isinstance(value, bool) or not isinstance(value, spec.types):
            raise r.fail(f"bus.{key}", f"must be an integer number of bit/s, e.g. 500000, "
                         f"got {_short(value)}")
        r.in_range(f"bus.{key}", spec, value)


def _short(value: Any) -> str:
    """``repr(value)``, at most 40 characters of it."""
    text = repr(value)
    return text if len(text) <= 40 else f"{text[:37]}..."


def _check_limit(r: _Reader, key: str, value: Any) -> float:
    """A limit's value as a config's [chassis] table must give it: a positive number
    within its range, inf only where the key allows it."""
    v = r.positive(f"chassis.{key}", value, allow_inf=key in _UNLIMITED_OK)
    r.in_range(f"chassis.{key}", SCHEMA["chassis"][key], value)
    return v


#: Live limits a higher value of which makes the base safer (a shorter stop); for the
#: others a lower value does.
_SAFER_HIGHER = ("stop_decel", "stop_angular_decel")
_UNITS = {"max_speed": "m/s", "max_wheel_speed": "m/s", "max_angular_speed": "rad/s",
          "max_accel": "m/s^2", "stop_decel": "m/s^2", "max_angular_accel": "rad/s^2",
          "stop_angular_decel": "rad/s^2"}


def with_live_limits(settings: ChassisSettings, changes: Mapping[str, Any],
                     origin: str = "live", configured: ChassisSettings | None = None
                     ) -> ChassisSettings:
    """``settings`` with ``changes`` (:data:`LIVE_LIMITS` keys -> values), each checked as
    a config file's [chassis] key is checked (its type, then its range). Each key changes
    only itself (a stop deceleration stays what it is when max_accel changes). Raises
    :class:`ConfigError` naming the key and why, e.g. ``live: chassis.max_accel: must be a
    positive number, got -1``.

    ``configured``: the settings the base was opened with. A live value may only make
    the base safer than those: never a higher speed or acceleration, never a lower stop
    deceleration (a longer stop) than they have."""
    r = _Reader(origin)
    values: dict[str, Any] = {}
    for key, value in changes.items():
        where = f"chassis.{key}"
        if key not in LIVE_LIMITS:
            what = ("unknown key" if key not in SCHEMA["chassis"] else
                    "cannot change while the base runs")
            raise r.fail(where, f"{what} (the limits that can: {', '.join(LIVE_LIMITS)})")
        if isinstance(value, bool) or not isinstance(value, _NUM):
            raise r.fail(where, f"must be a number, got {value!r}")
        if isinstance(value, float) and math.isnan(value):
            raise r.fail(where, "must be a number, got nan")
        values[key] = _check_limit(r, key, value)
        if configured is not None:
            _check_safer(r, key, values[key], getattr(configured, key))
    return replace(settings, **values)


def _check_safer(r: _Reader, key: str, value: float, configured: float) -> None:
    """A live ``value`` of ``key`` no less safe than the ``configured`` one."""
    unit = _UNITS[key]
    if key in _SAFER_HIGHER:
        if value < configured:
            raise r.fail(f"chassis.{key}", f"at least {configured:g} {unit}, the value the "
                         "base was opened with (a live value may only shorten a stop; "
                         f"lower it in the config), got {value:g}")
    elif value > configured:
        raise r.fail(f"chassis.{key}", f"at most {configured:g} {unit}, the value the base "
                     "was opened with (a live value may only make the base safer; raise it "
                     f"in the config), got {value:g}")


def _check_stop_bound(r: _Reader, cfg: ChassisConfig, given: Iterable[str]) -> None:
    """The stop decelerations stop the base from its top speed within MAX_STOP_S (see
    omnican.core.limits for where that floor comes from)."""
    limits, kin = cfg.limits(), cfg.kinematics()
    top = top_speeds(limits, kin)
    floor = stop_decel_floor(limits, kin)
    c = cfg.chassis
    for key, of, unit, speed, low in (
            ("stop_decel", "max_speed or max_wheel_speed", "m/s", top[0], floor[0]),
            ("stop_angular_decel", "max_angular_speed or max_wheel_speed", "rad/s", top[1],
             floor[1])):
        value = getattr(c, key)
        if value < low * (1 - 1e-9):
            scaled = SCHEMA["chassis"][key].scaled
            derived = f" ({scaled[1]:g} x {scaled[0]})" if scaled and key not in given else ""
            raise r.fail(f"chassis.{key}", f"{value:g}{derived} would stop the base from its top "
                         f"speed {speed:.3g} {unit} in {speed / value:.3g} s; every stop must "
                         f"end within {MAX_STOP_S:g} s: at least {low:.3g} {unit}^2 (or lower "
                         f"{of})")


def _foxglove_table(r: _Reader, data: Any, base_dir: Path | None) -> dict[str, Any]:
    """The ``[foxglove]`` table, its types checked; the TLS files' paths relative to the
    config file made whole (omnican.live.settings checks the rest)."""
    table = r.table("foxglove", data, "foxglove")
    for key in ("tls_cert", "tls_key"):
        if table[key] is not None:
            p = Path(table[key]).expanduser()
            table[key] = str(p if p.is_absolute() or base_dir is None else base_dir / p)
    return table


def _check_gamepad(r: _Reader, table: Any) -> None:
    """The ``[gamepad]`` table as ``omnican teleop --gamepad`` reads it."""
    from omnican.command.gamepad import TABLE_KEYS, mapping_from_table

    if not isinstance(table, dict):
        raise r.fail("gamepad", f"must be a table, got {type(table).__name__}")
    for key in table:
        if key not in TABLE_KEYS:
            raise r.fail(f"gamepad.{key}", f"unknown key {key!r}{_suggest(key, TABLE_KEYS)}")
    mapping_from_table(table, origin=f"{r.origin}: gamepad")


def _parse_wheel(r: _Reader, i: int, data: Any, settings: ChassisSettings,
                 base_dir: Path | None) -> WheelConfig:
    where = f"wheel[{i}]"
    w = r.table("wheel", data, where)
    node_id, axis = w["node_id"], w["axis"]
    if not 1 <= node_id <= 127:
        raise r.fail(f"{where}.node_id", f"must be 1-127, got {node_id}")
    if not 0 <= axis < 8:
        raise r.fail(f"{where}.axis", f"must be 0-7, got {axis}")
    scales_given = [k for k in ("velocity_scale", "position_scale") if w[k] is not None]
    physical = [k for k in ("gear_ratio", "encoder_cpr", "wheel_radius") if w[k] is not None]
    if scales_given and physical:
        both = ", ".join(scales_given + physical)
        raise r.fail(where, "give either velocity_scale and position_scale or gear_ratio, "
                     f"encoder_cpr and wheel_radius, not both ({both})")
    if physical:
        missing = {"gear_ratio", "encoder_cpr", "wheel_radius"} - set(physical)
        if missing:
            raise r.fail(f"{where}.{sorted(missing)[0]}", "missing (needed to derive the scales)")
        for k in physical:
            r.positive(f"{where}.{k}", w[k])
        try:
            vs, ps = derive_scales(w["gear_ratio"], w["encoder_cpr"], w["wheel_radius"],
                                   w["velocity_unit"], w["invert"])
        except ConfigError as exc:
            raise r.fail(f"{where}.velocity_unit", str(exc).split(": ", 1)[1]) from None
    else:
        for k in ("velocity_scale", "position_scale"):
            if w[k] is None:
                raise r.fail(f"{where}.{k}", "missing (or give gear_ratio, encoder_cpr and "
                             "wheel_radius)")
            if not math.isfinite(w[k]) or w[k] == 0:
                raise r.fail(f"{where}.{k}", f"must be a non-zero finite number, got {w[k]!r}")
        vs, ps = float(w["velocity_scale"]), float(w["position_scale"])
        if w["invert"]:
            vs, ps = -vs, -ps
    if w["base_radius"] is not None:
        r.positive(f"{where}.base_radius", w["base_radius"])
    for k in ("current_scale", "voltage_scale", "temperature_scale"):
        if w[k] is not None and (not math.isfinite(w[k]) or w[k] == 0):
            raise r.fail(f"{where}.{k}", f"must be a non-zero finite number, got {w[k]!r}")
    eds = WHEEL_EDS
    if w["eds"] is not None:
        p = Path(w["eds"]).expanduser()
        eds = p if p.is_absolute() or base_dir is None else (base_dir / p)
    return WheelConfig(
        node_id=node_id,
        axis=axis,
        eds=eds,
        velocity_scale=vs,
        position_scale=ps,
        angle_deg=None if w["angle_deg"] is None else float(w["angle_deg"]),
        drive_angle_deg=None if w["drive_angle_deg"] is None else float(w["drive_angle_deg"]),
        base_radius=None if w["base_radius"] is None else float(w["base_radius"]),
        mode=_parse_mode(r, f"{where}.mode", w["mode"]) or settings.mode,
        wheel_radius=float(w["wheel_radius"]) if physical else None,
        current=w["current"],
        current_scale=None if w["current_scale"] is None else float(w["current_scale"]),
        torque=w["torque"],
        voltage=w["voltage"],
        voltage_scale=float(w["voltage_scale"]),
        temperature=w["temperature"],
        temperature_scale=float(w["temperature_scale"]),
        settings=_parse_settings(r, where, w["sdo"]),
    )


def _check_wheels(r: _Reader, s: ChassisSettings, wheels: tuple[WheelConfig, ...]) -> None:
    if len(wheels) < 3:
        raise r.fail("wheel", f"an omni base needs at least 3 wheels, got {len(wheels)}")
    seen: dict[tuple[int, int], int] = {}
    for i, w in enumerate(wheels):
        key = (w.node_id, w.axis)
        if key in seen:
            raise r.fail(f"wheel[{i}]",
                         f"node {w.node_id} axis {w.axis} is already wheel[{seen[key]}]")
        seen[key] = i
        if w.node_id == s.host_node_id:
            raise r.fail(f"wheel[{i}].node_id", f"{w.node_id} is the host's node id "
                         "(chassis.host_node_id)")
    with_angles = [w.angle_deg is not None for w in wheels]
    if s.layout is not None:
        if any(with_angles):
            raise r.fail("chassis.layout", "give either a layout or angle_deg on every wheel, "
                         "not both")
        n = len(LAYOUTS[s.layout])
        if len(wheels) != n:
            raise r.fail("wheel", f"layout {s.layout!r} has {n} wheels, config has {len(wheels)}")
    elif not all(with_angles):
        i = with_angles.index(False)
        raise r.fail(f"wheel[{i}].angle_deg", "missing: without chassis.layout every wheel "
                     "needs angle_deg")


def check_eds_files(cfg: ChassisConfig, origin: str = "config") -> None:
    """Each wheel's EDS exists, parses, has what every node needs (see
    :mod:`omnican.protocol.eds_check`), the axis, and the objects omnican needs as integers."""
    from omnican.protocol.eds_check import variable_problem
    from omnican.protocol.object_map import (
        AxisObjects,
        Obj,
        declared_types,
        load_dictionary,
        obj_name,
        variable_at,
    )

    cache: dict[Path, Any] = {}
    for i, w in enumerate(cfg.wheels):
        where = f"{origin}: wheel[{i}].eds"
        if w.eds not in cache:
            try:
                cache[w.eds] = load_dictionary(w.eds)
            except ConfigError as exc:
                raise ConfigError(f"{where}: {exc}") from None
        objs = AxisObjects(cache[w.eds], w.axis)
        if w.axis >= max(objs.num_axes, 1):
            raise ConfigError(f"{where}: {w.eds.name} has {objs.num_axes} axis(es), "
                              f"no axis {w.axis}")
        mode = w.mode or Mode.PROFILE_VELOCITY
        target = Obj.VL_TARGET if mode is Mode.VELOCITY else Obj.TARGET_VELOCITY
        for obj in (Obj.CONTROLWORD, Obj.STATUSWORD, Obj.POSITION_ACTUAL, Obj.MODE, target):
            entry = objs.get(obj)
            if entry is None:
                raise ConfigError(
                    f"{where}: {w.eds.name} lacks {obj_name(obj)} "
                    f"(0x{int(obj):04X}) for axis {w.axis}, needed in {mode.short} mode"
                )
            var = variable_at(cache[w.eds], entry.index, entry.subindex)
            problem = (variable_problem(var, entry.name, declared_types(w.eds))
                       if var is not None else None)
            if problem:
                raise ConfigError(f"{where}: EDS {w.eds}: {problem}")


def load_config(path: str | Path, check_eds: bool = True) -> ChassisConfig:
    """Read and validate a TOML config file; raises :class:`ConfigError` on any problem."""
    p = Path(path).expanduser()
    try:
        text = p.read_bytes()
    except OSError as exc:
        raise ConfigError(f"cannot read config {p}: {exc.strerror or exc}") from None
    try:
        data = tomllib.loads(text.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: not valid TOML: {exc}") from None
    except RecursionError:  # tomllib parses nested arrays and tables recursively
        raise ConfigError(f"{p}: not a robot config: arrays or tables nested too deeply") \
            from None
    cfg = parse_config(data, origin=str(p), base_dir=p.resolve().parent, check_eds=check_eds)
    return replace(cfg, source=p)
