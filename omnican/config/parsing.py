"""TOML -> :class:`~omnican.config.model.ChassisConfig`: every table checked against
:data:`~omnican.config.schema.SCHEMA`, the first problem a :class:`ConfigError` whose
message names the key, e.g. ``robot.toml: wheel[2].node_id: must be 1-127, got 200``.
The ``[[wheel]]`` tables and their EDS files are :mod:`omnican.config.wheels`'.

No I/O beyond reading the TOML file and parsing the EDS files it names.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Iterable, Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

from omnican.config.front_ends import read_tables
from omnican.config.imu import parse_imu, parse_sim_gyro
from omnican.config.model import (
    ChassisConfig,
    ChassisSettings,
    EstopSettings,
    FusionSettings,
    PowerSettings,
    SimSlipSettings,
    SimSurface,
    SimTruth,
    WheelConfig,
)
from omnican.config.reader import Reader, short, suggest
from omnican.config.schema import (
    BUS_KEYS,
    CHASSIS_SCALED,
    GAMEPAD_AXES,
    GAMEPAD_BUTTONS,
    GAMEPAD_PRESETS,
    LIFTED_WHEEL,
    LIVE_LIMITS,
    MAX_RT_PRIORITY,
    NUMBER,
    PDO_MAPPINGS,
    SCHEMA,
)
from omnican.config.wheels import check_eds_files, check_wheels, parse_wheel
from omnican.core.kinematics import LAYOUTS
from omnican.core.limits import MAX_STOP_S, stop_decel_floor, top_speeds
from omnican.errors import ConfigError
from omnican.protocol import heartbeat
from omnican.protocol.sync_producer import SYNC_MODES

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib  # type: ignore[import-not-found,unused-ignore]



def sections() -> tuple[str, ...]:
    """The tables of a config: [bus] (free-form, passed to can.Bus) and SCHEMA's (the
    front ends' among them)."""
    return ("bus", *(section for section in SCHEMA if "." not in section))

_UNLIMITED_OK = ("max_speed", "max_angular_speed")  # inf: no such limit
_SCALED = CHASSIS_SCALED


def _chassis_settings(table: Mapping[str, Any]) -> ChassisSettings:
    """The settings of a checked ``[chassis]`` table but its mode: numbers as floats
    (TOML's 100 is an int); a scaled key not given is left to ChassisSettings to derive."""
    values: dict[str, Any] = {}
    for key, spec in SCHEMA["chassis"].items():
        value = table[key]
        if key == "mode" or (value is None and spec.scaled is not None):
            continue
        values[key] = float(value) if spec.types == NUMBER and value is not None else value
    return ChassisSettings(**values)


def parse_config(data: Mapping[str, Any], origin: str = "config", base_dir: Path | None = None,
                 check_eds: bool = True) -> ChassisConfig:
    """Validate a parsed TOML document into a :class:`ChassisConfig`."""
    r = Reader(origin)
    known = sections()
    for key in data:
        if key not in known:
            raise r.fail(key, f"unknown section {key!r}{suggest(key, known)}")
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
    settings = replace(settings, mode=r.mode("chassis.mode", c["mode"]))

    raw_wheels = data.get("wheel")
    if raw_wheels is None:
        raise r.fail("wheel", "missing: give one [[wheel]] table per wheel")
    if not isinstance(raw_wheels, list):
        raise r.fail("wheel", "must be an array of tables ([[wheel]])")
    wheels = tuple(
        parse_wheel(r, i, w, settings, base_dir) for i, w in enumerate(raw_wheels)
    )
    check_wheels(r, settings, wheels)
    front_ends = read_tables(r, data, base_dir)
    gamepad = _gamepad_table(r, data["gamepad"]) if "gamepad" in data else None
    power = _parse_power(r, data["power"]) if "power" in data else None
    estop = _parse_estop(r, data["estop"], wheels) if "estop" in data else None
    sim = _parse_sim(r, data["sim"], len(wheels)) if "sim" in data else None
    imu = parse_imu(r, data["imu"], base_dir) if "imu" in data else None
    fusion = _parse_fusion(r, data["fusion"]) if "fusion" in data else None
    cfg = ChassisConfig(chassis=settings, wheels=wheels, bus=bus, power=power, estop=estop,
                        sim=sim, gamepad=gamepad, front_ends=front_ends, imu=imu, fusion=fusion)
    try:
        cfg.kinematics()
    except ConfigError as exc:
        raise r.fail("wheel geometry", str(exc)) from None
    _check_stop_bound(r, cfg, data["chassis"].keys())
    if check_eds:
        check_eds_files(cfg, r.origin)
    return cfg


