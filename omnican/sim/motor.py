"""Motor model of a simulated wheel drive, advanced exactly over any time step.

The drive's *demand* velocity ramps towards the target at the acceleration (when
speeding up) or deceleration (when slowing down, and through zero when reversing)
limit; the *actual* velocity follows the demand through a first-order lag with time
constant ``tau``. Both are piecewise linear / exponential, so a step of any length
is integrated in closed form: the simulator can advance lazily (on SYNC, on reads)
instead of running a fast physics loop.

Units are the drive's own: position in counts, velocity in counts/s.
Pure module: no I/O.
"""

from __future__ import annotations

import math
from typing import NamedTuple


class MotorState(NamedTuple):
    """One motor at one instant (a value: a tuple, made as cheaply as one)."""

    position: float = 0.0  # counts (physical, never wraps)
    velocity: float = 0.0  # actual, counts/s
    demand: float = 0.0  # ramp output, counts/s


# MotorState((position, velocity, demand)) without the named tuple's __new__ (a Python
# function, a call more for each motor at each step): the same tuple.
_state = tuple.__new__


def _ramp_segments(
    demand: float, target: float, accel: float, decel: float, dt: float
) -> list[tuple[float, float, float]]:
    """Segments (duration, start value, slope) of the demand over ``dt``."""
    segments: list[tuple[float, float, float]] = []
    remaining = dt
    value = demand
    # Through zero when reversing: first slow down to 0 at the deceleration limit.
    waypoints: list[float] = []
    if value != 0.0 and (target == 0.0 or (target > 0) != (value > 0)):
        waypoints.append(0.0)
    waypoints.append(target)
    for goal in waypoints:
        if remaining <= 0.0:
            break
        delta = goal - value
        if delta == 0.0:
            continue
        slowing = abs(goal) < abs(value)
        rate = decel if slowing else accel
        if math.isinf(rate):
            value = goal  # no ramp: the demand jumps
            continue
        duration = abs(delta) / rate
        slope = math.copysign(rate, delta)
        if duration >= remaining:
            segments.append((remaining, value, slope))
            return segments
        segments.append((duration, value, slope))
        remaining -= duration
        value = goal
    if remaining > 0.0:
        segments.append((remaining, value, 0.0))
    return segments


def advance(
    state: MotorState,
    dt: float,
    target: float,
    accel: float,
    decel: float,
    tau: float,
) -> MotorState:
    """The motor state ``dt`` seconds later, the target being constant meanwhile.

    ``accel`` / ``decel`` are ramp limits (counts/s^2, ``inf`` = no ramp); ``tau`` is
    the lag time constant (s, 0 = the actual velocity equals the demand)."""
    if dt <= 0.0:
        return state
    if accel <= 0.0 or decel <= 0.0:
        raise ValueError("accel and decel must be positive (inf for no ramp)")
    p, v, demand = state
    if v == demand == target:  # settled: the one segment below, without its zero terms
        return _state(MotorState, (p + target * dt, target, target))
    if demand == target and tau > 0.0:
        # The ramp is done, the lag still closing: _ramp_segments' one flat segment
        # (dt, demand, 0.0), the loop below written out for it. The zero slope's terms
        # stay (0.0 added and taken away) so the sums are those of the loop, bit for bit.
        e = math.exp(-dt / tau)
        k = v - demand + 0.0 * tau
        p += demand * dt + 0.5 * 0.0 * dt * dt - 0.0 * tau * dt + k * tau * (1.0 - e)
        v = demand + 0.0 * dt - 0.0 * tau + k * e
        demand = demand + 0.0 * dt
        if abs(v - demand) < 1e-9 * max(1.0, abs(demand)):
            v = demand
        return _state(MotorState, (p, v, demand))
    for duration, c0, c1 in _ramp_segments(demand, target, accel, decel, dt):
        if tau <= 0.0:
            p += c0 * duration + 0.5 * c1 * duration * duration
            v = c0 + c1 * duration
        else:
            e = math.exp(-duration / tau)
            k = v - c0 + c1 * tau
            p += c0 * duration + 0.5 * c1 * duration * duration - c1 * tau * duration + k * tau * (
                1.0 - e
            )
            v = c0 + c1 * duration - c1 * tau + k * e
        demand = c0 + c1 * duration
    if tau > 0.0 and abs(v - demand) < 1e-9 * max(1.0, abs(demand)):
        v = demand  # settle exactly, so "target reached" and "speed zero" become true
    return _state(MotorState, (p, v, demand))
