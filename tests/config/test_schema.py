"""The schema: [gamepad] a table of it like every other, and the ranges its keys declare."""

from __future__ import annotations

import math
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from omnican.config import (
    GAMEPAD_AXES,
    GAMEPAD_BUTTONS,
    GAMEPAD_PRESETS,
    SCHEMA,
    Key,
    gamepad_values,
    parse_config,
)
from omnican.errors import ConfigError

WHEELS = [{"node_id": n, "velocity_scale": 1.0, "position_scale": 2.0} for n in (1, 2, 3)]
DOC = {"chassis": {"layout": "b21", "base_radius": 0.19}, "wheel": WHEELS}


def test_the_gamepad_table_parses_into_the_config_as_given() -> None:
    table = {"preset": "ps", "deadzone": 0.1, "turbo_button": ""}
    cfg = parse_config({**DOC, "gamepad": table}, check_eds=False)
    assert cfg.gamepad == table
    assert parse_config(DOC, check_eds=False).gamepad is None


def test_every_preset_names_codes_the_schema_knows() -> None:
    """A preset gives every key that names a code, and only such keys of [gamepad]."""
    code_keys = {k for k, spec in SCHEMA["gamepad"].items()
                 if k.startswith(("axis_", "deadman_", "turbo_button"))}
    for name, keys in GAMEPAD_PRESETS.items():
        assert set(keys) == code_keys, name
        assert gamepad_values({"preset": name, **keys})["preset"] == name
        for key, code in keys.items():
            assert code in (GAMEPAD_AXES if key.startswith("axis_") else GAMEPAD_BUTTONS)


_CODE_NAMES = st.sampled_from(sorted(GAMEPAD_BUTTONS))
_AXIS_NAMES = st.sampled_from(sorted(GAMEPAD_AXES))
_SCALES = st.floats(-100.0, 100.0)
_TABLES = st.fixed_dictionaries({}, optional={
    "preset": st.sampled_from(["", *GAMEPAD_PRESETS]),
    "deadzone": st.one_of(st.floats(0.0, 1.0, exclude_max=True), st.just(0)),
    "deadman_button": st.one_of(_CODE_NAMES, _CODE_NAMES.map(str.lower),
                                st.integers(0, 0x2FF)),
    "turbo_button": st.one_of(_CODE_NAMES, st.just("")),
    "require_deadman": st.booleans(),
    **{f"axis_{a}": st.one_of(_AXIS_NAMES, st.integers(0, 0x3F)) for a in ("vx", "vy", "wz")},
    **{f"{s}_{a}": _SCALES for s in ("scale", "turbo_scale") for a in ("vx", "vy", "wz")},
})


@given(table=_TABLES)
def test_a_gamepad_table_within_the_schema_is_taken_as_values(table: dict[str, Any]) -> None:
    """Whatever keys a good table gives come back as values (codes as numbers, "" turbo
    as none, numbers as floats), and a config with it parses."""
    values = gamepad_values(table)
    assert set(values) == set(table) - ({"preset"} if table.get("preset") == "" else set())
    for key, given_value in table.items():
        if key == "preset" and not given_value:
            continue
        value = values[key]
        if key.startswith("axis_") or key.endswith("_button"):
            codes = GAMEPAD_AXES if key.startswith("axis_") else GAMEPAD_BUTTONS
            expected = (None if given_value == "" else given_value
                        if isinstance(given_value, int) else codes[given_value.upper()])
            assert value == expected, key
        elif isinstance(given_value, (bool, str)):
            assert value == given_value, key
        else:
            assert value == float(given_value) and isinstance(value, float), key
    assert parse_config({**DOC, "gamepad": table}, check_eds=False).gamepad == table


@pytest.mark.parametrize(("table", "message"), [
    ({"preset": [1]}, "gamepad.preset: unknown preset [1]"),
    ({"deadzone": 1.0}, "gamepad.deadzone: must be 0 or more and below 1, got 1.0"),
    ({"deadzone": -0.1}, "gamepad.deadzone: must be 0 or more and below 1, got -0.1"),
    ({"scale_vx": math.inf}, "gamepad.scale_vx: want a finite number, got inf"),
    ({"deadman_button": -1}, "gamepad.deadman_button: must not be negative, got -1"),
    ({"turbo_button": True}, "gamepad.turbo_button: want a code name or number, got True"),
    ({"require_deadman": 1}, "gamepad.require_deadman: want true or false"),
    ({"deadzon": 0.1}, "gamepad.deadzon: unknown key 'deadzon' (did you mean 'deadzone'?)"),
])
def test_a_bad_gamepad_table_is_one_error_naming_the_key(table: dict[str, Any],
                                                         message: str) -> None:
    with pytest.raises(ConfigError) as info:
        gamepad_values(table)
    assert str(info.value).startswith(message), str(info.value)
    with pytest.raises(ConfigError) as info:
        parse_config({**DOC, "gamepad": table}, origin="robot.toml", check_eds=False)
    assert str(info.value).startswith(f"robot.toml: {message}"), str(info.value)


def test_a_gamepad_table_that_is_not_a_table_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"^robot\.toml: gamepad: must be a table, got str"):
        parse_config({**DOC, "gamepad": "xbox"}, origin="robot.toml", check_eds=False)


@given(lo=st.floats(-1e3, 1e3), span=st.floats(1e-3, 1e3), x=st.floats(allow_nan=False),
       open_high=st.booleans(), signed=st.booleans())
def test_a_key_refuses_a_number_beyond_its_range_and_says_the_range(
        lo: float, span: float, x: float, open_high: bool, signed: bool) -> None:
    hi = lo + span
    if signed:
        lo = abs(lo)
        hi = lo + span
    key = Key((int, float), None, "", range=(lo, hi), signed=signed, open_high=open_high)
    v = abs(x) if signed else x
    within = lo <= v < hi or (v == hi and not open_high)
    problem = key.out_of_range(x)
    assert (problem is None) == within
    if problem is not None:
        assert problem.startswith(f"must be {key.range_text()}, got ")
    assert key.out_of_range("text") is None and key.out_of_range(True) is None


def test_a_range_open_at_its_top_says_so() -> None:
    key = SCHEMA["gamepad"]["deadzone"]
    assert key.range_text() == "0 or more and below 1"
    assert key.out_of_range(0.0) is None and key.out_of_range(0.999) is None
    assert key.out_of_range(1) == "must be 0 or more and below 1, got 1"
