"""What a config should be multiplied by: the :class:`Correction`, how precisely to write
it, and where it comes from in a guided calibration (a straight run, then a spin); the
simulated base that is a given correction off (``calibrate --sim``, ``[sim]``).

See :mod:`omnican.analysis.calibration` for the factors' meaning. Pure: no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

from omnican.config import ChassisConfig, SimTruth
from omnican.core.kinematics import OmniKinematics


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


# ---------------------------------------------------------------- a base that far off


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
