"""Gamepad -> body velocity, after ROS ``teleop_twist_joy`` (pure: no device, no I/O).

A deadman (enable) button must be held for any motion; a turbo button switches to the
turbo scales. Holonomic by default: left stick forward/back -> vx, left/right -> vy, right
stick left/right -> wz. Sticks are normalised to [-1, 1] from the device's own axis range
(evdev ``absinfo``), a deadzone around the centre reads as 0 and the rest is rescaled so
the output stays continuous; each axis has a scale (m/s or rad/s at full deflection,
negative to flip it).

Codes are Linux input event codes (``linux/input-event-codes.h``, what evdev reports), so
a mapping is plain data. The ``[gamepad]`` table is the config's like every other: its
keys, defaults, codes and presets (:data:`PRESETS`: the pads tested with the kernel's
drivers, xpad: Xbox and Logitech F710 in X mode; hid-playstation: PS4/PS5) are declared
in :mod:`omnican.config.schema`, and a table overrides any part of a preset
(:func:`mapping_from_table`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

from omnican.config import (
    GAMEPAD_AXES,
    GAMEPAD_BUTTONS,
    GAMEPAD_PRESETS,
    SCHEMA,
    gamepad_values,
    schema_defaults,
)
from omnican.config.schema import default_text
from omnican.core.kinematics import Twist

# linux/input-event-codes.h (stable kernel ABI)
EV_SYN, EV_KEY, EV_ABS = 0x00, 0x01, 0x03
SYN_DROPPED = 3
#: Stick axes and buttons by name (the ``[gamepad]`` keys name them).
ABS_CODES: dict[str, int] = GAMEPAD_AXES
BUTTON_CODES: dict[str, int] = GAMEPAD_BUTTONS

_DEFAULTS = schema_defaults("gamepad")
DEFAULT_DEADZONE: float = _DEFAULTS["deadzone"]  # ROS joy's default
DEFAULT_REQUIRE_DEADMAN: bool = _DEFAULTS["require_deadman"]


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


def _preset(name: str) -> PadMapping:
    """Preset ``name``: its codes (:data:`GAMEPAD_PRESETS`), the schema's defaults."""
    codes = GAMEPAD_PRESETS[name]

    def axis(a: str) -> AxisMap:
        return AxisMap(ABS_CODES[codes[f"axis_{a}"]], _DEFAULTS[f"scale_{a}"],
                       _DEFAULTS[f"turbo_scale_{a}"])

    return PadMapping(name=name, vx=axis("vx"), vy=axis("vy"), wz=axis("wz"),
                      deadman=BUTTON_CODES[codes["deadman_button"]],
                      turbo=BUTTON_CODES[codes["turbo_button"]])


#: Default mappings. Deadman: the left shoulder button (LB, L1); turbo: the right one.
PRESETS: dict[str, PadMapping] = {name: _preset(name) for name in GAMEPAD_PRESETS}


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
TABLE_KEYS: dict[str, str] = {key: spec.doc for key, spec in SCHEMA["gamepad"].items()}
#: Defaults of the ``[gamepad]`` keys that do not depend on the preset (README's reference).
TABLE_DEFAULTS: dict[str, str] = {key: default_text(spec)
                                  for key, spec in SCHEMA["gamepad"].items()
                                  if spec.default is not None}


def mapping_from_table(table: Mapping[str, Any], device_name: str = "",
                       origin: str = "gamepad") -> PadMapping:
    """The mapping for a device: its preset (named in the table or guessed from the
    device's name) with the table's keys applied. ConfigError names a bad key
    (``origin.key``), as the config's check does (:func:`omnican.config.gamepad_values`)."""
    values = gamepad_values(table, origin)
    m = PRESETS[values.get("preset") or preset_for(device_name)]
    if "deadzone" in values:
        m = replace(m, deadzone=values["deadzone"])
    if "deadman_button" in values:
        m = replace(m, deadman=values["deadman_button"])
    if "turbo_button" in values:
        m = replace(m, turbo=values["turbo_button"])
    if "require_deadman" in values:
        m = replace(m, require_deadman=values["require_deadman"])
    for a in _AXES:
        axis: AxisMap = getattr(m, a)
        if f"axis_{a}" in values:
            axis = replace(axis, code=values[f"axis_{a}"])
        if f"scale_{a}" in values:
            axis = replace(axis, scale=values[f"scale_{a}"])
        if f"turbo_scale_{a}" in values:
            axis = replace(axis, turbo_scale=values[f"turbo_scale_{a}"])
        m = replace(m, vx=axis) if a == "vx" else replace(m, vy=axis) if a == "vy" \
            else replace(m, wz=axis)
    return m
