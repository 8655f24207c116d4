"""omnican drive: scripted motion, for scripts and tests.

Give one form of motion: straight (--vx --vy --wz, held for --duration), polar
(--speed along --heading-deg, degrees from forward and counter-clockwise, while
turning at --omega) or a square (--square SIDE, turning 90 deg left in place at
each corner). Prints the final pose, or one JSON object with --json. Speeds above
the base's limits are scaled down to them, with a warning.

With --foxglove-control and no motion, the base stands still for --duration seconds
(until Ctrl-C without one) and takes its commands from Foxglove (the Teleop panel,
services, parameters), then prints the same. --zenoh puts the base on Zenoh beside it
(as omnican zenoh does): with no motion it takes cmd_vel from there the same way; with
a motion, the motion holds control (a cmd_vel publisher is refused) and a stop from the
network (~/stop, a fleet stop) ends it, exit 1.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import math
import sys
from collections.abc import Iterator
from dataclasses import asdict
from typing import Any

from omnican.chassis import Chassis, supervisor
from omnican.cli import front_ends
from omnican.cli.common import (
    EXIT_FAILURE,
    EXIT_OK,
    UsageError,
    finite_float,
    fixed,
    interrupted_exit,
    interrupted_word,
    pose_dict,
    pose_line,
    positive_float,
    rounded,
)
from omnican.cli.progress import progress_bar
from omnican.cli.session import (
    add_bus_arguments,
    add_record_argument,
    add_sim_time_arguments,
    session,
)
from omnican.command import motion
from omnican.command.motion import Leg
from omnican.core.kinematics import Twist
from omnican.core.odometry import Pose2D
from omnican.errors import BaseStoppedError, ConfigError, OmnicanError
from omnican.plan.health_fields import HEALTH_FIELDS

DEFAULT_DURATION_S = 1.0
SQUARE_SPEED, SQUARE_OMEGA = 0.3, 1.0  # m/s, rad/s


def no_motion() -> str:
    """What drive says when it is given nothing to drive: the motions, and the front ends
    that could drive instead."""
    flags, titles = front_ends.drive_flags()
    return ("give a motion: --vx/--vy/--wz, --speed/--heading-deg/--omega, --square SIDE, "
            f"or {' or '.join(flags)} to take it from {' or '.join(titles)}")


def add_subparser(sub: Any) -> None:
    p = sub.add_parser("drive", help="drive a scripted motion and print the pose",
                       description=__doc__,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    motion = p.add_argument_group("motion (pick one form)")
    motion.add_argument("--vx", type=finite_float, metavar="M/S",
                        help="forward speed (default 0)")
    motion.add_argument("--vy", type=finite_float, metavar="M/S",
                        help="leftward speed (default 0)")
    motion.add_argument("--wz", type=finite_float, metavar="RAD/S",
                        help="turn rate, counter-clockwise positive (default 0)")
    motion.add_argument("--speed", type=finite_float, metavar="M/S",
                        help="polar form: speed along --heading-deg (default 0; square: the "
                             f"speed along the sides, default {SQUARE_SPEED:g})")
    motion.add_argument("--heading-deg", type=finite_float, metavar="DEG",
                        help="polar form: direction of travel, degrees from forward, "
                             "counter-clockwise (default 0)")
    motion.add_argument("--omega", type=finite_float, metavar="RAD/S",
                        help="polar form: turn rate (default 0; square: the turn rate at the "
                             f"corners, default {SQUARE_OMEGA:g})")
    motion.add_argument("--square", type=positive_float, metavar="SIDE",
                        help="drive a square with sides of SIDE m, turning 90 deg left in place")
    p.add_argument("--duration", type=positive_float, metavar="S",
                   help=f"seconds to hold the velocity (default {DEFAULT_DURATION_S:g}; not with "
                        "--square); with --foxglove-control and no motion, seconds to take "
                        "commands from Foxglove (default: until Ctrl-C)")
    p.add_argument("--json", action="store_true",
                   help='print {"pose", "twist", "duration_s", "wheels"} (+ "imu" and '
                        '"fused_pose" with an [imu] table, "true_pose" under --sim); a '
                        'run-time failure prints {"error", "pose", ...} and exits 1')
    add_record_argument(p)
    front_ends.add_arguments(p, "base")
    add_bus_arguments(p)
    add_sim_time_arguments(p)
    p.set_defaults(func=run)


def legs(args: argparse.Namespace) -> list[Leg] | None:
    """The motion as legs (None: no motion given, for Foxglove to drive); bad
    combinations, and values beyond any wheeled base (the base's own check), are usage
    errors."""
    plan = _legs(args)
    problem = motion.plan_problem(plan or [])
    if problem is not None:
        raise UsageError(f"motion refused: {problem}")
    return plan


def _legs(args: argparse.Namespace) -> list[Leg] | None:
    cartesian = any(v is not None for v in (args.vx, args.vy, args.wz))
    polar = any(v is not None for v in (args.speed, args.heading_deg, args.omega))
    refused = front_ends.motion_refused(args)  # a front end that drives instead
    if args.square is not None:
        if refused is not None:
            raise UsageError(refused)
        if cartesian or args.heading_deg is not None:
            raise UsageError("--square takes only --speed and --omega")
        if args.duration is not None:
            raise UsageError("--duration is not used with --square (it drives until the "
                             "square is done)")
        speed = args.speed if args.speed is not None else SQUARE_SPEED
        omega = args.omega if args.omega is not None else SQUARE_OMEGA
        if speed <= 0 or omega <= 0:
            raise UsageError("--square needs a positive --speed and --omega")
        try:
            return motion.square(args.square, speed, omega)
        except ValueError as exc:  # a side no motion may be (motion.MAX_TRAVEL, ...)
            raise UsageError(f"motion refused: --square {args.square:g}: {exc}") from None
    if cartesian and polar:
        raise UsageError("give either --vx/--vy/--wz or --speed/--heading-deg/--omega")
    if refused is not None and (cartesian or polar):
        raise UsageError(refused)
    if not (cartesian or polar):
        return None  # a front end's to drive, if one may (the config may say so)
    duration = args.duration if args.duration is not None else DEFAULT_DURATION_S
    if polar:
        if args.heading_deg is not None and args.speed is None:
            raise UsageError("--heading-deg needs --speed (the speed along that heading)")
        twist = motion.polar_twist(args.speed or 0.0, args.heading_deg or 0.0, args.omega or 0.0)
    else:
        twist = Twist(args.vx or 0.0, args.vy or 0.0, args.wz or 0.0)
    return [motion.hold(twist, duration)]


def execute(base: Chassis, plan: list[Leg]) -> motion.MotionResult:
    """Run the plan with a progress bar on a terminal."""
    c = base.cfg.chassis
    with progress_bar(motion.nominal_duration(plan, c.max_accel, c.max_angular_accel)) as bar:
        return motion.run(base, plan, bar)


def take_commands(base: Chassis, duration_s: float | None,
                  whence: str) -> motion.MotionResult:
    """Command nothing for ``duration_s`` (None: until Ctrl-C) while ``whence``
    (Foxglove, Zenoh) drives; the measured twist at the end."""
    clock = base.clock
    start = clock.now()
    end = start + duration_s if duration_s is not None else math.inf
    twist = Twist()
    with progress_bar(duration_s or 0.0) as bar:
        while (now := clock.now()) < end:
            bar(now - start, duration_s or 0.0, whence)
            clock.sleep(min(0.05, end - now))
            twist = base.twist
    elapsed = clock.now() - start
    motion.settle(base)  # the pose printed is where it stopped
    return motion.MotionResult(twist, elapsed)


class Arbitrated:
    """The base as a motion drives it beside front ends that drive too (Zenoh's): its
    commands go through a command source of the base's one arbiter, so that a cmd_vel
    publisher cannot take the base over mid-motion (it is refused while the motion
    drives), and a stop from another source (~/stop, a fleet stop) ends the motion:
    BaseStoppedError naming who stopped it. The rest is the base's."""

    SOURCE = "the scripted motion"

    def __init__(self, base: Chassis) -> None:
        self._base = base
        self._source = base.command_source(self.SOURCE)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._base, name)

    def set_velocity(self, vx: float, vy: float, wz: float) -> None:
        sent = self._source.drive(Twist(vx, vy, wz))
        if not sent.ok:
            how = "stopped by" if self._source.stopped_by() else "taken over by"
            raise BaseStoppedError(f"{how} {sent.refused_by}")


def _number(value: float) -> str:
    return f"{value:.6g}" if value else "0"


def _note(text: str) -> None:
    print(f"omnican: {text}", file=sys.stderr, flush=True)


def run(args: argparse.Namespace) -> int:
    plan = legs(args)
    if plan is None and not front_ends.asked(args) and not args.config:  # a config may
        raise UsageError(no_motion())  # turn a front end on; else none could drive
    seen: dict[str, Any] = {}  # what is known when a run-time failure ends the run
    try:
        return _run(args, plan, seen)
    except OmnicanError as exc:
        if isinstance(exc, ConfigError) or not args.json:
            raise
        _fail_json(str(exc), seen)
        raise
    except KeyboardInterrupt as exc:  # Ctrl-C or SIGTERM before the motion, or after it
        word = interrupted_word(exc)
        when = ("after the run" if "duration_s" in seen else
                "during bring-up: nothing moved; every drive is disabled")
        print(f"omnican: {word} {when}", file=sys.stderr)
        if args.json:
            _fail_json(word, seen)
        elif "pose" in seen:
            print(pose_line(Pose2D(**seen["pose"])))
        return interrupted_exit(exc)


def _fail_json(error: str, seen: dict[str, Any]) -> None:
    """With --json, a run-time failure is a JSON object too (scripts parse stdout)."""
    print(json.dumps({"error": error, "pose": seen.get("pose"), "twist": None,
                      "duration_s": seen.get("duration_s"), "wheels": seen.get("wheels"),
                      **({"true_pose": seen["true_pose"]} if "true_pose" in seen else {})}))


def imu_json(base: Any) -> dict[str, Any] | None:
    """The configured IMU as --json shows it: its source, the samples it gave, and how
    long it had been silent at the end (null: it never spoke); None: no [imu]."""
    inbox, imu = base.imu, base.cfg.imu
    if inbox is None or imu is None:
        return None
    last = inbox.last_t
    return {"source": imu.source, "samples": inbox.received,
            "silent_s": None if last is None else round(max(0.0, base.clock.now() - last), 3)}


#: What --json gives of what each drive reports (omnican.plan.health_fields).
JSON_HEALTH = tuple(f.name for f in HEALTH_FIELDS if f.in_drive_json)


def wheels_json(wheels: Any) -> list[dict[str, Any]]:
    """Each wheel's drive as --json shows it (null: the drive does not give it)."""
    return [{"node_id": w.node_id, "axis": w.axis,
             "state": str(w.state) if w.online else "OFFLINE",
             **{name: None if (value := getattr(w, name)) is None else rounded(value)
                for name in JSON_HEALTH}} for w in wheels]


class _StopSaidOnce(logging.Filter):
    """The library warns "base stopped: <reason>" when a stop latches, and drive ends
    such a run with an error naming the same stop: held back here so that each stop is
    said once. A stop the error does not name (the run ended otherwise) is said on exit."""

    def __init__(self) -> None:
        super().__init__()
        self.held: list[logging.LogRecord] = []
        self.said = False

    def filter(self, record: logging.LogRecord) -> bool:
        if record.getMessage().startswith("base stopped: "):
            self.held.append(record)
            return False
        return True


@contextlib.contextmanager
def _stop_said_once() -> Iterator[_StopSaidOnce]:
    logger = supervisor.logger  # the one that says a stop latched
    hold = _StopSaidOnce()
    logger.addFilter(hold)
    try:
        yield hold
    finally:
        logger.removeFilter(hold)
        if not hold.said:
            for record in hold.held:
                logger.handle(record)


def _run(args: argparse.Namespace, given: list[Leg] | None, seen: dict[str, Any]) -> int:
    with session(args) as s, _stop_said_once() as stops:
        running = front_ends.from_args(args, s.cfg, "base")
        drivers = [front_end for front_end in running if front_end.drives]
        if given is None and not drivers:
            raise UsageError(no_motion())
        for front_end in running:
            problem = front_end.motion_problem() if given is not None else None
            if problem is not None:
                raise UsageError(problem)
        for front_end in running:
            problem = front_end.lockstep_problem() if s.clock.lockstep else None
            if problem is not None:
                raise UsageError(problem)
        plan: list[Leg] = given or []
        too_much = motion.extent_problem(plan, s.cfg) if plan else None
        if too_much is not None:  # before anything moves, as a value beyond sense is
            raise UsageError(f"motion refused: {too_much}")
        plan, clamps = motion.fit_to_limits(plan, s.cfg) if plan else (plan, [])
        for c in clamps:
            r, a = c.requested, c.applied
            print(f"omnican: warning: vx={_number(r.vx)} vy={_number(r.vy)} wz={_number(r.wz)} "
                  f"is beyond the base's limits ({c.limit}): driving vx={fixed(a.vx, 3)} "
                  f"vy={fixed(a.vy, 3)} wz={fixed(a.wz, 3)}", file=sys.stderr)
        front_ends.prepare(running, s.cfg)  # their slow set-up before the control loop runs
        whence = " and ".join(front_end.title for front_end in drivers)
        with s.open_base(record=args.record) as base, \
                front_ends.attached(running, base, s.sim, announce=_note):
            driven: Any = Arbitrated(base) if drivers else base
            try:
                result = (execute(driven, plan) if plan else
                          take_commands(base, args.duration, whence))
            except BaseStoppedError as exc:
                print(f"omnican: error: base stopped: {exc}", file=sys.stderr)
                stops.said = True
                if args.json:
                    seen["pose"] = pose_dict(base.pose)
                    seen["wheels"] = wheels_json(base.wheels)
                    if s.sim is not None:
                        seen["true_pose"] = pose_dict(s.sim.true_pose)
                    _fail_json(f"base stopped: {exc}", seen)
                else:
                    print(pose_line(base.pose))
                return EXIT_FAILURE
            except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM (timeout, kill)
                base.stop()
                motion.settle(base)
                word = interrupted_word(exc)
                print(f"omnican: {word}: the base stopped here", file=sys.stderr)
                if args.json:
                    seen["pose"] = pose_dict(base.pose)
                    seen["wheels"] = wheels_json(base.wheels)
                    if s.sim is not None:
                        seen["true_pose"] = pose_dict(s.sim.true_pose)
                    _fail_json(word, seen)
                else:
                    print(pose_line(base.pose))
                return interrupted_exit(exc)
            pose, fused = base.pose, base.fused_pose  # (fused: None without an IMU)
            seen["pose"] = pose_dict(pose)
            seen["duration_s"] = round(result.elapsed_s, 3)
            seen["wheels"] = wheels_json(base.wheels)
            imu = imu_json(base)
        out: dict[str, Any] = {
            "pose": pose_dict(pose),
            "twist": {k: rounded(v) for k, v in asdict(result.twist).items()},
            "duration_s": round(result.elapsed_s, 3),
            "wheels": seen["wheels"],
        }
        if s.sim is not None:
            out["true_pose"] = pose_dict(s.sim.true_pose)
        if imu is not None:
            out["imu"] = imu
        if fused is not None:
            out["fused_pose"] = pose_dict(fused)
        # The motion ran, but a drive the close could not confirm disabled (the error
        # logged names it) is a failure at run time.
        if base.not_disabled:
            out["error"] = "base closed; not confirmed disabled: " + ", ".join(
                base.not_disabled)
    if args.json:
        print(json.dumps(out))
    else:
        t = result.twist
        when = "once stopped on the goal" if plan and plan[-1].is_goal else "before the stop"
        what = "drove" if plan else f"took commands from {whence} for"
        print(f"{what} {result.elapsed_s:.2f} s; measured twist {when}: vx={fixed(t.vx, 3)} "
              f"vy={fixed(t.vy, 3)} wz={fixed(t.wz, 3)}")
        if "true_pose" in out:
            print(pose_line(s.sim.true_pose).replace("pose", "true pose", 1) + " (simulated)")
        print(pose_line(pose))
        if fused is not None:
            print(pose_line(fused).replace("pose", "fused pose", 1) + " (wheels and gyro)")
    return EXIT_FAILURE if "error" in out else EXIT_OK
