"""The corrected config as TOML text: a config file's numbers edited in place (comments
and layout kept), its ``[sim]`` table set, a whole config rendered for the demo base
(which has no file), and checks that what was written loads with the intended values.

Pure: text in, text out (no file I/O).
"""

from __future__ import annotations

import math
import re
import sys
from dataclasses import dataclass, fields

from omnican.analysis.calibration.correction import Correction
from omnican.config import (
    SCHEMA,
    WHEEL_EDS,
    ChassisConfig,
    ChassisSettings,
    SimTruth,
    parse_config,
)
from omnican.errors import ConfigError
from omnican.plan.health import CONFIG_KEYS as HEALTH_CONFIG_KEYS

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib  # type: ignore[import-not-found,unused-ignore]


_HEADER = re.compile(r"^\s*\[(?P<array>\[)?\s*(?P<name>[^\[\]]+?)\s*\]\]?\s*(#.*)?$")
_KEY_VALUE = re.compile(
    r"^(?P<pre>\s*(?P<key>[A-Za-z0-9_-]+)\s*=\s*)"
    r"(?P<value>[+-]?(?:\d[\d_]*)(?:\.\d[\d_]*)?(?:[eE][+-]?\d[\d_]*)?)"
    r"(?P<post>\s*(?:#.*)?)$"
)


def format_number(value: float, digits: int = 7) -> str:
    """A TOML float with ``digits`` significant digits (``0.1938``, ``21487.35``)."""
    return repr(float(f"{value:.{digits}g}"))


@dataclass(frozen=True)
class ConfigEdit:
    """One number :func:`edit_config` changed: ``key`` in ``[chassis]`` (``wheel`` None)
    or in the ``wheel``-th ``[[wheel]]`` table (0-based), from ``old`` to ``new`` as
    written."""

    wheel: int | None
    key: str
    old: float
    new: float


def edit_config_text(text: str, correction: Correction) -> str:
    """:func:`edit_config`'s new text."""
    return edit_config(text, correction)[0]


def edit_config(text: str, correction: Correction) -> tuple[str, list[ConfigEdit]]:
    """The config file ``text`` with the correction applied, comments and layout kept:
    ``velocity_scale`` and ``position_scale`` (or ``wheel_radius``) of each ``[[wheel]]``
    and every ``base_radius``; and the numbers it changed, in the file's own terms.
    Only lines of the form ``key = number`` are edited; use :func:`check_edited` to
    confirm the result loads with the intended values."""
    edits: list[ConfigEdit] = []
    lines = text.splitlines(keepends=True)
    section: str | None = None
    wheel = -1
    out = []
    for line in lines:
        body = line.rstrip("\r\n")
        ending = line[len(body):]
        header = _HEADER.match(body)
        if header:
            section = header.group("name").strip()
            if header.group("array") and section == "wheel":
                wheel += 1
            out.append(line)
            continue
        m = _KEY_VALUE.match(body)
        factor = None
        if m and section == "chassis" and m.group("key") == "base_radius":
            factor = correction.radius_factor
        elif m and section == "wheel" and 0 <= wheel < len(correction.wheel_factors):
            s = correction.wheel_factors[wheel]
            factor = {"velocity_scale": s, "position_scale": s, "wheel_radius": 1.0 / s,
                      "base_radius": correction.radius_factor}.get(m.group("key"))
        if m is None or factor is None:
            out.append(line)
            continue
        old = float(m.group("value").replace("_", ""))
        new = format_number(old * factor, correction.digits)
        edits.append(ConfigEdit(wheel if section == "wheel" else None, m.group("key"), old,
                                float(new)))
        out.append(f"{m.group('pre')}{new}{m.group('post')}{ending}")
    return "".join(out), edits


#: Significant digits of a ``[sim]`` table's numbers: the simulated base stays the same
#: base to well below what one encoder count resolves.
SIM_DIGITS = 10
_SIM_COMMENT = "# the simulated base 'omnican calibrate --sim' drives, as it really is"


def _sim_lines(truth: SimTruth) -> list[str]:
    lines = []
    if truth.base_radius is not None:
        lines.append(f"base_radius = {format_number(truth.base_radius, SIM_DIGITS)}")
    scale = truth.position_scale
    if scale is not None:
        text = (format_number(scale[0], SIM_DIGITS) if len(set(scale)) == 1 else
                "[" + ", ".join(format_number(v, SIM_DIGITS) for v in scale) + "]")
        lines.append(f"position_scale = {text}")
    return lines


def set_sim_table(text: str, truth: SimTruth) -> str:
    """The config file ``text`` with its ``[sim]`` table saying ``truth``: the numbers of
    the table it has replaced (its comments and other lines kept), or the table appended."""
    lines = text.splitlines(keepends=True)
    headers = [(i, m.group("name").strip()) for i, m in
               ((i, _HEADER.match(line.rstrip("\r\n"))) for i, line in enumerate(lines)) if m]
    start = next((i for i, name in headers if name == "sim"), None)
    if start is None:
        head = text if not text or text.endswith("\n") else text + "\n"
        return head + "\n".join(["", f"[sim]  {_SIM_COMMENT}", *_sim_lines(truth)]) + "\n"
    end = next((i for i, _ in headers if i > start), len(lines))
    kept = [line for line in lines[start + 1:end]
            if not re.match(r"\s*(base_radius|position_scale)\s*=", line)]
    new = [line + "\n" for line in _sim_lines(truth)]
    return "".join([*lines[:start + 1], *new, *kept, *lines[end:]])


