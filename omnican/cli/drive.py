"""``omnican drive``: scripted motion, for scripts and tests.

Straight (``--vx --vy --wz``), polar (``--speed --heading-deg --omega``, the seed's
``compute(speed, angle, omega)`` with its 2/3 translation error fixed) or a square
(``--square SIDE``); prints the final pose, or a JSON object with ``--json``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import asdict, dataclass
from typing import Any

from omnican.chassis import Chassis
from omnican.cli.common import (
    EXIT_FAILURE,
    EXIT_OK,
    UsageError,
    add_bus_arguments,
    finite_float,
    positive_float,
    session,
)
from omnican.kinematics import Twist
from omnican.live import FOXGLOVE_HELP, foxglove_address, watch
from omnican.odometry import Pose2D

COMMAND_PERIOD_S = 0.02


def add_subparser(sub: Any) -> None:
    p = sub.add_parser("drive", help="drive a scripted motion and print the pose",
                       description=__doc__,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    motion = p.add_argument_group("motion (pick one form)")
    motion.add_argument("--vx", type=finite_float, help="forward speed, m/s")
    motion.add_argument("--vy", type=finite_float, help="leftward speed, m/s")
    motion.add_argument("--wz", type=finite_float, help="turn rate, rad/s (CCW positive)")
    motion.add_argument("--speed", type=finite_float,
                        help="polar form: speed along --heading-deg, m/s (square: leg speed, "
                             "default 0.3)")
    motion.add_argument("--heading-deg", type=finite_float,
                        help="polar form: direction of travel, degrees from forward, CCW")
    motion.add_argument("--omega", type=finite_float,
                        help="polar form: turn rate, rad/s (square: turn rate, default 1.0)")
    motion.add_argument("--square", type=positive_float, metavar="SIDE",
                        help="drive a square with sides of SIDE m, turning 90 deg left in place")
    p.add_argument("--duration", type=positive_float, default=1.0, metavar="S",
                   help="seconds to hold the velocity (default 1.0; not with --square)")
    p.add_argument("--json", action="store_true",
                   help='print {"pose", "twist", "duration_s"} (+ "true_pose" under --sim)')
    p.add_argument("--record", metavar="FILE",
                   help="record the bus to FILE; format by extension (.log candump, .asc, .blf; "
                        ".mcap: frames plus the robot's state as ROS 2 messages)")
    p.add_argument("--foxglove", nargs="?", const="", type=foxglove_address,
                   metavar="[HOST:]PORT", help=FOXGLOVE_HELP)
    add_bus_arguments(p)
    p.set_defaults(func=run)


@dataclass(frozen=True)
class Leg:
    """One piece of motion: hold ``twist`` for ``seconds``, or until the odometry says
    the base went ``distance`` m or turned ``angle`` rad (slowing down to land on it)."""

    twist: Twist
    seconds: float
    label: str
    distance: float | None = None
    angle: float | None = None


def legs(args: argparse.Namespace) -> list[Leg]:
    """The motion as legs; bad combinations are usage errors."""
    cartesian = any(v is not None for v in (args.vx, args.vy, args.wz))
    polar = args.heading_deg is not None
    if args.square is not None:
        if cartesian or polar:
            raise UsageError("--square takes only --speed and --omega")
        speed = args.speed if args.speed is not None else 0.3
        omega = args.omega if args.omega is not None else 1.0
        if speed <= 0 or omega <= 0:
            raise UsageError("--square needs a positive --speed and --omega")
        out = []
        for side in range(1, 5):
            out.append(Leg(Twist(speed, 0.0, 0.0), args.square / speed, f"side {side}/4",
                           distance=args.square))
            out.append(Leg(Twist(0.0, 0.0, omega), (math.pi / 2) / omega, f"turn {side}/4",
                           angle=math.pi / 2))
        return out
    if cartesian and (polar or args.speed is not None or args.omega is not None):
        raise UsageError("give either --vx/--vy/--wz or --speed/--heading-deg/--omega")
    if polar or args.speed is not None or args.omega is not None:
        speed = args.speed or 0.0
        heading = math.radians(args.heading_deg or 0.0)
        twist = Twist(speed * math.cos(heading), speed * math.sin(heading), args.omega or 0.0)
    else:
        twist = Twist(args.vx or 0.0, args.vy or 0.0, args.wz or 0.0)
    return [Leg(twist, args.duration, "drive")]


def pose_dict(p: Pose2D) -> dict[str, float]:
    return {"x": round(p.x, 6), "y": round(p.y, 6), "theta": round(p.theta, 6)}


def pose_line(p: Pose2D) -> str:
    return f"pose x={p.x:.4f} y={p.y:.4f} theta={p.theta:.4f}"


class _Progress:
    """A one-line progress display on stderr when it is a terminal."""

    def __init__(self, total_s: float) -> None:
        self.total = total_s
        self.enabled = sys.stderr.isatty() and total_s > 2.0

    def show(self, done_s: float, label: str) -> None:
        if self.enabled:
            frac = min(1.0, done_s / self.total)
            bar = "=" * int(frac * 30)
            sys.stderr.write(f"\r[{bar:<30}] {frac:4.0%} {label:<10}")
            sys.stderr.flush()

    def close(self) -> None:
        if self.enabled:
            sys.stderr.write("\r" + " " * 50 + "\r")
            sys.stderr.flush()


def _leg_command(base: Chassis, leg: Leg, origin: Pose2D) -> Twist | None:
    """This cycle's command for a goal leg, or None when the goal is reached."""
    limits = base.cfg.chassis
    if leg.distance is not None:
        remaining = leg.distance - base.pose.distance_to(origin)
        scale_to = math.sqrt(2 * 0.7 * limits.max_accel * max(remaining, 0.0))
        speed = leg.twist.linear_speed
    else:
        assert leg.angle is not None
        remaining = leg.angle - abs(base.pose.theta - origin.theta)
        scale_to = math.sqrt(2 * 0.7 * limits.max_angular_accel * max(remaining, 0.0))
        speed = abs(leg.twist.wz)
    if remaining <= 0.0005:
        return None
    k = min(1.0, max(scale_to, 0.02 * speed) / speed) if speed else 0.0
    return leg.twist.scaled(k)


