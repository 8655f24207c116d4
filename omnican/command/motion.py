"""Scripted motion on a base: the legs driven one after the other, each goal leg stopped
on its goal.

:func:`run` drives the legs (:mod:`omnican.command.legs`, fitted to the base by
:mod:`omnican.command.feasibility`): a timed leg for its time, a goal leg until the
odometry says it reached its goal, then stopped on it (and crept back onto it when it
stopped off it). Goal legs are measured against the plan, not against where the
previous leg happened to stop: a square's fourth turn ends on the start heading plus 360
degrees as the odometry measures it, however much each earlier turn over- or undershot.

:func:`run` and :func:`settle` drive a :class:`omnican.chassis.Chassis` (anything with
its ``pose``/``twist``/``command``/``wheels``/``stopped_reason``/``cfg``/``set_velocity``/``stop``)
from the caller's thread and report progress through a callback. The names of the legs
and of fitting a plan are importable from here too.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

from omnican.clock import REAL_TIME, Clock
from omnican.command.feasibility import (
    SETTLE_ESTIMATE_S,
    Clamp,
    clamp,
    extent_problem,
    feasible,
    fit_to_limits,
    leg_duration,
    nominal_duration,
    plan_problem,
)
from omnican.command.legs import (
    ANGLE_TOLERANCE_RAD,
    APPROACH_MARGIN,
    CORRECTION_FRACTION,
    CREEP_FRACTION,
    DISTANCE_TOLERANCE_M,
    MAX_MOTION_S,
    MAX_TRAVEL,
    Leg,
    goal_command,
    hold,
    planned_end,
    polar_twist,
    span,
    spin,
    square,
    straight,
)
from omnican.config import ChassisConfig
from omnican.core.kinematics import Twist
from omnican.core.odometry import Pose2D
from omnican.errors import BaseStoppedError

__all__ = [
    "ANGLE_TOLERANCE_RAD", "APPROACH_MARGIN", "COMMAND_PERIOD_S", "CORRECTION_FRACTION",
    "CREEP_FRACTION", "DISTANCE_TOLERANCE_M", "DRIVE_LAG_S", "LAG_CYCLES", "MAX_CORRECTIONS",
    "MAX_MOTION_S", "MAX_TRAVEL", "SETTLE_ESTIMATE_S", "SETTLE_TIMEOUT_S", "STANDSTILL_M_S",
    "Base", "BaseStoppedError", "Clamp", "Leg", "MotionResult", "ProgressCallback", "clamp",
    "extent_problem", "feasible", "fit_to_limits", "goal_command", "hold", "leg_duration",
    "nominal_duration", "plan_problem", "planned_end", "polar_twist", "run", "settle", "span",
    "spin", "square", "straight"]

logger = logging.getLogger(__name__)

COMMAND_PERIOD_S = 0.02  # how often run() commands the base (the watchdog wants fresh ones)
SETTLE_TIMEOUT_S = 3.0
STANDSTILL_M_S = 0.002  # every wheel slower than this: the base stands still
MAX_CORRECTIONS = 3  # per goal leg: creep back onto the goal after stopping off it
# A command reaches the wheels at the next control cycle and SYNC; the drive follows with
# its own lag; the encoders' answer reaches the odometry a cycle later.
LAG_CYCLES = 2.0
DRIVE_LAG_S = 0.01

#: ``progress(done_s, total_s, label)``: seconds driven so far, the plan's nominal
#: duration (goal legs may take longer), and the label of the current leg.
ProgressCallback = Callable[[float, float, str], None]


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
    def stopped_reason(self) -> str | None: ...

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
    reason = base.stopped_reason
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
