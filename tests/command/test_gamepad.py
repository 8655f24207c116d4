"""The gamepad mapping (pure): events -> twist, deadman, turbo, deadzone, config table."""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from omnican.command.gamepad import (
    ABS_CODES,
    BUTTON_CODES,
    EV_ABS,
    EV_KEY,
    EV_SYN,
    PRESETS,
    SYN_DROPPED,
    TABLE_DEFAULTS,
    TABLE_KEYS,
    PadState,
    apply_deadzone,
    mapping_from_table,
    normalise,
    preset_for,
)
from omnican.errors import ConfigError

X, Y, RX = ABS_CODES["ABS_X"], ABS_CODES["ABS_Y"], ABS_CODES["ABS_RX"]
LB, RB = BUTTON_CODES["BTN_TL"], BUTTON_CODES["BTN_TR"]
XPAD = {X: (-32768, 32767), Y: (-32768, 32767), RX: (-32768, 32767)}
raw = st.integers(-32768, 32767)
unit = st.floats(-1.0, 1.0)
deadzones = st.floats(0.0, 0.9)


def pad(**table: object) -> PadState:
    return PadState(mapping_from_table(table, "Microsoft X-Box 360 pad"), XPAD)


@given(value=raw, lo=st.integers(-40000, 0), span=st.integers(1, 80000))
def test_normalise_stays_in_range(value: int, lo: int, span: int) -> None:
    v = normalise(value, lo, lo + span)
    assert -1.0 <= v <= 1.0
    assert normalise(lo, lo, lo + span) == -1.0 and normalise(lo + span, lo, lo + span) == 1.0


@given(v=unit, dz=deadzones)
def test_deadzone_is_zero_inside_and_keeps_sign_and_ends(v: float, dz: float) -> None:
    out = apply_deadzone(v, dz)
    assert -1.0 <= out <= 1.0
    if abs(v) <= dz:
        assert out == 0.0
    else:
        assert math.copysign(1.0, out) == math.copysign(1.0, v) or out == 0.0
    assert apply_deadzone(1.0, dz) == 1.0 and apply_deadzone(-1.0, dz) == -1.0


@given(a=unit, b=unit, dz=deadzones)
def test_deadzone_is_monotonic_and_continuous(a: float, b: float, dz: float) -> None:
    lo, hi = sorted((a, b))
    assert apply_deadzone(lo, dz) <= apply_deadzone(hi, dz)
    # Lipschitz with constant 1/(1-dz): no jump at the edge of the zone
    assert apply_deadzone(hi, dz) - apply_deadzone(lo, dz) <= (hi - lo) / (1 - dz) + 1e-12


@given(x=raw, y=raw, rx=raw, turbo=st.booleans())
def test_nothing_moves_without_the_deadman(x: int, y: int, rx: int, turbo: bool) -> None:
    s = pad()
    for code, value in ((X, x), (Y, y), (RX, rx)):
        s.feed(EV_ABS, code, value)
    if turbo:
        s.feed(EV_KEY, RB, 1)
    assert s.command().is_zero()
    s.feed(EV_KEY, LB, 1)
    held = s.command()
    s.feed(EV_KEY, LB, 0)  # released: zero at once, whatever the sticks say
    assert s.command().is_zero()
    s.feed(EV_KEY, LB, 2)  # autorepeat counts as held
    assert s.command() == held


@given(x=raw, y=raw, rx=raw)
def test_sticks_map_to_rep103_directions(x: int, y: int, rx: int) -> None:
    s = pad()
    s.feed(EV_KEY, LB, 1)
    for code, value in ((X, x), (Y, y), (RX, rx)):
        s.feed(EV_ABS, code, value)
    t = s.command()
    m = PRESETS["xbox"]
    # stick up (evdev: negative y) -> forward; stick left -> +vy; right stick left -> CCW
    assert t.vx * normalise(y, -32768, 32767) <= 0
    assert t.vy * normalise(x, -32768, 32767) <= 0
    assert t.wz * normalise(rx, -32768, 32767) <= 0
    assert abs(t.vx) <= abs(m.vx.scale) and abs(t.vy) <= abs(m.vy.scale)
    assert abs(t.wz) <= abs(m.wz.scale)


def test_full_deflection_and_turbo() -> None:
    s = pad()
    s.feed(EV_KEY, LB, 1)
    s.feed(EV_ABS, Y, -32768)  # full forward
    s.feed(EV_ABS, RX, 32767)  # full right: clockwise
    assert s.command().vx == pytest.approx(0.3)
    assert s.command().wz == pytest.approx(-1.0)
    s.feed(EV_KEY, RB, 1)
    assert s.command().vx == pytest.approx(0.8)
    assert s.command().wz == pytest.approx(-2.0)


