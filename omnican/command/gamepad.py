"""Gamepad -> body velocity, after ROS ``teleop_twist_joy`` (pure: no device, no I/O).

A deadman (enable) button must be held for any motion; a turbo button switches to the
turbo scales. Holonomic by default: left stick forward/back -> vx, left/right -> vy, right
stick left/right -> wz. Sticks are normalised to [-1, 1] from the device's own axis range
(evdev ``absinfo``), a deadzone around the centre reads as 0 and the rest is rescaled so
the output stays continuous; each axis has a scale (m/s or rad/s at full deflection,
negative to flip it).

Codes are Linux input event codes (``linux/input-event-codes.h``, what evdev reports), so
a mapping is plain data: :data:`PRESETS` holds the pads tested with the kernel's drivers
(xpad: Xbox and Logitech F710 in X mode; hid-playstation: PS4/PS5), and the ``[gamepad]``
table of the config overrides any part of it (:func:`mapping_from_table`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

from omnican.core.kinematics import Twist
from omnican.errors import ConfigError

# linux/input-event-codes.h (stable kernel ABI)
EV_SYN, EV_KEY, EV_ABS = 0x00, 0x01, 0x03
SYN_DROPPED = 3
ABS_CODES: dict[str, int] = {
    "ABS_X": 0x00, "ABS_Y": 0x01, "ABS_Z": 0x02, "ABS_RX": 0x03, "ABS_RY": 0x04,
    "ABS_RZ": 0x05, "ABS_HAT0X": 0x10, "ABS_HAT0Y": 0x11,
}
BUTTON_CODES: dict[str, int] = {
    "BTN_SOUTH": 0x130, "BTN_A": 0x130, "BTN_EAST": 0x131, "BTN_B": 0x131,
    "BTN_NORTH": 0x133, "BTN_X": 0x133, "BTN_WEST": 0x134, "BTN_Y": 0x134,
    "BTN_TL": 0x136, "BTN_TR": 0x137, "BTN_TL2": 0x138, "BTN_TR2": 0x139,
    "BTN_SELECT": 0x13A, "BTN_START": 0x13B, "BTN_MODE": 0x13C,
    "BTN_THUMBL": 0x13D, "BTN_THUMBR": 0x13E,
    # generic HID joysticks (e.g. the F710 with its switch on D)
    "BTN_TRIGGER": 0x120, "BTN_THUMB": 0x121, "BTN_THUMB2": 0x122, "BTN_TOP": 0x123,
    "BTN_TOP2": 0x124, "BTN_PINKIE": 0x125, "BTN_BASE": 0x126, "BTN_BASE2": 0x127,
}

DEFAULT_DEADZONE = 0.05  # ROS joy's default
DEFAULT_REQUIRE_DEADMAN = True


@dataclass(frozen=True)
class AxisMap:
    """One stick axis: its code and the twist value at full deflection (sign = direction).

    evdev's sticks read + to the right and + down; REP-103 wants + forward, + left and
    + counter-clockwise, hence the negative default scales."""

    code: int
    scale: float
    turbo_scale: float


@dataclass(frozen=True)
class PadMapping:
    name: str
    vx: AxisMap
    vy: AxisMap
    wz: AxisMap
    deadman: int
    turbo: int | None
    deadzone: float = DEFAULT_DEADZONE
    require_deadman: bool = DEFAULT_REQUIRE_DEADMAN


def _pad(name: str, right_x: int, deadman: int, turbo: int | None) -> PadMapping:
    return PadMapping(
        name=name,
        vx=AxisMap(ABS_CODES["ABS_Y"], -0.3, -0.8),
        vy=AxisMap(ABS_CODES["ABS_X"], -0.3, -0.8),
        wz=AxisMap(right_x, -1.0, -2.0),
        deadman=deadman, turbo=turbo)


#: Default mappings. Deadman: the left shoulder button (LB, L1); turbo: the right one.
PRESETS: dict[str, PadMapping] = {
    "xbox": _pad("xbox", ABS_CODES["ABS_RX"], BUTTON_CODES["BTN_TL"], BUTTON_CODES["BTN_TR"]),
    "ps": _pad("ps", ABS_CODES["ABS_RX"], BUTTON_CODES["BTN_TL"], BUTTON_CODES["BTN_TR"]),
    "f710": _pad("f710", ABS_CODES["ABS_RX"], BUTTON_CODES["BTN_TL"], BUTTON_CODES["BTN_TR"]),
    # the F710 with its switch on D is a generic HID joystick: right stick on Z/RZ
    "f710-d": _pad("f710-d", ABS_CODES["ABS_Z"], BUTTON_CODES["BTN_TOP2"],
                   BUTTON_CODES["BTN_PINKIE"]),
}


def preset_for(device_name: str) -> str:
    """The preset for a device's name as its kernel driver reports it."""
    name = device_name.lower()
    if "f710" in name:
        return "f710"
    if any(k in name for k in ("xbox", "x-box", "microsoft")):
        return "xbox"
    if any(k in name for k in ("sony", "playstation", "dualshock", "dualsense",
                               "wireless controller")):
        return "ps"
    return "xbox"