def _parse_sim(r: Reader, table: Any, n_wheels: int) -> SimTruth:
    gyro = slip = None
    if isinstance(table, dict) and ("gyro" in table or "slip" in table):
        table = dict(table)
        if "gyro" in table:  # [sim.gyro]: omnican.config.imu's
            gyro = parse_sim_gyro(r, table.pop("gyro"))
        if "slip" in table:
            slip = _parse_sim_slip(r, table.pop("slip"), n_wheels)
    t = r.table("sim", table, "sim")
    scale = t["position_scale"]
    values = None if scale is None else _per_wheel(r, "sim", "position_scale", scale, n_wheels)
    radius = t["base_radius"]
    return SimTruth(None if radius is None else float(radius), values, gyro, slip)


def _parse_sim_slip(r: Reader, table: Any, n_wheels: int) -> SimSlipSettings:
    """The ``[sim.slip]`` table and its ``[[sim.slip.surface]]`` patches."""
    surfaces_raw: Any = []
    if isinstance(table, dict) and "surface" in table:
        table = dict(table)
        surfaces_raw = table.pop("surface")
        if not isinstance(surfaces_raw, list) or not all(
                isinstance(x, dict) for x in surfaces_raw):
            raise r.fail("sim.slip.surface", "must be an array of tables "
                         "([[sim.slip.surface]])")
    t = r.table("sim.slip", table, "sim.slip")
    surfaces = []
    for i, raw in enumerate(surfaces_raw):
        where = f"sim.slip.surface[{i}]"
        f = r.table("sim.slip.surface", raw, where)
        surfaces.append(SimSurface(float(f["x0"]), float(f["y0"]), float(f["x1"]),
                                   float(f["y1"]), _per_wheel(r, "sim.slip.surface", "ratio",
                                                              f["ratio"], n_wheels, where)))
    return SimSlipSettings(
        _per_wheel(r, "sim.slip", "ratio", t["ratio"], n_wheels),
        _per_wheel(r, "sim.slip", "roller", t["roller"], n_wheels),
        float(t["ramp_grade_deg"]), float(t["ramp_downhill_deg"]), float(t["ramp_creep"]),
        tuple(surfaces))


def _per_wheel(r: Reader, section: str, key: str, value: Any, n_wheels: int,
               where: str | None = None) -> tuple[float, ...]:
    """A key that is one number for every wheel or a list of one per wheel (each within
    the key's range), as one float per wheel."""
    at = f"{where or section}.{key}"
    spec = SCHEMA[section][key]
    if not isinstance(value, list):
        r.in_range(at, spec, value)
        return (float(value),) * n_wheels
    if len(value) != n_wheels:
        raise r.fail(at, f"give one number for every wheel or one per wheel ({n_wheels}), "
                     f"got {len(value)}")
    for i, v in enumerate(value):
        if isinstance(v, bool) or not isinstance(v, NUMBER) or math.isnan(v):
            raise r.fail(f"{at}[{i}]", f"must be a number, got {v!r}")
        r.in_range(f"{at}[{i}]", spec, v)
    return tuple(float(v) for v in value)


def _parse_fusion(r: Reader, table: Any) -> FusionSettings:
    f = r.table("fusion", table, "fusion")
    for key in ("gyro_noise", "bias_walk", "wheel_slip", "slip_warn_s"):
        r.positive(f"fusion.{key}", f[key])
    return FusionSettings(
        gyro_noise=float(f["gyro_noise"]), bias_walk=float(f["bias_walk"]),
        wheel_slip=float(f["wheel_slip"]), slip_warn_s=float(f["slip_warn_s"]),
        stop_on_slip=bool(f["stop_on_slip"]), stop_on_imu_stale=bool(f["stop_on_imu_stale"]))


def _parse_power(r: Reader, table: Any) -> PowerSettings:
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


def _parse_estop(r: Reader, table: Any, wheels: tuple[WheelConfig, ...]) -> EstopSettings:
    e = r.table("estop", table, "estop")
    if not 0 <= e["bit"] < 32:
        raise r.fail("estop.bit", f"must be 0-31, got {e['bit']}")
    if e["node_id"] is not None and e["node_id"] not in {w.node_id for w in wheels}:
        raise r.fail("estop.node_id", f"node {e['node_id']} drives no wheel")
    if not e["object"].strip():
        raise r.fail("estop.object", "must name an object")
    return EstopSettings(bit=e["bit"], object=e["object"], active_low=e["active_low"],
                         node_id=e["node_id"])


