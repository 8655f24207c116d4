"""Calibration math: wheel scales and base radius from odometry against measurements,
and the corrected config as TOML text.

Two unknowns per wheel matter to odometry: how many encoder counts one metre of rim
travel really is, and how far the wheels really sit from the centre. Both are
expressed as factors on the config:

* ``s_i`` = true counts per metre / configured ``position_scale`` of wheel ``i`` (a
  wheel worn smaller than configured has ``s_i > 1``: it turns more counts per metre,
  so the odometry over-reads distance by ``s_i``). The corrected ``position_scale``
  and ``velocity_scale`` are both multiplied by ``s_i`` (a drive velocity unit is a
  fixed number of counts per second); a config giving ``wheel_radius`` instead
  divides it by ``s_i``.
* ``g`` = true base radius / configured base radius.

Guided calibration (:func:`guided_correction`): a straight run gives the common scale
``s = d_odo / d_true`` (translation does not involve the radius); a spin then gives
``g = (theta_odo / s) / theta_true``: with corrected scales the odometry would have
read ``theta_odo / s``, and for a given wheel travel the turned angle is inversely
proportional to the radius.

Fit (:func:`fit`): Gauss-Newton least squares of the end poses predicted by integrating
the recorded counts with candidate factors against measured end poses (3 equations per
recording). Pure module: numpy only, no I/O.
"""

from __future__ import annotations

import math
import re
import sys
from collections.abc import Sequence
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from omnican.config import (
    SCHEMA,
    WHEEL_EDS,
    ChassisConfig,
    ChassisSettings,
    SimTruth,
    parse_config,
)
from omnican.core.kinematics import OmniKinematics
from omnican.core.odometry import wrap_angle
from omnican.errors import ConfigError
from omnican.plan.health import CONFIG_KEYS as HEALTH_CONFIG_KEYS

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib  # type: ignore[import-not-found,unused-ignore]

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Correction:
    """What the config should be multiplied by (see the module docstring)."""

    wheel_factors: tuple[float, ...]  # s_i: true counts per m / configured position_scale
    radius_factor: float = 1.0  # g: true base radius / configured
    # Significant digits the corrected numbers are written with: what the measurements
    # support (see measured_digits), not a float's noise (0.1938, not 0.1937999).
    digits: int = 7

    def __post_init__(self) -> None:
        for v in (*self.wheel_factors, self.radius_factor):
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"correction factors must be positive and finite, got {v!r}")

    @classmethod
    def common(cls, n_wheels: int, scale: float, radius_factor: float = 1.0) -> Correction:
        return cls((scale,) * n_wheels, radius_factor)

    def with_digits(self, digits: int) -> Correction:
        return replace(self, digits=digits)

    def apply(self, cfg: ChassisConfig) -> ChassisConfig:
        """``cfg`` with corrected scales and radii."""
        if len(self.wheel_factors) != len(cfg.wheels):
            raise ValueError(f"{len(self.wheel_factors)} factors for {len(cfg.wheels)} wheels")
        g = self.radius_factor
        wheels = tuple(
            replace(w, velocity_scale=w.velocity_scale * s, position_scale=w.position_scale * s,
                    base_radius=None if w.base_radius is None else w.base_radius * g)
            for w, s in zip(cfg.wheels, self.wheel_factors, strict=True))
        chassis = replace(cfg.chassis, base_radius=cfg.chassis.base_radius * g)
        return replace(cfg, chassis=chassis, wheels=wheels)


# ---------------------------------------------------------------- how precise

#: What a person measures a calibration run with: a tape to the millimetre, a mark on
#: the floor to about a degree.
DISTANCE_RESOLUTION_M = 0.001
ANGLE_RESOLUTION_RAD = math.radians(1.0)