def normalise(raw: int, lo: int, hi: int) -> float:
    """A raw axis value in [lo, hi] -> [-1, 1] (clamped; the centre of the range is 0)."""
    if hi <= lo:
        return 0.0
    v = (2.0 * (raw - lo) / (hi - lo)) - 1.0
    return max(-1.0, min(1.0, v))


def apply_deadzone(v: float, deadzone: float) -> float:
    """0 within ``deadzone`` of the centre; outside, rescaled so +-1 stays +-1 and the
    output rises continuously from 0 at the edge of the zone."""
    a = abs(v)
    if a <= deadzone or deadzone >= 1.0:
        return 0.0
    return math.copysign(min(1.0, (a - deadzone) / (1.0 - deadzone)), v)


@dataclass
class PadState:
    """The pad as events describe it so far. Feed it ``(type, code, value)`` in order."""

    mapping: PadMapping
    ranges: Mapping[int, tuple[int, int]]  # axis code -> (min, max) of the device
    axes: dict[int, float] = field(default_factory=dict)  # normalised, before the deadzone
    buttons: set[int] = field(default_factory=set)
    connected: bool = True

    def feed(self, type_: int, code: int, value: int) -> None:
        if type_ == EV_ABS:
            lo, hi = self.ranges.get(code, (-32768, 32767))
            self.axes[code] = normalise(value, lo, hi)
        elif type_ == EV_KEY:
            if value:  # 1 press, 2 autorepeat
                self.buttons.add(code)
            else:
                self.buttons.discard(code)
        elif type_ == EV_SYN and code == SYN_DROPPED:
            # The kernel dropped events: what we hold may be stale. Stop until fresh ones.
            self.axes.clear()
            self.buttons.clear()

    def unplugged(self) -> None:
        self.connected = False
        self.axes.clear()
        self.buttons.clear()

    @property
    def deadman(self) -> bool:
        return self.connected and (self.mapping.deadman in self.buttons
                                   or not self.mapping.require_deadman)

    @property
    def turbo(self) -> bool:
        return self.mapping.turbo is not None and self.mapping.turbo in self.buttons

    def axis(self, a: AxisMap) -> float:
        v = apply_deadzone(self.axes.get(a.code, 0.0), self.mapping.deadzone)
        return v * (a.turbo_scale if self.turbo else a.scale)

    def command(self) -> Twist:
        """The body velocity asked for now: zero unless the deadman is held."""
        if not self.deadman:
            return Twist()
        m = self.mapping
        return Twist(self.axis(m.vx), self.axis(m.vy), self.axis(m.wz))


# ------------------------------------------------------------------ the [gamepad] table

