"""The configuration schema: every key of every table, its type, default, range and
meaning (:data:`SCHEMA`; a front end's table is its own, read through the front ends'
registry), and the values some keys take (:data:`VELOCITY_UNITS`, :data:`PDO_MAPPINGS`,
the gamepad's codes and presets...). The one place a default or a range is written: the
dataclasses of :mod:`omnican.config.model` take their defaults from here,
:mod:`omnican.config.parsing` checks a TOML document against it, and README's
configuration reference is made from it (:func:`reference_rows`, checked by a test).

Pure data: no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

from omnican.config import imu_keys
from omnican.config import key as key_spec
from omnican.core.limits import MAX_ACCEL_SENSE, MAX_SPEED_SENSE
from omnican.layers import FRONT_ENDS

#: One key's spec, and the TOML types of a number (their home: :mod:`omnican.config.key`).
Key = key_spec.Key
NUMBER = key_spec.NUMBER
#: Values of imu.source (:mod:`omnican.config.imu_keys`, the [imu] and [sim.gyro] keys).
IMU_SOURCES = imu_keys.IMU_SOURCES

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

#: [[wheel.sdo]] type names -> (bits, signed); bool is one byte.
SDO_TYPES: dict[str, tuple[int, bool]] = {"u8": (8, False), "u16": (16, False),
                                          "u32": (32, False), "i8": (8, True),
                                          "i16": (16, True), "i32": (32, True),
                                          "bool": (8, False)}


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
#: The range of a wait (s) and of a topic's publish rate (Hz), for the front ends' keys.
WAIT_S, TOPIC_RATE_HZ = _WAIT, (0.01, 1000.0)

#: The highest chassis.rt_priority: Linux's highest SCHED_FIFO priority.
MAX_RT_PRIORITY = 99

#: Values of chassis.pdo_mapping (what omnican.plan.pdo does with each).
PDO_MAPPINGS = ("try", "eds", "sdo")
#: Values of chassis.lifted_wheel (what the chassis checks do with a wheel off the ground).
LIFTED_WHEEL = ("warn", "stop", "off")

#: [chassis] keys a running base takes while it runs (:meth:`omnican.Chassis.set_limits`,
#: Foxglove's parameters): its velocity limiter's.
LIVE_LIMITS = ("max_speed", "max_angular_speed", "max_accel", "max_angular_accel",
               "stop_decel", "stop_angular_decel", "max_wheel_speed")

#: The keys of the free-form [bus] table that omnican reads itself: their type and range.
#: The bitrates (the bus load; CAN's nominal bitrates run from 10 kbit/s down to what some
#: controllers allow, 1 kbit/s, up to 1 Mbit/s; a CAN FD data phase up to 12 Mbit/s) go
#: on to ``can.Bus`` too; ``sync`` and ``sync_counter`` (who sends SYNC: issue 41,
#: :mod:`omnican.protocol.sync_producer`) are omnican's alone.
BUS_KEYS: dict[str, Key] = {
    "bitrate": Key((int,), None, "bit/s of the bus (nominal)", range=(1000, 1_000_000)),
    "data_bitrate": Key((int,), None, "bit/s of a CAN FD data phase",
                        range=(1000, 12_000_000)),
    "sync": Key((str,), "auto", "who sends SYNC: \"kernel\" (SocketCAN's broadcast manager, "
                "on its own timer; the loop wakes on each SYNC and re-arms it every cycle), "
                "\"loop\" (the control loop, after its RPDOs), \"auto\" (the kernel on "
                "SocketCAN, the loop elsewhere)"),
    "sync_counter": Key((int,), 0, "the SYNC counter's overflow value (CiA 301 1019h): 0 no "
                        "counter, 2-240 SYNCs carry a counter 1..N; set the drives' 1019h "
                        "to the same (a [[wheel.sdo]] line)", range=(0, 240)),
}

# The [gamepad] table's words: Linux input event codes (linux/input-event-codes.h, the
# stable kernel ABI, what evdev reports) and the pads tested with the kernel's drivers
# (xpad: Xbox and Logitech F710 in X mode; hid-playstation: PS4/PS5).
#: Stick axes a ``[gamepad]`` axis key may name.
GAMEPAD_AXES: dict[str, int] = {
    "ABS_X": 0x00, "ABS_Y": 0x01, "ABS_Z": 0x02, "ABS_RX": 0x03, "ABS_RY": 0x04,
    "ABS_RZ": 0x05, "ABS_HAT0X": 0x10, "ABS_HAT0Y": 0x11,
}
#: Buttons a ``[gamepad]`` button key may name.
GAMEPAD_BUTTONS: dict[str, int] = {
    "BTN_SOUTH": 0x130, "BTN_A": 0x130, "BTN_EAST": 0x131, "BTN_B": 0x131,
    "BTN_NORTH": 0x133, "BTN_X": 0x133, "BTN_WEST": 0x134, "BTN_Y": 0x134,
    "BTN_TL": 0x136, "BTN_TR": 0x137, "BTN_TL2": 0x138, "BTN_TR2": 0x139,
    "BTN_SELECT": 0x13A, "BTN_START": 0x13B, "BTN_MODE": 0x13C,
    "BTN_THUMBL": 0x13D, "BTN_THUMBR": 0x13E,
    # generic HID joysticks (e.g. the F710 with its switch on D)
    "BTN_TRIGGER": 0x120, "BTN_THUMB": 0x121, "BTN_THUMB2": 0x122, "BTN_TOP": 0x123,
    "BTN_TOP2": 0x124, "BTN_PINKIE": 0x125, "BTN_BASE": 0x126, "BTN_BASE2": 0x127,
}
_STICKS = {"axis_vx": "ABS_Y", "axis_vy": "ABS_X", "axis_wz": "ABS_RX"}
_SHOULDERS = {"deadman_button": "BTN_TL", "turbo_button": "BTN_TR"}  # LB / L1, RB / R1
#: Preset -> the ``[gamepad]`` keys it gives (the others default as :data:`SCHEMA` says).
#: The left stick moves, the right one turns; hold the left shoulder button to move, the
#: right one for the turbo scales.
GAMEPAD_PRESETS: dict[str, dict[str, str]] = {
    "xbox": {**_STICKS, **_SHOULDERS},
    "ps": {**_STICKS, **_SHOULDERS},
    "f710": {**_STICKS, **_SHOULDERS},
    # the F710 with its switch on D is a generic HID joystick: right stick on Z/RZ
    "f710-d": {**_STICKS, "axis_wz": "ABS_Z", "deadman_button": "BTN_TOP2",
               "turbo_button": "BTN_PINKIE"},
}
_AXES = ("vx", "vy", "wz")
_GAMEPAD_SCALES = {"vx": (-0.3, -0.8), "vy": (-0.3, -0.8), "wz": (-1.0, -2.0)}  # turbo 2nd

# The library's tables: section -> key -> spec. The [bus] table is free-form (passed to
# can.Bus); the front ends' tables are their own (SCHEMA reads them).
_OWN: dict[str, dict[str, Key]] = {
    "chassis": {
        "layout": Key((str,), None, "wheel preset: \"b21\" (180, -60, 60 deg) or \"a12\" "
                      "(0, 120, -120 deg); omit and give angle_deg per wheel instead"),
        "base_radius": Key(NUMBER, None, "m, base centre to wheel contact point", required=True,
                           range=(0.01, 10.0)),
        "rate_hz": Key(NUMBER, 100.0, "control loop and SYNC rate", range=(1.0, 5000.0)),
        "rt_priority": Key((int,), 50, "SCHED_FIFO priority 1-99 of the control loop thread "
                           "(its thread alone) where the process may: root, CAP_SYS_NICE or "
                           "RLIMIT_RTPRIO; elsewhere normal priority and a note; 0: never"),
        "cmd_timeout_s": Key(NUMBER, 0.5, "no command for this long -> controlled stop",
                             range=_WAIT),
        "max_wheel_speed": Key(NUMBER, 1.0, "m/s at the rim; commands are desaturated to it",
                               range=_SPEED),
        "max_speed": Key(NUMBER, math.inf, "m/s, body linear speed (vector norm)", range=_SPEED,
                         inf_ok=True),
        "max_angular_speed": Key(NUMBER, math.inf, "rad/s, body angular speed", range=_SPEED,
                                 inf_ok=True),
        "max_accel": Key(NUMBER, 1.0, "m/s^2, body linear acceleration", range=_ACCEL),
        "max_angular_accel": Key(NUMBER, 3.0, "rad/s^2, body angular acceleration",
                                 range=_ACCEL),
        "stop_decel": _scaled(NUMBER, "m/s^2 for a stop command (and every other stop); at "
                              "least the top speed / 2 s", "max_accel", 2.0, _DECEL),
        "stop_angular_decel": _scaled(NUMBER, "rad/s^2 for a stop; at least the top angular "
                                      "speed / 2 s", "max_angular_accel", 2.0, _DECEL),
        "mode": Key((str,), None, "\"pv\", \"csv\" or \"vl\"; default: pv, or what 6502h offers"),
        "host_node_id": Key((int,), 127, "node id of this host's heartbeat (0x700 + id)",
                            range=(1, 127)),
        "heartbeat_ms": Key((int,), 100, "heartbeat period of host and drives, ms",
                            range=(1, 65535)),
        "heartbeat_timeout_factor": Key(NUMBER, 3.0, "a heartbeat is lost after this many "
                                        "periods and half a period more: that many lost in a "
                                        "row stop the base, one fewer never does",
                                        range=(1.0, 100.0)),
        "sdo_timeout_s": Key(NUMBER, 0.3, "one SDO request's wait for its answer", range=_WAIT),
        "sdo_retries": Key((int,), 3, "an SDO request unanswered within sdo_timeout_s is sent "
                           "again, up to this many times", range=(0, 20)),
        "boot_timeout_s": Key(NUMBER, 2.0, "wait for a drive's boot-up after NMT reset",
                              range=(0.1, 60.0)),
        "enable_timeout_s": Key(NUMBER, 1.0, "bring a drive to OPERATION ENABLED within this",
                                range=_WAIT),
        "cyclic_controlword": Key((bool,), True, "write each controlword every cycle, beside "
                                  "the targets on the cyclic RPDO (as ros2_canopen's master "
                                  "does; some drives act on a controlword only as one "
                                  "arrives); false: on an RPDO of its own, only when it "
                                  "changes (for a drive that dislikes the repeat)"),
        "pdo_mapping": Key((str,), "try", "objects an EDS marks not PDO-mappable: \"try\" maps "
                           "them anyway (warning; a drive that refuses runs on its own mapping, "
                           "and what that lacks goes by SDO every cycle), \"eds\" sends them by "
                           "SDO every cycle, \"sdo\" sends targets and positions by SDO every "
                           "cycle"),
        "health_rate_hz": Key(NUMBER, 5.0, "how often each drive's current, torque, voltage, "
                              "temperature, error register and e-stop input are read",
                              range=_RATE),
        "tracking_error": Key(NUMBER, 0.1, "m/s: a wheel whose measured speed stays this far "
                              "outside what its target was over the last tracking_lag_s "
                              "latches a stop (inf: never)", range=_SPEED, inf_ok=True),
        "tracking_ratio": Key(NUMBER, 0.5, "a wheel whose measured speed stays under this "
                              "share of its target (the least it was over tracking_lag_s, "
                              "all one way, 5 mm/s or more) latches a stop too, however slow "
                              "(0: never)", range=(0.0, 1.0), open_high=True),
        "tracking_time_s": Key(NUMBER, 0.5, "for this long", range=_WAIT),
        "tracking_lag_s": Key(NUMBER, 0.3, "how far a wheel's measured speed may lag its target "
                              "(speed window, drive ramp and velocity loop)", range=_WAIT),
        "lifted_wheel": Key((str,), "warn", "a wheel off the ground (or without its roller), "
                            "found from its current against its siblings': \"warn\" (a status "
                            "warning naming it), \"stop\" (a stop naming it) or \"off\""),
    },
    "wheel": {
        "node_id": Key((int,), None, "CANopen node id 1-127", required=True, range=(1, 127)),
        "axis": Key((int,), 0, "axis on a multi-axis drive (0-based)", range=(0, 7)),
        "serial": Key((int,), None, "the drive's serial number (1018h sub 4): 'omnican "
                      "commission' gives the drive with it this node_id by LSS",
                      range=(0, 0xFFFFFFFF)),
        "eds": Key((str,), None, "EDS file (relative to the config file); default: bundled EDS"),
        "velocity_scale": Key(NUMBER, None, "drive velocity units per m/s at the rim; sign = "
                              "polarity", range=_SCALE, signed=True),
        "position_scale": Key(NUMBER, None, "encoder position units per m of rim travel",
                              range=_SCALE, signed=True),
        "gear_ratio": Key(NUMBER, None, "motor turns per wheel turn (instead of the scales)",
                          range=(0.001, 1e5)),
        "encoder_cpr": Key(NUMBER, None, "encoder counts per motor turn (instead of the scales)",
                           range=(1.0, 1e9)),
        "wheel_radius": Key(NUMBER, None, "m, wheel radius (instead of the scales)",
                            range=(0.001, 10.0)),
        "velocity_unit": Key((str,), "counts/s", "drive velocity unit when deriving the scales: "
                             + ", ".join(VELOCITY_UNITS)),
        "invert": Key((bool,), False, "reverse the wheel's direction (negates both scales)"),
        "angle_deg": Key(NUMBER, None, "wheel position angle from +x, CCW (instead of layout)",
                         range=(-720.0, 720.0)),
        "drive_angle_deg": Key(NUMBER, None, "drive direction; default angle_deg + 90",
                               range=(-720.0, 720.0)),
        "base_radius": Key(NUMBER, None, "m, this wheel's distance from the centre; default "
                           "[chassis] base_radius", range=(0.01, 10.0)),
        "mode": Key((str,), None, "this wheel's mode; default [chassis] mode"),
        "current": Key((str,), "0x6078", "object with the motor current: \"0xIIII:SS\", "
                       "\"0xIIII\" (this axis's copy) or the EDS entry's name; \"\" for none"),
        "current_scale": Key(NUMBER, None, "A per unit of current; default: 6078h's per mille "
                             "of the rated current 6075h, read at startup", range=_SCALE,
                             signed=True),
        "torque": Key((str,), "0x6077", "object with the torque, per mille of the rated "
                      "torque; \"\" for none"),
        "voltage": Key((str,), "0x6079", "object with the DC link voltage; \"\" for none"),
        "voltage_scale": Key(NUMBER, 0.001, "V per unit of voltage (6079h: mV)", range=_SCALE,
                             signed=True),
        "temperature": Key((str,), None, "object with a temperature (vendor-specific, e.g. "
                           "\"0x2032:01\" or its EDS name); default none"),
        "temperature_scale": Key(NUMBER, 1.0, "degC per unit of temperature", range=_SCALE,
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
        "warn_v": Key(NUMBER, None, "V: the DC link below this warns (status, diagnostics)",
                      range=(0.1, 2000.0)),
        "cutoff_v": Key(NUMBER, None, "V: below this for delay_s, a controlled stop "
                        "(recover() refuses until it is back above cutoff_v + hysteresis_v)",
                        range=(0.1, 2000.0)),
        "hysteresis_v": Key(NUMBER, 0.5, "V a warning or cutoff needs to clear",
                            range=(0.0, 100.0)),
        "delay_s": Key(NUMBER, 1.0, "below a threshold this long before it counts (a sag "
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
    # Read by the base when an IMU is attached: how its gyro is fused with the wheels
    # (omnican.core.fusion) and what a slip or a silent IMU does.
    "fusion": {
        "gyro_noise": Key(NUMBER, 0.005, "rad/s: 1-sigma of one gyro sample",
                          range=(1e-6, 1.0)),
        "bias_walk": Key(NUMBER, 0.0001, "rad/s per sqrt(s): the gyro bias's random walk",
                         range=(1e-9, 0.1)),
        "wheel_slip": Key(NUMBER, 0.01, "1-sigma slip of a wheel, a fraction of its rim "
                          "speed: more than this is a slip", range=(1e-4, 0.5)),
        "slip_warn_s": Key(NUMBER, 0.5, "s of slip before a warning (status, dashboard)",
                           range=(0.01, 60.0)),
        "stop_on_slip": Key((bool,), False, "a slip warning also stops the base (recover() "
                            "to drive again)"),
        "stop_on_imu_stale": Key((bool,), False, "a silent IMU stops the base (default: a "
                                 "warning, and the wheels alone)"),
    },
    "imu": imu_keys.IMU_KEYS,
    # The simulated base `omnican calibrate --sim` drives, as it really is: kept apart from
    # the [chassis] and [[wheel]] numbers calibration corrects, so it stays the same base.
    "sim": {
        "base_radius": Key(NUMBER, None, "m, the simulated base's true base_radius (per-wheel "
                           "base_radius scale with it); default the configured one",
                           range=(0.01, 10.0)),
        "position_scale": Key((*NUMBER, list), None, "true encoder counts per m of rim travel "
                              "of the simulated wheels (magnitude): one number for every "
                              "wheel, or one per wheel; default the configured ones",
                              range=_SCALE),
    },
    "sim.gyro": imu_keys.SIM_GYRO_KEYS,
    # What the simulated ground takes of the wheels' motion (omnican.sim.slip): the
    # encoders count every turn, only the true pose (and a gyro) see the difference.
    "sim.slip": {
        "ratio": Key((*NUMBER, list), 0.0, "the share of a wheel's rim travel the ground does "
                     "not take (0: it grips, 0.1: 10 % lost): one number for every wheel, or "
                     "one per wheel", range=(0.0, 1.0)),
        "roller": Key((*NUMBER, list), 0.0, "the share of a wheel's rim travel by which its "
                      "contact point also slides along its roller (a roller that gives way: "
                      "the base turns and drifts): one number for every wheel, or one per "
                      "wheel", range=(0.0, 1.0)),
        "ramp_grade_deg": Key(NUMBER, 0.0, "the floor is a ramp this steep (deg)",
                              range=(-60.0, 60.0)),
        "ramp_downhill_deg": Key(NUMBER, 0.0, "the direction the ramp falls towards (deg, "
                                 "world frame)", range=(-360.0, 360.0)),
        "ramp_creep": Key(NUMBER, 0.005, "m/s the base creeps downhill per m/s^2 of gravity "
                          "along the ramp, while its wheels turn", range=(0.0, 1.0)),
    },
    # [[sim.slip.surface]]: a patch of floor with its own slip, taken while the simulated
    # base's centre is on it (a rectangle between two corners, world frame).
    "sim.slip.surface": {
        "x0": Key(NUMBER, None, "m, one corner's x", required=True, range=(-1e6, 1e6)),
        "y0": Key(NUMBER, None, "m, one corner's y", required=True, range=(-1e6, 1e6)),
        "x1": Key(NUMBER, None, "m, the opposite corner's x", required=True,
                  range=(-1e6, 1e6)),
        "y1": Key(NUMBER, None, "m, the opposite corner's y", required=True,
                  range=(-1e6, 1e6)),
        "ratio": Key((*NUMBER, list), None, "the share of a wheel's rim travel the ground "
                     "does not take there: one number for every wheel, or one per wheel",
                     required=True, range=(0.0, 1.0)),
    },
    # Read by `omnican teleop --gamepad` (omnican.command.gamepad). A key left out is the
    # preset's; every preset has the defaults below. evdev's sticks read + to the right
    # and + down, REP-103 wants + forward, + left and + counter-clockwise: hence the
    # negative scales.
    "gamepad": {
        "preset": Key((str,), None, "xbox, ps (PS4/PS5), f710 (X mode) or f710-d; default: "
                      "from the device name"),
        "deadzone": Key(NUMBER, 0.05, "stick deadzone, fraction of full deflection",
                        range=(0.0, 1.0), open_high=True),  # 0.05: ROS joy's default
        "deadman_button": Key((str, int), None, "button to hold for any motion, e.g. "
                              "\"BTN_TL\"; default the preset's (LB / L1)"),
        "turbo_button": Key((str, int), None, "button for the turbo scales, e.g. \"BTN_TR\"; "
                            "\"\" for none; default the preset's (RB / R1)"),
        "require_deadman": Key((bool,), True, "whether the deadman must be held for any "
                               "motion"),
        **{f"axis_{a}": Key((str, int), None, f"axis for {a}, e.g. \"{_STICKS[f'axis_{a}']}\"; "
                            "default the preset's") for a in _AXES},
        **{f"scale_{a}": Key(NUMBER, _GAMEPAD_SCALES[a][0], f"{a} at full deflection "
                             f"({'rad/s' if a == 'wz' else 'm/s'}; negative flips it)")
           for a in _AXES},
        **{f"turbo_scale_{a}": Key(NUMBER, _GAMEPAD_SCALES[a][1], f"{a} at full deflection "
                                   "with turbo held") for a in _AXES},
    },
}



class Schema(Mapping[str, Mapping[str, Key]]):
    """Section -> key -> spec of every table a config may have: the library's own, and
    each front end's (its own, read through the front ends' registry when first asked
    for: :mod:`omnican.config.front_ends`), in the order README lists them: the base's
    tables, the front ends' (before ``before``), then the rest."""

    def __init__(self, own: dict[str, dict[str, Key]], before: str) -> None:
        self._own = own
        self._before = before

    def __getitem__(self, section: str) -> Mapping[str, Key]:
        if section in self._own:
            return self._own[section]
        if section in FRONT_ENDS:  # its plug-in's table (config.front_ends reads them)
            import importlib

            module, _, cls = FRONT_ENDS[section].plugin.partition(":")
            spec = getattr(importlib.import_module(module), cls).table
            keys: Mapping[str, Key] = spec.keys if spec is not None else {}
            return keys
        raise KeyError(section)

    def __iter__(self) -> Iterator[str]:
        names = list(self._own)
        at = names.index(self._before)
        front = [name for name in FRONT_ENDS if name not in self._own]
        return iter(names[:at] + front + names[at:])

    def __len__(self) -> int:
        return len(list(iter(self)))


