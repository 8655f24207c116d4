"""Scripted motion: legs, the square, and running them on a base.

A :class:`Leg` holds a twist for a time, or until the odometry says the base went a
distance or turned an angle (a goal leg, slowing down to land on it). Goal legs are
measured against the plan, not against where the previous leg happened to stop: a
square's fourth turn ends on the start heading plus 360 degrees as the odometry
measures it, however much each earlier turn over- or undershot.

The planning functions and :func:`goal_command` are pure; :func:`run` and
:func:`settle` drive a :class:`omnican.chassis.Chassis` (anything with its
``pose``/``twist``/``command``/``wheels``/``status``/``cfg``/``set_velocity``/``stop``)
from the caller's thread and report progress through a callback.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any, Protocol

from omnican.clock import REAL_TIME, Clock
from omnican.config import ChassisConfig
from omnican.core.kinematics import Twist
from omnican.core.limits import (
    MAX_POSE_SENSE,
    VelocityLimiter,
    clamp_twist,
    command_problem,
    desaturate_twist,
)
from omnican.core.odometry import Displacement, Pose2D
from omnican.errors import BaseStoppedError

logger = logging.getLogger(__name__)

COMMAND_PERIOD_S = 0.02  # how often run() commands the base (the watchdog wants fresh ones)
DISTANCE_TOLERANCE_M = 0.001
ANGLE_TOLERANCE_RAD = math.radians(0.1)
# Slow down onto a goal at this fraction of the acceleration limit: the limiter and the
# drives follow a little late, and the margin keeps the approach from being cut short.
APPROACH_MARGIN = 0.7
# Never slower than this fraction of the leg's speed while a goal is still ahead: the
# last millimetres would otherwise take forever.
CREEP_FRACTION = 0.02
# A correction after stopping off the goal runs at most this fraction of the leg's speed.
CORRECTION_FRACTION = 0.25
SETTLE_TIMEOUT_S = 3.0
STANDSTILL_M_S = 0.002  # every wheel slower than this: the base stands still
MAX_CORRECTIONS = 3  # per goal leg: creep back onto the goal after stopping off it
# A command reaches the wheels at the next control cycle and SYNC; the drive follows with
# its own lag; the encoders' answer reaches the odometry a cycle later.
LAG_CYCLES = 2.0
DRIVE_LAG_S = 0.01

# What one motion may be: refused beyond these (what no base drives in one run), as a
# command beyond any base's speed is. The travel and turning bound is the odometry's, the
# one reset_pose() holds a pose to (limits.MAX_POSE_SENSE, 1000 km or 160,000 turns): the
# odometry accumulates every metre and radian driven, and a motion longer than that
# could not be measured. The time bound is the one a user meets first: a day at the
# speeds the base will drive (its limits), longer than a battery base runs, and under
# --fast hours of a full core for a number mistyped (1e6 for 1.6).
#: m of travel, rad of turning (each summed over the motion's legs)
MAX_TRAVEL = MAX_POSE_SENSE
#: s, the motion's nominal duration at the speeds the base drives it
MAX_MOTION_S = 24 * 3600.0

#: ``progress(done_s, total_s, label)``: seconds driven so far, the plan's nominal
#: duration (goal legs may take longer), and the label of the current leg.
ProgressCallback = Callable[[float, float, str], None]


@dataclass(frozen=True)
class Leg:
    """One piece of motion: hold ``twist`` (body frame) for ``seconds``, or, for a goal
    leg, until the base went ``distance`` m along the twist's direction or turned
    ``angle`` rad (in the twist's sense of rotation). ``seconds`` of a goal leg is its
    nominal duration; it gives up after three times that plus two seconds."""

    twist: Twist
    seconds: float
    label: str
    distance: float | None = None
    angle: float | None = None

    def __post_init__(self) -> None:
        if not self.twist.is_finite():
            raise ValueError(f"leg {self.label!r}: the twist must be finite, got {self.twist}")
        if not (math.isfinite(self.seconds) and self.seconds >= 0):
            raise ValueError(f"leg {self.label!r}: seconds must be 0 or more, got {self.seconds}")
        if self.distance is not None and self.angle is not None:
            raise ValueError(f"leg {self.label!r}: a goal is a distance or an angle, not both")
        if self.distance is not None and not (self.distance > 0 and self.twist.linear_speed > 0
                                              and self.twist.wz == 0):
            raise ValueError(f"leg {self.label!r}: a distance goal needs a positive distance "
                             "and a linear speed without turning")
        if self.angle is not None and not (self.angle > 0 and self.twist.wz != 0):
            raise ValueError(f"leg {self.label!r}: an angle goal needs a positive angle and a "
                             "turn rate")

    @property
    def is_goal(self) -> bool:
        return self.distance is not None or self.angle is not None

    @property
    def timeout_s(self) -> float:
        return self.seconds * 3 + 2 if self.is_goal else self.seconds


# ---------------------------------------------------------------- planning (pure)


def polar_twist(speed: float, heading_deg: float, omega: float = 0.0) -> Twist:
    """Move at ``speed`` m/s towards ``heading_deg`` (from forward, CCW) while turning at
    ``omega`` rad/s: the physical speed, in the body frame."""
    heading = math.radians(heading_deg)
    return Twist(speed * math.cos(heading), speed * math.sin(heading), omega)


def hold(twist: Twist, seconds: float, label: str = "drive") -> Leg:
    """Hold ``twist`` for ``seconds``."""
    return Leg(twist, seconds, label)


def straight(distance: float, speed: float, label: str = "straight") -> Leg:
    """Drive ``distance`` m straight ahead at ``speed`` m/s.

    Raises ValueError, in words for a user, for a distance beyond :data:`MAX_TRAVEL` or
    one that takes longer than :data:`MAX_MOTION_S` at ``speed``."""
    if not (distance > 0 and speed > 0):
        raise ValueError(f"distance and speed must be positive, got {distance}, {speed}")
    _check_goal(distance, speed, "m", "m/s")
    return Leg(Twist(speed, 0.0, 0.0), distance / speed, label, distance=distance)


def spin(angle: float, omega: float, label: str = "spin") -> Leg:
    """Turn ``angle`` rad in place at ``omega`` rad/s (negative: clockwise).

    Raises ValueError as :func:`straight` does, for the angle and ``omega``."""
    if not (angle > 0 and omega != 0 and math.isfinite(omega)):
        raise ValueError(f"angle must be positive and omega non-zero, got {angle}, {omega}")
    _check_goal(angle, abs(omega), "rad", "rad/s")
    return Leg(Twist(0.0, 0.0, omega), angle / abs(omega), label, angle=angle)


def _check_goal(goal: float, speed: float, unit: str, speed_unit: str) -> None:
    problem = _travel_problem(goal, unit) or _time_problem(
        goal / speed, f"{goal:.6g} {unit} at {speed:.6g} {speed_unit}", "")
    if problem is not None:
        raise ValueError(problem)


def _travel_problem(amount: float, unit: str) -> str | None:
    if amount > MAX_TRAVEL:
        what = "of travel" if unit == "m" else "of turning"
        return (f"{amount:.6g} {unit} {what} is beyond what one motion may take (at most "
                f"{MAX_TRAVEL:g} {unit}, the range the odometry holds a pose in)")
    return None


def _time_problem(seconds: float, what: str, how: str) -> str | None:
    if not seconds <= MAX_MOTION_S:  # inf and NaN too
        return (f"{what} would take {span(seconds)}{how}; one motion may take at most "
                f"{span(MAX_MOTION_S)}")
    return None


def span(seconds: float) -> str:
    """A duration as a person reads it: ``42 s``, ``12 min``, ``3.5 h``, ``15 days``."""
    if not math.isfinite(seconds):
        return "forever"
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 2 * 3600:
        return f"{seconds / 60:.0f} min"
    if seconds <= 86400:
        return f"{seconds / 3600:.3g} h"
    value, unit = ((seconds / 86400, "day") if seconds < 2 * 365 * 86400 else
                   (seconds / (365.25 * 86400), "year"))
    number = f"{value:.3g}"
    return f"{number} {unit}" + ("" if number == "1" else "s")


def square(side: float, speed: float = 0.3, omega: float = 1.0, sides: int = 4) -> list[Leg]:
    """``sides`` sides (1-4) of a square of ``side`` m, each followed by a 90 degree turn
    to the left in place: four sides end where they started, one turn further."""
    if not (side > 0 and speed > 0 and omega > 0):
        raise ValueError("a square needs a positive side, speed and turn rate")
    if not 1 <= sides <= 4:
        raise ValueError(f"a square has 1-4 sides, not {sides}")
    plan = []
    for k in range(1, sides + 1):
        plan.append(straight(side, speed, f"side {k}/{sides}"))
        plan.append(spin(math.pi / 2, omega, f"turn {k}/{sides}"))
    return plan


def planned_end(start: Pose2D, leg: Leg) -> Pose2D:
    """Where a goal leg that starts at ``start`` should end; for a timed leg, where
    constant ``twist`` for ``seconds`` would take the base."""
    if leg.distance is not None:
        t = leg.twist
        direction = math.atan2(t.vy, t.vx) + start.theta
        return Pose2D(start.x + leg.distance * math.cos(direction),
                      start.y + leg.distance * math.sin(direction), start.theta)
    if leg.angle is not None:
        return Pose2D(start.x, start.y, start.theta + math.copysign(leg.angle, leg.twist.wz))
    return start.compose(Pose2D.exp(Displacement.of(leg.twist, leg.seconds)))


def goal_command(leg: Leg, start: Pose2D, pose: Pose2D, max_accel: float,
                 max_angular_accel: float, correcting: bool = False,
                 lead: float = 0.0) -> Twist | None:
    """This cycle's command for goal leg ``leg`` that should take the base from its
    planned ``start`` to :func:`planned_end`, now that it is at ``pose``; None when the
    goal is reached (or passed). The speed falls as the goal nears, so the base can
    stop on it within ``APPROACH_MARGIN`` of the acceleration limits. A distance leg
    keeps the planned direction of travel in the world even if the heading drifted.

    ``lead``: how much further (m or rad) the base will move before a new command takes
    effect (the command in flight times the lag of loop, bus, drive and odometry); the
    approach slows down that much earlier. ``correcting``: a correction after stopping
    off the goal: towards the goal whichever side of it the base is on, at most at
    ``CORRECTION_FRACTION`` of the leg's speed."""
    goal = planned_end(start, leg)
    t = leg.twist
    if leg.distance is not None:
        direction = math.atan2(t.vy, t.vx) + start.theta
        ux, uy = math.cos(direction), math.sin(direction)
        remaining = (goal.x - pose.x) * ux + (goal.y - pose.y) * uy
        tolerance, speed, accel = DISTANCE_TOLERANCE_M, t.linear_speed, max_accel
    elif leg.angle is not None:
        remaining = (goal.theta - pose.theta) * math.copysign(1.0, t.wz)
        tolerance, speed, accel = ANGLE_TOLERANCE_RAD, abs(t.wz), max_angular_accel
    else:
        raise ValueError(f"leg {leg.label!r} has no goal")
    if remaining <= tolerance and not (correcting and remaining < -tolerance):
        return None
    approach = math.sqrt(2 * APPROACH_MARGIN * accel * max(abs(remaining) - lead, 0.0))
    cap = CORRECTION_FRACTION * speed if correcting else speed
    k = math.copysign(min(cap, max(approach, CREEP_FRACTION * speed)) / speed, remaining)
    if leg.distance is not None:
        # The body-frame direction that keeps the planned world direction.
        body = direction - pose.theta
        linear = t.linear_speed * k
        return Twist(linear * math.cos(body), linear * math.sin(body), 0.0)
    return t.scaled(k)


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
    return (_travel_problem(travel, "m") or _travel_problem(turning, "rad")
            or _time_problem(nominal_duration(fitted, c.max_accel, c.max_angular_accel),
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


# ---------------------------------------------------------------- running


class Base(Protocol):
    """What :func:`run` needs of a base (a :class:`omnican.chassis.Chassis`)."""

    @property
    def cfg(self) -> ChassisConfig: ...

    @property
    def pose(self) -> Pose2D: ...

    @property
    def twist(self) -> Twist: ...

    @property
    def command(self) -> Twist: ...

    @property
    def wheels(self) -> Sequence[Any]: ...

    @property
    def status(self) -> Any: ...

    def set_velocity(self, vx: float, vy: float, wz: float) -> None: ...

    def stop(self) -> None: ...


@dataclass(frozen=True)
class MotionResult:
    """``twist``: the measured body twist at the end of the last leg: a timed leg's just
    before the final stop, a goal leg's once the base stopped on its goal (a twist read
    while it brakes into the goal says nothing); ``elapsed_s``: seconds from the first
    command to the end of the last leg."""

    twist: Twist
    elapsed_s: float


def _lead(leg: Leg, applied: Twist, lag_s: float) -> float:
    """How far the base still goes (m or rad, towards the goal) on the twist it is
    applying now, before a new command would show in the odometry."""
    if leg.angle is not None:
        return abs(applied.wz) * lag_s
    return applied.linear_speed * lag_s


def _check(base: Base) -> None:
    reason = base.status.stopped_reason
    if reason:
        raise BaseStoppedError(reason)


def run(base: Base, plan: Sequence[Leg], progress: ProgressCallback | None = None,
        period_s: float = COMMAND_PERIOD_S) -> MotionResult:
    """Drive the legs one after the other, then stop and wait until the base stands.

    Goal legs stop on their goal before the next leg starts. Raises
    :class:`BaseStoppedError` when the base stops itself; a KeyboardInterrupt passes
    through (the caller's ``with Chassis`` block stops the base)."""
    limits = base.cfg.chassis
    durations = [leg_duration(leg, limits.max_accel, limits.max_angular_accel)
                 for leg in plan]
    clock = _clock(base)
    start = clock.now()
    measured = Twist()
    reference = base.pose  # where the plan says the base is
    leg_index, leg_start = 0, 0.0  # the leg under way, and when it began (s from start)

    def report(label: str) -> None:
        # The total: the legs done as they took, this one as expected (or as long as it
        # takes), the rest as expected: 100 % only when the motion is over.
        if progress is not None:
            done = clock.now() - start
            total = (leg_start + max(durations[leg_index],
                                     done - leg_start + SETTLE_ESTIMATE_S)
                     + sum(durations[leg_index + 1:]))
            progress(done, total, label)

    lag_s = LAG_CYCLES / limits.rate_hz + DRIVE_LAG_S
    for leg_index, leg in enumerate(plan):  # noqa: B007 (report() reads it)
        leg_start = clock.now() - start
        end = clock.now() + leg.timeout_s
        if not leg.is_goal:
            while clock.now() < end:
                _check(base)
                base.set_velocity(leg.twist.vx, leg.twist.vy, leg.twist.wz)
                report(leg.label)
                clock.sleep(min(period_s, max(0.0, end - clock.now())))
            measured = base.twist
            reference = base.pose
            continue
        for attempt in range(MAX_CORRECTIONS + 1):
            while clock.now() < end:
                _check(base)
                command = goal_command(leg, reference, base.pose, limits.max_accel,
                                       limits.max_angular_accel, correcting=attempt > 0,
                                       lead=_lead(leg, base.command, lag_s))
                if command is None:
                    break
                base.set_velocity(command.vx, command.vy, command.wz)
                report(leg.label)
                clock.sleep(period_s)
            else:
                logger.warning("%s: goal not reached within %.1f s", leg.label, leg.timeout_s)
            settle(base)  # stop on the goal, so one leg does not run into the next
            measured = base.twist
            if clock.now() >= end or goal_command(
                    leg, reference, base.pose, limits.max_accel, limits.max_angular_accel,
                    correcting=True) is None:
                break
            logger.debug("%s: stopped off the goal at %s: correcting", leg.label, base.pose)
        reference = planned_end(reference, leg)
    elapsed = clock.now() - start
    _check(base)
    settle(base)
    if progress is not None:
        done = clock.now() - start
        progress(done, done, "done")
    return MotionResult(measured, elapsed)


def settle(base: Base, timeout_s: float = SETTLE_TIMEOUT_S,
           period_s: float = COMMAND_PERIOD_S) -> None:
    """Stop and wait (bounded) until the wheels stand still and the last samples of the
    stop reached the odometry."""
    base.stop()
    clock = _clock(base)
    deadline = clock.now() + timeout_s
    while clock.now() < deadline:
        if base.command.is_zero() and all(abs(w.actual_speed) < STANDSTILL_M_S
                                          for w in base.wheels):
            break
        clock.sleep(period_s)
    clock.sleep(0.05)


def _clock(base: Base) -> Clock:
    """The base's clock: simulated time runs while the motion waits."""
    clock = getattr(base, "clock", None)
    return clock if isinstance(clock, Clock) else REAL_TIME