def test_dropped_events_and_unplug_stop() -> None:
    s = pad()
    s.feed(EV_KEY, LB, 1)
    s.feed(EV_ABS, Y, -32768)
    assert not s.command().is_zero()
    s.feed(EV_SYN, SYN_DROPPED, 0)
    assert s.command().is_zero()
    s.feed(EV_KEY, LB, 1)
    s.feed(EV_ABS, Y, -32768)
    s.unplugged()
    assert s.command().is_zero() and not s.deadman


@pytest.mark.parametrize(("name", "preset"), [
    ("Microsoft X-Box 360 pad", "xbox"), ("Xbox Wireless Controller", "xbox"),
    ("Sony Interactive Entertainment Wireless Controller", "ps"),
    ("DualSense Wireless Controller", "ps"), ("Logitech Gamepad F710", "f710"),
])
def test_presets_by_device_name(name: str, preset: str) -> None:
    assert preset_for(name) == preset


def test_table_overrides() -> None:
    m = mapping_from_table({"preset": "ps", "deadzone": 0.2, "deadman_button": "BTN_SOUTH",
                            "turbo_button": "", "axis_wz": "ABS_Z", "scale_vx": -0.5,
                            "require_deadman": True})
    assert (m.name, m.deadzone, m.deadman, m.turbo) == ("ps", 0.2, 0x130, None)
    assert (m.wz.code, m.vx.scale) == (ABS_CODES["ABS_Z"], -0.5)


@pytest.mark.parametrize("preset", list(PRESETS))
def test_the_table_reference_gives_the_defaults(preset: str) -> None:
    m = mapping_from_table({"preset": preset})
    assert TABLE_DEFAULTS["deadzone"] == f"{m.deadzone:g}"
    assert TABLE_DEFAULTS["require_deadman"] == str(m.require_deadman).lower()
    assert set(TABLE_DEFAULTS) <= set(TABLE_KEYS)


def test_the_docs_gamepad_table_is_the_ps_preset_as_it_is() -> None:
    """The [gamepad] example of docs/getting-started.md writes the defaults out: they are
    the preset's."""
    from omnican.config import tomllib

    page = (Path(__file__).resolve().parents[2] / "docs" / "getting-started.md").read_text()
    block = re.search(r"```toml\n(\[gamepad\]\n.*?)```", page, re.S)
    assert block is not None
    table = tomllib.loads(block.group(1))["gamepad"]
    assert table["preset"] == "ps"
    assert mapping_from_table(table) == PRESETS["ps"]


@pytest.mark.parametrize(("table", "message"), [
    ({"preset": "wii"}, "gamepad.preset: unknown preset 'wii'"),
    ({"deadzone": 1.5}, "gamepad.deadzone: must be 0 or more and below 1"),
    ({"axis_vx": "ABS_FOO"}, "gamepad.axis_vx: unknown code 'ABS_FOO'"),
    ({"scale_wz": "fast"}, "gamepad.scale_wz: want a finite number"),
    ({"speed": 1}, "gamepad.speed: unknown key"),
])
def test_bad_table_is_a_config_error(table: dict[str, object], message: str) -> None:
    with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace(")", r"\)")):
        mapping_from_table(table)


def test_codes_are_the_kernels() -> None:
    ecodes = pytest.importorskip("evdev.ecodes", reason="evdev not installed "
                                 "(pip install 'omnican[gamepad]')")
    for name, code in {**ABS_CODES, **BUTTON_CODES}.items():
        assert getattr(ecodes, name) == code, name
    assert (EV_SYN, EV_KEY, EV_ABS, SYN_DROPPED) == (ecodes.EV_SYN, ecodes.EV_KEY,
                                                     ecodes.EV_ABS, ecodes.SYN_DROPPED)


def test_the_pad_drives_through_the_shared_teleop_model() -> None:
    """The pad's twist goes through TeleopModel: the same twist, the keyboard's speed keys
    scale it, and a released deadman zeroes it."""
    from types import SimpleNamespace

    from omnican import default_config
    from omnican.gamepad.device import apply, teleop_model_for

    s = pad()
    front = SimpleNamespace(state=s, command=s.command)
    model = teleop_model_for(default_config(), s.mapping)
    s.feed(EV_KEY, LB, 1)
    s.feed(EV_ABS, Y, -32768)  # full forward
    s.feed(EV_ABS, RX, 16384)  # half right
    apply(front, model, 1.0)  # type: ignore[arg-type]
    assert model.command(1.0).vx == pytest.approx(s.command().vx)
    assert model.command(1.0).wz == pytest.approx(s.command().wz, abs=1e-3)
    s.feed(EV_KEY, RB, 1)  # turbo
    apply(front, model, 1.1)  # type: ignore[arg-type]
    assert model.command(1.1).vx == pytest.approx(0.8)
    model.press("z", 1.2)  # the keyboard's "all speeds -10 %"
    apply(front, model, 1.3)  # type: ignore[arg-type]
    assert model.command(1.3).vx == pytest.approx(0.72)
    s.feed(EV_KEY, LB, 0)
    apply(front, model, 1.4)  # type: ignore[arg-type]
    assert model.command(1.4).is_zero()