def _check_bus_numbers(r: Reader, bus: Mapping[str, Any]) -> None:
    """The [bus] keys of :data:`BUS_KEYS`, when given: the bitrates integers within their
    range, ``sync`` one of its words, ``sync_counter`` 0 or 2-240 (the rest of the table is
    python-can's to check)."""
    for key, spec in BUS_KEYS.items():
        if key not in bus:
            continue
        value = bus[key]
        if key == "sync":
            if value not in SYNC_MODES:
                raise r.fail("bus.sync", f"must be one of {', '.join(map(repr, SYNC_MODES))}, "
                             f"got {short(value)}")
            continue
        if isinstance(value, bool) or not isinstance(value, spec.types):
            what = ("an integer, 0 or 2-240" if key == "sync_counter" else
                    "an integer number of bit/s, e.g. 500000")
            raise r.fail(f"bus.{key}", f"must be {what}, got {short(value)}")
        r.in_range(f"bus.{key}", spec, value)
        if key == "sync_counter" and value == 1:
            raise r.fail("bus.sync_counter", "must be 0 (no counter) or 2-240, got 1")


def _check_limit(r: Reader, key: str, value: Any) -> float:
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
    r = Reader(origin)
    values: dict[str, Any] = {}
    for key, value in changes.items():
        where = f"chassis.{key}"
        if key not in LIVE_LIMITS:
            what = ("unknown key" if key not in SCHEMA["chassis"] else
                    "cannot change while the base runs")
            raise r.fail(where, f"{what} (the limits that can: {', '.join(LIVE_LIMITS)})")
        if isinstance(value, bool) or not isinstance(value, NUMBER):
            raise r.fail(where, f"must be a number, got {value!r}")
        if isinstance(value, float) and math.isnan(value):
            raise r.fail(where, "must be a number, got nan")
        values[key] = _check_limit(r, key, value)
        if configured is not None:
            _check_safer(r, key, values[key], getattr(configured, key))
    return replace(settings, **values)


def _check_safer(r: Reader, key: str, value: float, configured: float) -> None:
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


def _check_stop_bound(r: Reader, cfg: ChassisConfig, given: Iterable[str]) -> None:
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


def _gamepad_table(r: Reader, table: Any) -> dict[str, Any]:
    """The ``[gamepad]`` table as given, checked as ``omnican teleop --gamepad`` reads it."""
    if not isinstance(table, dict):
        raise r.fail("gamepad", f"must be a table, got {type(table).__name__}")
    gamepad_values(table, where=f"{r.origin}: gamepad")
    return dict(table)


def gamepad_values(table: Mapping[str, Any], where: str = "gamepad") -> dict[str, Any]:
    """The keys a ``[gamepad]`` table gives, checked against ``SCHEMA["gamepad"]``, as
    values: a preset's name ("" or none: not given), codes as numbers, ``turbo_button``
    "" as None (no turbo button), numbers as floats. ConfigError names ``where.key``."""
    schema = SCHEMA["gamepad"]
    for key in table:
        if key not in schema:
            raise ConfigError(f"{where}.{key}: unknown key {key!r}{suggest(key, schema)}")
    out: dict[str, Any] = {}
    preset = table.get("preset")
    if preset:
        if not isinstance(preset, str) or preset not in GAMEPAD_PRESETS:
            raise ConfigError(f"{where}.preset: unknown preset {preset!r} "
                              f"(known: {', '.join(GAMEPAD_PRESETS)})")
        out["preset"] = preset
    if "deadzone" in table:
        out["deadzone"] = dz = _number(f"{where}.deadzone", table["deadzone"])
        spec = schema["deadzone"]
        if spec.out_of_range(dz) is not None:
            raise ConfigError(f"{where}.deadzone: must be {spec.range_text()}, got {dz}")
    for key in ("deadman_button", "turbo_button"):
        if key in table:
            value = table[key]
            none = key == "turbo_button" and value == ""
            out[key] = None if none else _code(f"{where}.{key}", value, GAMEPAD_BUTTONS)
    if "require_deadman" in table:
        if not isinstance(table["require_deadman"], bool):
            raise ConfigError(f"{where}.require_deadman: want true or false")
        out["require_deadman"] = table["require_deadman"]
    for a in ("vx", "vy", "wz"):
        if f"axis_{a}" in table:
            out[f"axis_{a}"] = _code(f"{where}.axis_{a}", table[f"axis_{a}"], GAMEPAD_AXES)
        for key in (f"scale_{a}", f"turbo_scale_{a}"):
            if key in table:
                out[key] = _number(f"{where}.{key}", table[key])
    return out


def _code(where: str, value: Any, codes: Mapping[str, int]) -> int:
    """An input event code given by its name (any case) or number."""
    if isinstance(value, bool):
        raise ConfigError(f"{where}: want a code name or number, got {value!r}")
    if isinstance(value, int):
        if value < 0:
            raise ConfigError(f"{where}: must not be negative, got {value}")
        return value
    if isinstance(value, str) and value.upper() in codes:
        return codes[value.upper()]
    raise ConfigError(f"{where}: unknown code {value!r} (known: {', '.join(codes)})")


def _number(where: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, NUMBER) or not math.isfinite(value):
        raise ConfigError(f"{where}: want a finite number, got {value!r}")
    return float(value)


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
