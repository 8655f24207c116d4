"""The legs of a scripted motion: timed legs, goal legs that end on a distance or an
angle, the square, and each cycle's command that lands a goal leg on its goal.

A :class:`Leg` holds a twist for a time, or until the odometry says the base went a
distance or turned an angle (a goal leg, slowing down to land on it). A goal leg is
measured from where the plan says it starts (:func:`planned_end` of the leg before), not
from where the previous leg happened to stop. One motion is bounded
(:data:`MAX_TRAVEL`, :data:`MAX_MOTION_S`): :func:`straight` and :func:`spin` refuse a
goal beyond them in words for a user.

Pure: no base, no clock. :mod:`omnican.command.motion` drives the legs on a base.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from omnican.core.kinematics import Twist
from omnican.core.limits import MAX_POSE_SENSE
from omnican.core.odometry import Displacement, Pose2D

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
    problem = travel_problem(goal, unit) or time_problem(
        goal / speed, f"{goal:.6g} {unit} at {speed:.6g} {speed_unit}", "")
    if problem is not None:
        raise ValueError(problem)


def travel_problem(amount: float, unit: str) -> str | None:
    """Why ``amount`` ``unit`` (``m`` of travel, ``rad`` of turning) is more than one
    motion may take (:data:`MAX_TRAVEL`), or None."""
    if amount > MAX_TRAVEL:
        what = "of travel" if unit == "m" else "of turning"
        return (f"{amount:.6g} {unit} {what} is beyond what one motion may take (at most "
                f"{MAX_TRAVEL:g} {unit}, the range the odometry holds a pose in)")
    return None


def time_problem(seconds: float, what: str, how: str) -> str | None:
    """Why ``what``, taking ``seconds`` (``how``: at which speeds), is longer than one
    motion may take (:data:`MAX_MOTION_S`), or None."""
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
