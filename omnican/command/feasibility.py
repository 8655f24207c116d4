"""A plan fitted to a base: each twist scaled down to what the base will drive (and
said), how long the plan takes at its acceleration limits, and whether it is more than
one motion may be.

Pure: the base is its config. Check a plan with :func:`plan_problem` (a twist beyond any
wheeled base) and :func:`extent_problem` (beyond :data:`~omnican.command.legs.MAX_TRAVEL`
or :data:`~omnican.command.legs.MAX_MOTION_S`) before driving it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

from omnican.command.legs import APPROACH_MARGIN, Leg, time_problem, travel_problem
from omnican.config import ChassisConfig
from omnican.core.kinematics import Twist
from omnican.core.limits import (
    VelocityLimiter,
    clamp_twist,
    command_problem,
    desaturate_twist,
)


def plan_problem(plan: Sequence[Leg]) -> str | None:
    """Why a plan cannot be driven at all, or None: a twist with a value beyond any
    wheeled base (:func:`omnican.core.limits.command_problem`, what
    :meth:`Chassis.set_velocity` refuses). Within that, fit_to_limits scales it."""
    for leg in plan:
        problem = command_problem(leg.twist.vx, leg.twist.vy, leg.twist.wz)
        if problem is not None:
            return problem
    return None


def extent_problem(plan: Sequence[Leg], cfg: ChassisConfig) -> str | None:
    """Why ``plan`` is more than one motion may be, or None: its travel or turning,
    summed over the legs, beyond :data:`MAX_TRAVEL`, or its duration at the speeds
    ``cfg``'s base will drive it (:func:`fit_to_limits`, the ramps included) beyond
    :data:`MAX_MOTION_S`. Check it before driving (and :func:`plan_problem` first)."""
    fitted, _ = fit_to_limits(plan, cfg)
    travel = sum(leg.distance if leg.distance is not None
                 else leg.twist.linear_speed * leg.seconds for leg in fitted)
    turning = sum(leg.angle if leg.angle is not None
                  else abs(leg.twist.wz) * leg.seconds for leg in fitted)
    c = cfg.chassis
    return (travel_problem(travel, "m") or travel_problem(turning, "rad")
            or time_problem(nominal_duration(fitted, c.max_accel, c.max_angular_accel),
                             "the motion", " at the speeds this base drives it"))


def feasible(twist: Twist, cfg: ChassisConfig) -> Twist:
    """The twist the base will really drive for ``twist``: scaled down by one factor
    to the speed limits and the wheels' maximum rim speed, direction kept."""
    return VelocityLimiter(cfg.limits(), cfg.kinematics()).target(twist)


@dataclass(frozen=True)
class Clamp:
    """A twist beyond the base's limits: what was asked, what it will drive, and the
    config key (with its value) that binds."""

    requested: Twist
    applied: Twist
    limit: str


def clamp(twist: Twist, cfg: ChassisConfig) -> Clamp | None:
    """None when ``cfg``'s base can drive ``twist`` as it is."""
    limits, c = cfg.limits(), cfg.chassis
    scaled = clamp_twist(twist, limits)
    reasons = []
    if scaled != twist:
        if twist.linear_speed > limits.max_linear:
            reasons.append(f"chassis.max_speed {c.max_speed:g} m/s")
        if abs(twist.wz) > limits.max_angular:
            reasons.append(f"chassis.max_angular_speed {c.max_angular_speed:g} rad/s")
    applied = desaturate_twist(scaled, cfg.kinematics(), limits.max_wheel_speed)
    if applied != scaled:
        reasons.append(f"chassis.max_wheel_speed {c.max_wheel_speed:g} m/s at the rim")
    return Clamp(twist, applied, ", ".join(reasons)) if reasons else None


def fit_to_limits(plan: Sequence[Leg], cfg: ChassisConfig) -> tuple[list[Leg], list[Clamp]]:
    """The plan with every twist the base cannot drive scaled down to what it will
    drive (goal legs keep their goal and take longer), and the clamps, one per
    distinct twist."""
    out: list[Leg] = []
    clamps: list[Clamp] = []
    for leg in plan:
        c = clamp(leg.twist, cfg)
        if c is None:
            out.append(leg)
            continue
        if all(seen.requested != c.requested for seen in clamps):
            clamps.append(c)
        seconds = leg.seconds
        if leg.distance is not None:
            seconds = leg.distance / c.applied.linear_speed
        elif leg.angle is not None:
            seconds = leg.angle / abs(c.applied.wz)
        out.append(replace(leg, twist=c.applied, seconds=seconds))
    return out, clamps


# A goal leg's creep onto its goal and stop on it (settle()), about (simulated base).
SETTLE_ESTIMATE_S = 0.25


def leg_duration(leg: Leg, max_accel: float = math.inf,
                 max_angular_accel: float = math.inf) -> float:
    """What ``leg`` should take (s): a timed leg its ``seconds``; a goal leg also the
    ramp up at the acceleration limit and the slower one down onto the goal
    (:data:`APPROACH_MARGIN`), and the stop on it. Infinite limits: ``seconds``."""
    if not leg.is_goal:
        return leg.seconds
    if leg.distance is not None:
        goal, speed, accel = leg.distance, leg.twist.linear_speed, max_accel
    else:
        goal, speed, accel = leg.angle or 0.0, abs(leg.twist.wz), max_angular_accel
    if not (accel > 0 and math.isfinite(accel)):
        return leg.seconds
    down = accel * APPROACH_MARGIN
    ramps = speed * speed / (2 * accel) + speed * speed / (2 * down)  # m (or rad) on ramps
    if goal >= ramps:
        moving = goal / speed + speed / (2 * accel) + speed / (2 * down)
    else:  # never at full speed: up and straight back down
        peak = math.sqrt(2 * goal * accel * down / (accel + down))
        moving = peak / accel + peak / down
    return moving + SETTLE_ESTIMATE_S


def nominal_duration(plan: Sequence[Leg], max_accel: float = math.inf,
                     max_angular_accel: float = math.inf) -> float:
    """What ``plan`` should take (s), its goal legs' ramps included given the limits."""
    return sum(leg_duration(leg, max_accel, max_angular_accel) for leg in plan)
