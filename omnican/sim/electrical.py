"""The electrical side of a simulated wheel drive: the motor current the motion needs
(acceleration, friction, the ground's load), the torque it makes, the DC link voltage
sagging under that current, and the motor's temperature rising with it.

A velocity-controlled motor draws what it takes to follow its demand: friction and the
ground's rolling resistance at speed, plus the base's share of inertia while it
accelerates. A wheel off the ground carries only its own inertia and friction: it
follows its target as before, on much less current. A jammed wheel stands still while
the drive's velocity loop pushes against the jam at its current limit; a wheel turned
from outside (pushed) is braked at that limit. An unpowered stage draws nothing.

Torque is taken proportional to current (rated torque at rated current). The supply
has an internal resistance: the DC link reads the supply voltage less that resistance
times the drive's motor currents. The winding warms towards ``ambient + k I^2`` with a
thermal time constant, integrated exactly for a current held over a step.

SI units throughout (A, V, degC, m/s at the rim, s). Pure: no I/O, no clock.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

NOMINAL_SUPPLY_V = 24.0  # the simulated battery when nothing else is said


@dataclass(frozen=True)
class MotorModel:
    """What one wheel's motor draws, per wheel (rim speeds in m/s)."""

    friction_a: float = 0.3  # dry friction of motor and gearbox
    rolling_a: float = 0.4  # the ground's rolling resistance at speed (on the ground only)
    accel_a: float = 1.5  # per m/s^2 at the rim on the ground: the base's share of inertia
    accel_lifted_a: float = 0.1  # per m/s^2 off the ground: the wheel's own inertia
    limit_a: float = 10.0  # the drive's current limit: what a stalled wheel draws
    smooth_m_s: float = 0.005  # friction changes sign smoothly over this speed
    resistance_ohm: float = 0.1  # the supply's internal resistance
    heating_c_per_a2: float = 0.8  # steady-state temperature rise per A^2
    thermal_tau_s: float = 60.0
    ambient_c: float = 25.0


DEFAULT_MODEL = MotorModel()


def motor_current(model: MotorModel, speed: float, accel: float, demand: float, *,
                  powered: bool, grounded: bool = True, jammed: bool = False,
                  pushed: bool = False) -> float:
    """Motor current (A, signed as the torque) of a wheel at rim ``speed`` (m/s)
    accelerating at ``accel`` (m/s^2) while its drive asks for ``demand`` (m/s).

    ``jammed``: it cannot turn, and the drive pushes against it at its limit whenever it
    asks for motion. ``pushed``: something turns it, and the drive brakes at its limit
    towards its demand. Within the current limit, always."""
    if not powered:
        return 0.0
    limit = model.limit_a
    if jammed:
        return math.copysign(limit, demand) if abs(demand) > model.smooth_m_s else 0.0
    if pushed:
        error = demand - speed
        return math.copysign(limit, error) if abs(error) > model.smooth_m_s else 0.0
    direction = math.tanh(speed / model.smooth_m_s)
    current = model.friction_a * direction
    if grounded:
        current += model.rolling_a * direction + model.accel_a * accel
    else:
        current += model.accel_lifted_a * accel
    return max(-limit, min(limit, current))


def dc_link_voltage(model: MotorModel, supply_v: float, currents: Iterable[float]) -> float:
    """The DC link (V): the supply less its internal resistance times the currents
    drawn (never below zero)."""
    return max(0.0, supply_v - model.resistance_ohm * sum(abs(i) for i in currents))


def temperature_after(model: MotorModel, temperature_c: float, current_a: float,
                      dt: float) -> float:
    """The winding temperature ``dt`` s later with ``current_a`` held meanwhile: on its
    way to ``ambient + k I^2`` with the thermal time constant, exactly."""
    if dt <= 0.0:
        return temperature_c
    steady = model.ambient_c + model.heating_c_per_a2 * current_a * current_a
    return steady + (temperature_c - steady) * math.exp(-dt / model.thermal_tau_s)


def per_mille(value: float, rated: float) -> int:
    """``value`` in thousandths of ``rated`` (CiA 402's unit of 6077h and 6078h)."""
    return round(1000.0 * value / rated) if rated > 0 else 0