def measured_digits(distance_m: float | None, angle_rad: float | None = None,
                    distance_resolution_m: float = DISTANCE_RESOLUTION_M,
                    angle_resolution_rad: float = ANGLE_RESOLUTION_RAD) -> int:
    """Significant digits the corrected numbers carry, from the relative resolution of
    the measurements (by default 1 mm over ``distance_m``, 1 degree over ``angle_rad``):
    one more digit than the measurements resolve, between 3 and 6 (a seventh digit is
    below what the odometry itself repeats to). 1 m and 2 turns measured by hand give 4
    (0.1938, not 0.1937999)."""
    parts = []
    if distance_m:
        parts.append(distance_resolution_m / abs(distance_m))
    if angle_rad and abs(angle_rad) > 5 * angle_resolution_rad:
        parts.append(angle_resolution_rad / abs(angle_rad))
    if not parts:
        return 6
    relative = math.hypot(*parts)
    return max(3, min(6, 1 + math.ceil(-math.log10(relative))))


# ---------------------------------------------------------------- guided calibration


def scale_from_distance(odometry_m: float, measured_m: float) -> float:
    """Common wheel factor ``s`` from a straight run: odometry distance / true distance."""
    if not (math.isfinite(measured_m) and measured_m > 0):
        raise ValueError(f"the measured distance must be positive, got {measured_m!r}")
    if not (math.isfinite(odometry_m) and odometry_m > 0):
        raise ValueError(f"the odometry saw no straight motion ({odometry_m!r} m)")
    return odometry_m / measured_m


def radius_factor_from_spin(odometry_rad: float, measured_rad: float, scale: float = 1.0) -> float:
    """``g`` from a spin: (odometry angle with corrected scales) / true angle."""
    if not (math.isfinite(measured_rad) and measured_rad != 0):
        raise ValueError(f"the measured rotation must be non-zero, got {measured_rad!r}")
    if not (math.isfinite(odometry_rad) and odometry_rad != 0):
        raise ValueError("the odometry saw no rotation")
    if (odometry_rad > 0) != (measured_rad > 0):
        raise ValueError("the measured rotation has the opposite sign of the odometry's "
                         "(the spin is counter-clockwise, seen from above)")
    return (odometry_rad / scale) / measured_rad


def guided_correction(n_wheels: int, distance_odometry: float, distance_measured: float,
                      angle_odometry: float | None = None,
                      angle_measured: float | None = None) -> Correction:
    """The correction from a straight run (and a spin, if given)."""
    s = scale_from_distance(distance_odometry, distance_measured)
    g = 1.0
    if angle_odometry is not None and angle_measured is not None:
        g = radius_factor_from_spin(angle_odometry, angle_measured, s)
    return Correction.common(n_wheels, s, g)


# ---------------------------------------------------------------- odometry, vectorised


def scaled_kinematics(kin: OmniKinematics, radius_factor: float) -> OmniKinematics:
    """The same wheel layout with every radius multiplied by ``radius_factor``."""
    return OmniKinematics(kin.angles_deg, [r * radius_factor for r in kin.base_radius],
                          kin.drive_angles_deg)


def truth_options(cfg: ChassisConfig, scale_error: float | Sequence[float],
                  radius_error: float) -> dict[str, Any]:
    """``SimulatedBase.from_config`` arguments for a base whose wheels turn
    ``1 + scale_error`` times the configured counts per metre and whose radius is
    ``1 + radius_error`` times the configured one."""
    errors = ([float(e) for e in scale_error] if isinstance(scale_error, Sequence)
              else [float(scale_error)] * len(cfg.wheels))
    return {"true_scale": [1.0 + e for e in errors],
            "true_kinematics": scaled_kinematics(cfg.kinematics(), 1.0 + radius_error)}


def sim_truth(cfg: ChassisConfig, scale_error: float, radius_error: float) -> SimTruth:
    """The ``[sim]`` table of a simulated base whose wheels turn ``1 + scale_error`` times
    ``cfg``'s counts per metre and whose radius is ``1 + radius_error`` times ``cfg``'s."""
    return SimTruth(cfg.chassis.base_radius * (1.0 + radius_error),
                    tuple(abs(w.position_scale) * (1.0 + scale_error) for w in cfg.wheels))