def check_sim(text: str, truth: SimTruth, origin: str = "config") -> None:
    """Raise ConfigError unless ``text`` loads with the ``[sim]`` table ``truth``."""
    got = parse_config(tomllib.loads(text), origin, check_eds=False).sim or SimTruth()
    want = [truth.base_radius, *(truth.position_scale or ())]
    have = [got.base_radius, *(got.position_scale or ())]
    if len(want) != len(have) or not all(
            (a is None and b is None) or (a is not None and b is not None
                                          and math.isclose(a, b, rel_tol=1e-8))
            for a, b in zip(want, have, strict=False)):
        raise ConfigError(f"could not write the [sim] table of {origin} automatically: give "
                          "it " + ", ".join(_sim_lines(truth)) + " by hand")


def check_edited(text: str, expected: ChassisConfig, origin: str = "config",
                 rel_tol: float = 1e-6) -> None:
    """Raise ConfigError unless ``text`` loads with ``expected``'s scales and radii (to
    ``rel_tol``: give about 10**(1 - digits) for numbers written with ``digits``)."""
    try:
        got = parse_config(tomllib.loads(text), origin, check_eds=False)
    except (tomllib.TOMLDecodeError, ConfigError) as exc:
        raise ConfigError(f"the corrected {origin} does not load: {exc}") from None
    pairs = [("chassis.base_radius", got.chassis.base_radius, expected.chassis.base_radius)]
    if len(got.wheels) != len(expected.wheels):
        raise ConfigError(f"the corrected {origin} has {len(got.wheels)} wheels, expected "
                          f"{len(expected.wheels)}")
    for i, (wa, wb) in enumerate(zip(got.wheels, expected.wheels, strict=True)):
        pairs += [(f"wheel[{i}].velocity_scale", wa.velocity_scale, wb.velocity_scale),
                  (f"wheel[{i}].position_scale", wa.position_scale, wb.position_scale),
                  (f"wheel[{i}].base_radius", wa.base_radius or 0.0, wb.base_radius or 0.0)]
    for name, a, b in pairs:
        if not math.isclose(a, b, rel_tol=rel_tol, abs_tol=1e-12):
            raise ConfigError(f"could not correct {name} in {origin} automatically (it is not "
                              f"a plain 'key = number' line): set it to {format_number(b)} "
                              "by hand")


def render_config(cfg: ChassisConfig, comment: str = "", digits: int = 7) -> str:
    """A TOML config equivalent to ``cfg`` (for a config that has no file: the demo
    base). Chassis settings are written where they differ from the defaults; the
    [bus] table is left out (give the bus on the command line or in python-can's config)."""
    lines = [f"# {line}" for line in comment.splitlines()] if comment else []
    lines += ["# [bus] is not written: use --interface/--channel or python-can's configuration.",
              "", "[chassis]"]
    c = cfg.chassis
    if c.layout is not None:
        lines.append(f'layout = "{c.layout}"')
    lines.append(f"base_radius = {format_number(c.base_radius, digits)}")
    for f in fields(ChassisSettings):
        if f.name in ("layout", "base_radius"):
            continue
        value = getattr(c, f.name)
        if value == c.default_of(f.name) or value is None or value == math.inf:
            continue
        if f.name == "mode":
            lines.append(f'mode = "{value.short}"')
        elif isinstance(value, int):
            lines.append(f"{f.name} = {value}")
        else:
            lines.append(f"{f.name} = {format_number(value)}")
    for w in cfg.wheels:
        lines += ["", "[[wheel]]", f"node_id = {w.node_id}"]
        if w.axis:
            lines.append(f"axis = {w.axis}")
        if w.eds != WHEEL_EDS:
            lines.append(f"eds = {_toml_string(str(w.eds))}")
        lines.append(f"velocity_scale = {format_number(w.velocity_scale, digits)}")
        lines.append(f"position_scale = {format_number(w.position_scale, digits)}")
        for key in ("angle_deg", "drive_angle_deg", "base_radius"):
            value = getattr(w, key)
            if value is not None:
                lines.append(f"{key} = {format_number(value)}")
        if w.mode is not None and w.mode != c.mode:
            lines.append(f'mode = "{w.mode.short}"')
        for key in HEALTH_CONFIG_KEYS:  # what the drive reports
            value = getattr(w, key)
            if value == SCHEMA["wheel"][key].default:
                continue
            # None for an object: none (what "" says in a config)
            lines.append(f"{key} = " + (_toml_string(value or "") if not isinstance(
                value, float) else format_number(value)))
        for write in w.sdo_writes:
            lines += ["[[wheel.sdo]]", f"object = {_toml_string(write.object)}",
                      f"value = {_toml_value(write.value)}"]
            if write.type is not None:
                lines.append(f'type = "{write.type}"')
    if cfg.sim is not None:
        lines += ["", f"[sim]  {_SIM_COMMENT}", *_sim_lines(cfg.sim)]
    for table, settings in (("power", cfg.power), ("estop", cfg.estop)):
        if settings is None:
            continue
        lines += ["", f"[{table}]"]
        for f in fields(settings):
            value = getattr(settings, f.name)
            if value is not None and (f.name == "bit" or value != SCHEMA[table][f.name].default):
                lines.append(f"{f.name} = {_toml_value(value)}")
    return "\n".join(lines) + "\n"


def _toml_value(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return _toml_string(value)
    if isinstance(value, int):
        return str(value)
    assert isinstance(value, float)
    return format_number(value)


def _toml_string(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'