_AXES = ("vx", "vy", "wz")
#: Keys of the config's ``[gamepad]`` table and their meaning (README lists them).
TABLE_KEYS: dict[str, str] = {
    "preset": "xbox, ps (PS4/PS5), f710 (X mode) or f710-d; default: from the device name",
    "deadzone": "stick deadzone, fraction of full deflection",
    "deadman_button": "button to hold for any motion, e.g. \"BTN_TL\"; default the preset's "
                      "(LB / L1)",
    "turbo_button": "button for the turbo scales, e.g. \"BTN_TR\"; \"\" for none; default the "
                    "preset's (RB / R1)",
    "require_deadman": "whether the deadman must be held for any motion",
    **{f"axis_{a}": f"axis for {a}, e.g. \"{code}\"; default the preset's"
       for a, code in zip(_AXES, ("ABS_Y", "ABS_X", "ABS_RX"), strict=True)},
    **{f"scale_{a}": f"{a} at full deflection ({'rad/s' if a == 'wz' else 'm/s'}; "
                     "negative flips it)" for a in _AXES},
    **{f"turbo_scale_{a}": f"{a} at full deflection with turbo held" for a in _AXES},
}
#: Defaults of the ``[gamepad]`` keys that do not depend on the preset (README's reference).
TABLE_DEFAULTS: dict[str, str] = {"deadzone": f"{DEFAULT_DEADZONE:g}",
                                  "require_deadman": str(DEFAULT_REQUIRE_DEADMAN).lower()}
for _a in _AXES:
    _axis: AxisMap = getattr(PRESETS["xbox"], _a)  # every preset has the same scales
    TABLE_DEFAULTS[f"scale_{_a}"] = f"{_axis.scale:g}"
    TABLE_DEFAULTS[f"turbo_scale_{_a}"] = f"{_axis.turbo_scale:g}"


def _code(where: str, value: Any, table: Mapping[str, int]) -> int:
    if isinstance(value, bool):
        raise ConfigError(f"{where}: want a code name or number, got {value!r}")
    if isinstance(value, int):
        if value < 0:
            raise ConfigError(f"{where}: must not be negative, got {value}")
        return value
    if isinstance(value, str) and value.upper() in table:
        return table[value.upper()]
    raise ConfigError(f"{where}: unknown code {value!r} (known: {', '.join(table)})")


def _number(where: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(f"{where}: want a finite number, got {value!r}")
    return float(value)


def mapping_from_table(table: Mapping[str, Any], device_name: str = "",
                       origin: str = "gamepad") -> PadMapping:
    """The mapping for a device: its preset (named in the table or guessed from the
    device's name) with the table's keys applied. ConfigError names a bad key."""
    for key in table:
        if key not in TABLE_KEYS:
            raise ConfigError(f"{origin}.{key}: unknown key (known: {', '.join(TABLE_KEYS)})")
    preset = table.get("preset") or preset_for(device_name)
    if preset not in PRESETS:
        raise ConfigError(f"{origin}.preset: unknown preset {preset!r} "
                          f"(known: {', '.join(PRESETS)})")
    m = PRESETS[preset]
    if "deadzone" in table:
        dz = _number(f"{origin}.deadzone", table["deadzone"])
        if not 0.0 <= dz < 1.0:
            raise ConfigError(f"{origin}.deadzone: must be 0 or more and below 1, got {dz}")
        m = replace(m, deadzone=dz)
    if "deadman_button" in table:
        m = replace(m, deadman=_code(f"{origin}.deadman_button", table["deadman_button"],
                                     BUTTON_CODES))
    if "turbo_button" in table:
        t = table["turbo_button"]
        m = replace(m, turbo=None if t == "" else _code(f"{origin}.turbo_button", t,
                                                        BUTTON_CODES))
    if "require_deadman" in table:
        if not isinstance(table["require_deadman"], bool):
            raise ConfigError(f"{origin}.require_deadman: want true or false")
        m = replace(m, require_deadman=table["require_deadman"])
    for a in _AXES:
        axis: AxisMap = getattr(m, a)
        if f"axis_{a}" in table:
            axis = replace(axis, code=_code(f"{origin}.axis_{a}", table[f"axis_{a}"],
                                            ABS_CODES))
        if f"scale_{a}" in table:
            axis = replace(axis, scale=_number(f"{origin}.scale_{a}", table[f"scale_{a}"]))
        if f"turbo_scale_{a}" in table:
            axis = replace(axis, turbo_scale=_number(f"{origin}.turbo_scale_{a}",
                                                     table[f"turbo_scale_{a}"]))
        m = replace(m, vx=axis) if a == "vx" else replace(m, vy=axis) if a == "vy" \
            else replace(m, wz=axis)
    return m