def sim_options(cfg: ChassisConfig, truth: SimTruth) -> dict[str, Any]:
    """``SimulatedBase.from_config`` arguments for the simulated base ``truth`` describes
    (a ``[sim]`` table), against what ``cfg`` says it is."""
    scale = ([1.0] * len(cfg.wheels) if truth.position_scale is None else
             [t / abs(w.position_scale)
              for t, w in zip(truth.position_scale, cfg.wheels, strict=True)])
    radius = 1.0 if truth.base_radius is None else truth.base_radius / cfg.chassis.base_radius
    return {"true_scale": scale, "true_kinematics": scaled_kinematics(cfg.kinematics(), radius)}


def _sinc_terms(w: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Vectorised (sin w / w, (1 - cos w) / w), with the series near 0 (as odometry.py)."""
    small = np.abs(w) < 1e-4
    safe = np.where(small, 1.0, w)
    w2 = w * w
    a = np.where(small, 1.0 - w2 / 6.0 + w2 * w2 / 120.0, np.sin(safe) / safe)
    b = np.where(small, w / 2.0 - w * w2 / 24.0, (1.0 - np.cos(safe)) / safe)
    return a, b


def integrate(travel: npt.ArrayLike, kin: OmniKinematics) -> FloatArray:
    """Poses (M, 3) from cumulative wheel travel (M, N), starting at the origin: what
    :class:`omnican.core.odometry.Odometry` gives update by update (SE(2) exponential)."""
    arr = np.asarray(travel, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != kin.num_wheels:
        raise ValueError(f"travel must be (M, {kin.num_wheels}), got shape {arr.shape}")
    out = np.zeros((arr.shape[0], 3))
    if arr.shape[0] < 2:
        return out
    body = np.diff(arr, axis=0) @ kin.forward_matrix.T
    dx, dy, dw = body[:, 0], body[:, 1], body[:, 2]
    theta = np.concatenate([[0.0], np.cumsum(dw)])
    a, b = _sinc_terms(dw)
    lx, ly = a * dx - b * dy, b * dx + a * dy
    c, s = np.cos(theta[:-1]), np.sin(theta[:-1])
    out[1:, 0] = np.cumsum(c * lx - s * ly)
    out[1:, 1] = np.cumsum(s * lx + c * ly)
    out[:, 2] = theta
    return out


# ---------------------------------------------------------------- least-squares fit


@dataclass(frozen=True)
class FitRun:
    """One recording: continuous encoder counts per complete SYNC (M, N) and the
    measured end pose (x m, y m, theta rad) in the frame of the start pose."""

    counts: FloatArray
    measured: tuple[float, float, float]
    name: str = "run"


@dataclass(frozen=True)
class FitResult:
    model: str  # "wheels+radius", "scale+radius" or "scale"
    correction: Correction
    predicted_before: FloatArray  # (K, 3) end poses with the configured values
    predicted_after: FloatArray  # (K, 3) end poses with the fitted values
    residual_before: FloatArray  # (K, 3) predicted - measured (theta wrapped)
    residual_after: FloatArray
    iterations: int
    note: str = ""


MODELS = {
    "wheels+radius": "a scale factor per wheel and the base radius",
    "scale+radius": "one scale factor for all wheels and the base radius",
    "scale": "one scale factor for all wheels (the base radius is kept)",
}


def _unpack(model: str, q: FloatArray, n: int) -> Correction:
    if model == "wheels+radius":
        return Correction(tuple(float(v) for v in q[:n]), float(q[n]))
    if model == "scale+radius":
        return Correction.common(n, float(q[0]), float(q[1]))
    return Correction.common(n, float(q[0]))


def _n_params(model: str, n: int) -> int:
    return {"wheels+radius": n + 1, "scale+radius": 2, "scale": 1}[model]


def end_poses(runs: Sequence[FitRun], cfg: ChassisConfig, c: Correction) -> FloatArray:
    """(K, 3) end poses the odometry gives for each run with the correction applied."""
    kin = scaled_kinematics(cfg.kinematics(), c.radius_factor)
    cpm = np.array([w.position_scale * s for w, s in zip(cfg.wheels, c.wheel_factors,
                                                        strict=True)])
    return np.array([integrate(r.counts / cpm, kin)[-1] if len(r.counts) else np.zeros(3)
                     for r in runs])


def _residuals(pred: FloatArray, measured: FloatArray) -> FloatArray:
    res = pred - measured
    res[:, 2] = [wrap_angle(float(v)) for v in res[:, 2]]
    return res


def fit(runs: Sequence[FitRun], cfg: ChassisConfig, model: str = "auto",
        max_iterations: int = 50) -> FitResult:
    """Fit the correction to the runs' measured end poses.

    ``model="auto"`` takes the richest model the data determines: per-wheel scales and
    the radius when there are enough equations (3 per run) and the runs excite every
    parameter, else one common scale and the radius, else the common scale alone.
    Heading residuals count as arc length at the wheels (times the base radius)."""
    if not runs:
        raise ValueError("no recordings to fit")
    n = len(cfg.wheels)
    measured = np.array([r.measured for r in runs], dtype=np.float64)
    if not np.all(np.isfinite(measured)):
        raise ValueError("measured poses must be finite")
    weight = np.array([1.0, 1.0, float(np.mean(cfg.kinematics().base_radius))])

    def residual(model_: str, q: FloatArray) -> FloatArray:
        c = _unpack(model_, q, n)
        out: FloatArray = (_residuals(end_poses(runs, cfg, c), measured) * weight).ravel()
        return out

    def jacobian(model_: str, q: FloatArray) -> FloatArray:
        cols = []
        for k in range(q.size):
            h = 1e-6 * max(1.0, abs(q[k]))
            up, down = q.copy(), q.copy()
            up[k] += h
            down[k] -= h
            cols.append((residual(model_, up) - residual(model_, down)) / (2 * h))
        return np.column_stack(cols)

    candidates = list(MODELS) if model == "auto" else [model]
    if model != "auto" and model not in MODELS:
        raise ValueError(f"unknown model {model!r} (known: {', '.join(MODELS)})")
    note = ""
    chosen = None
    for m in candidates:
        k = _n_params(m, n)
        if 3 * len(runs) < k:
            continue
        q0 = np.ones(k)
        sv = np.linalg.svd(jacobian(m, q0), compute_uv=False)
        if sv.size and sv[-1] > 1e-3 * sv[0] and sv[0] > 0:
            chosen = m
            break
        if model == "auto":
            note = f"the recordings do not determine {MODELS[m]}; "
    if chosen is None:
        raise ValueError("the recordings do not determine any scale: drive an open path "
                         "(e.g. a straight line, then a spin) and give its measured end pose")
    q = np.ones(_n_params(chosen, n))
    r = residual(chosen, q)
    cost = float(r @ r)
    iterations = 0
    while iterations < max_iterations:
        iterations += 1
        step = np.linalg.lstsq(jacobian(chosen, q), -r, rcond=None)[0]
        lam, improved = 1.0, False
        while lam > 1e-4 and not improved:
            cand = q + lam * step
            if np.all(cand > 0):
                r_new = residual(chosen, cand)
                improved = float(r_new @ r_new) <= cost
            if not improved:
                lam /= 2
        if not improved:
            break
        q, r = cand, r_new
        new_cost = float(r @ r)
        converged = float(np.max(np.abs(lam * step))) < 1e-12 or cost - new_cost < 1e-18
        cost = new_cost
        if converged:
            break
    correction = _unpack(chosen, q, n)
    before = end_poses(runs, cfg, Correction.common(n, 1.0))
    after = end_poses(runs, cfg, correction)
    return FitResult(chosen, correction, before, after, _residuals(before, measured),
                     _residuals(after, measured), iterations,
                     note + f"fitted {MODELS[chosen]}")


# ---------------------------------------------------------------- the config as TOML text

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
        for setting in w.settings:
            lines += ["[[wheel.sdo]]", f"object = {_toml_string(setting.object)}",
                      f"value = {_toml_value(setting.value)}"]
            if setting.type is not None:
                lines.append(f'type = "{setting.type}"')
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