def execute(base: Chassis, plan: list[Leg]) -> tuple[Twist, float]:
    """Run the legs; returns (measured twist at the end of the motion, seconds driven)."""
    total = sum(leg.seconds for leg in plan)
    progress = _Progress(total)
    start = time.monotonic()
    measured = Twist()
    try:
        for leg in plan:
            origin = base.pose
            goal = leg.distance is not None or leg.angle is not None
            end = time.monotonic() + (leg.seconds * 3 + 2 if goal else leg.seconds)
            while time.monotonic() < end:
                reason = base.status.stopped_reason
                if reason:
                    raise BaseStoppedError(reason)
                twist = _leg_command(base, leg, origin) if goal else leg.twist
                if twist is None:
                    _settle(base)  # stop between goal legs, so one does not run into the next
                    break
                base.set_velocity(twist.vx, twist.vy, twist.wz)
                progress.show(time.monotonic() - start, leg.label)
                time.sleep(min(COMMAND_PERIOD_S, max(0.0, end - time.monotonic())))
            measured = base.twist
    finally:
        progress.close()
    elapsed = time.monotonic() - start
    _settle(base)
    return measured, elapsed


def _settle(base: Chassis, timeout_s: float = 3.0) -> None:
    """Stop and wait (bounded) until the wheels stand still."""
    base.stop()
    settle_until = time.monotonic() + timeout_s
    while time.monotonic() < settle_until:
        if base.command.is_zero() and all(abs(w.actual_speed) < 0.002 for w in base.wheels):
            break
        time.sleep(COMMAND_PERIOD_S)
    time.sleep(0.05)  # the last samples of the stop reach the odometry


class BaseStoppedError(Exception):
    """The base stopped itself (fault, lost drive) during the motion."""


def _note(text: str) -> None:
    print(f"omnican: {text}", file=sys.stderr, flush=True)


def run(args: argparse.Namespace) -> int:
    plan = legs(args)
    with session(args) as s:
        with Chassis.open(s.cfg, record=args.record) as base, \
                watch(base, s.sim, args.foxglove, announce=_note):
            try:
                twist, elapsed = execute(base, plan)
            except BaseStoppedError as exc:
                print(f"omnican: error: base stopped: {exc}", file=sys.stderr)
                print(pose_line(base.pose))
                return EXIT_FAILURE
            pose = base.pose
        result: dict[str, Any] = {
            "pose": pose_dict(pose),
            "twist": {k: round(v, 6) for k, v in asdict(twist).items()},
            "duration_s": round(elapsed, 3),
        }
        if s.sim is not None:
            result["true_pose"] = pose_dict(s.sim.true_pose)
    if args.json:
        print(json.dumps(result))
    else:
        t = twist
        print(f"drove {elapsed:.2f} s; measured twist vx={t.vx:.3f} vy={t.vy:.3f} wz={t.wz:.3f}")
        if "true_pose" in result:
            tp = result["true_pose"]
            print(f"true pose x={tp['x']:.4f} y={tp['y']:.4f} theta={tp['theta']:.4f} (simulated)")
        print(pose_line(pose))
    return EXIT_OK