#: Every key of every table (the library's and the front ends').
SCHEMA: Mapping[str, Mapping[str, Key]] = Schema(_OWN, before="sim")

#: The [chassis] keys that default to a factor times another: key -> (other key, factor).
CHASSIS_SCALED = {name: spec.scaled for name, spec in _OWN["chassis"].items() if spec.scaled}


def defaults_of(keys: Mapping[str, Key]) -> dict[str, Any]:
    """Key -> default of every key of a table's keys (None: required, scaled or no
    value)."""
    return {name: spec.default for name, spec in keys.items()}


def schema_defaults(section: str) -> dict[str, Any]:
    """Key -> default of every key of a :data:`SCHEMA` section (None: required, scaled or
    no value)."""
    return defaults_of(SCHEMA[section])


def default_text(spec: Key) -> str:
    """A key's default as README's reference table writes it: "required", "-" (none),
    true, "text", inf, 0.5."""
    d = spec.default
    if spec.required:
        return "required"
    if d is None:
        return "-"
    if isinstance(d, bool):
        return str(d).lower()
    if isinstance(d, str):
        return f'"{d}"'
    if isinstance(d, float) and math.isinf(d):
        return "inf"
    return f"{d:g}"


def reference_rows() -> list[tuple[str, str, str]]:
    """(key, default, meaning) for every key of :data:`SCHEMA`: README's reference table."""
    return [(f"{section}.{name}", default_text(spec), spec.doc)
            for section, keys in SCHEMA.items() for name, spec in keys.items()]
