"""omnican calibrate's guided run: the base drives a straight line and spins in place;
the operator (or the command line, or under --sim the simulator's ground truth) gives
how far it really went and turned; the correction follows.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass
from typing import Any

from omnican.analysis import calibration
from omnican.cli.calibrate.output import (
    edits_of,
    new_radius,
    print_correction,
    print_written,
    wheel_changes,
    write_config,
)
from omnican.cli.common import EXIT_FAILURE, EXIT_OK, UsageError
from omnican.cli.progress import progress_bar
from omnican.cli.session import load, recording, session
from omnican.command import motion
from omnican.config import ChassisConfig, SimTruth
from omnican.core.odometry import Pose2D
from omnican.errors import BaseStoppedError

DEFAULT_SIM_SCALE_ERROR = 0.03
DEFAULT_SIM_RADIUS_ERROR = 0.02
MAX_ASK_TRIES = 3
TRUTH = "simulator ground truth"


@dataclass
class Measurements:
    distance_odometry: float
    distance_measured: float
    angle_odometry: float
    angle_measured: float
    distance_source: str  # where the measured values came from
    angle_source: str
    sim: SimTruth | None = None  # under --sim: the simulated base, as it really is


def _ask(prompt: str, parse: Any) -> float:
    """Ask the operator on the terminal (prompt on stderr) until the answer parses."""
    for _ in range(MAX_ASK_TRIES):
        sys.stderr.write(prompt)
        sys.stderr.flush()
        line = sys.stdin.readline()
        if not line:
            raise UsageError("no answer (end of input)")
        try:
            value: float = parse(line.strip())
            return value
        except ValueError as exc:
            print(f"  {exc}; try again", file=sys.stderr)
    raise UsageError(f"no valid answer after {MAX_ASK_TRIES} tries")


def _parse_distance(text: str) -> float:
    problem = "give a positive distance in metres"
    try:
        value = float(text)
    except ValueError:
        raise ValueError(problem) from None
    if not (math.isfinite(value) and value > 0):
        raise ValueError(problem)
    return value


def _parse_turns(text: str) -> float:
    """Turns, or degrees with a 'deg' suffix."""
    problem = "give a positive number of turns (or degrees, e.g. 712deg)"
    t = text.lower()
    try:
        value = float(t[:-3]) / 360.0 if t.endswith("deg") else float(t)
    except ValueError:
        raise ValueError(problem) from None
    if not (math.isfinite(value) and value > 0):
        raise ValueError(problem)
    return value


def guided_run(args: argparse.Namespace) -> tuple[ChassisConfig, Measurements]:
    """Drive the straight line and the spin; return the config and the measurements."""
    from omnican.chassis import Chassis

    cfg = load(args)
    options: dict[str, Any] = {}
    sim_base = simulated_base(cfg, args) if args.sim else None
    if sim_base is not None:
        options = calibration.sim_options(cfg, sim_base)
    measured_turns = args.measured_turns
    if args.measured_angle_deg is not None:
        measured_turns = args.measured_angle_deg / 360.0
    interactive = not args.sim and (args.measured_distance is None or measured_turns is None)
    angle = 2 * math.pi * args.turns
    try:  # a distance or turns no motion may be (motion.MAX_TRAVEL, MAX_MOTION_S)
        straight = motion.straight(args.distance, args.speed)
        spin = motion.spin(angle, args.omega)
    except ValueError as exc:
        raise UsageError(f"calibration run refused: {exc}") from None
    too_much = motion.extent_problem([straight, spin], cfg)
    if too_much is not None:
        raise UsageError(f"calibration run refused: {too_much}")
    if interactive:
        print(f"The base will drive {args.distance:g} m straight ahead, stop for you to "
              f"measure, then spin {args.turns:g} turns counter-clockwise in place. Mark its "
              "position and heading on the floor, clear the way, then press Enter (Ctrl-C "
              "aborts).", file=sys.stderr)
        if not sys.stdin.readline():
            raise UsageError("no answer (end of input)")
    with session(args, **options) as s, \
            Chassis.open(s.cfg, record=recording(args.record), clock=s.clock) as base:
        sim = s.sim
        truth: list[Pose2D] = [sim.true_pose] if sim is not None else []
        poses = [base.pose]
        try:
            with progress_bar(straight.seconds) as bar:
                motion.run(base, [straight], bar)
            poses.append(base.pose)
            if sim is not None:
                truth.append(sim.true_pose)
            distance = args.measured_distance
            if distance is None and interactive:
                distance = _ask(f"Measured straight distance, m (odometry: "
                                f"{poses[1].distance_to(poses[0]):.4f}): ", _parse_distance)
            with progress_bar(spin.seconds) as bar:
                motion.run(base, [spin], bar)
        except BaseStoppedError as exc:
            raise _RunError(f"base stopped: {exc}") from None
        poses.append(base.pose)
        if sim is not None:
            truth.append(sim.true_pose)
    odo_distance = poses[1].distance_to(poses[0])
    odo_angle = poses[2].theta - poses[1].theta
    given = "operator" if interactive else "command line"
    distance_source = angle_source = given
    if args.measured_distance is not None:
        distance_source = "command line"
    if distance is None:
        distance = truth[1].distance_to(truth[0])
        distance_source = TRUTH
    if measured_turns is None and interactive:
        measured_turns = _ask(f"Measured rotation, turns (or e.g. 712deg) (odometry: "
                              f"{odo_angle / (2 * math.pi):.4f}): ", _parse_turns)
    elif measured_turns is not None:
        angle_source = "command line"
    if measured_turns is None:
        measured_angle = truth[2].theta - truth[1].theta
        angle_source = TRUTH
    else:
        measured_angle = 2 * math.pi * measured_turns
    return cfg, Measurements(odo_distance, distance, odo_angle, measured_angle,
                             distance_source, angle_source, sim_base)


def simulated_base(cfg: ChassisConfig, args: argparse.Namespace) -> SimTruth:
    """The simulated base --sim drives, as it really is: --sim-scale-error and
    --sim-radius-error against the config where given; else the config's [sim] table
    (the same base as the run that wrote it), else the defaults against the config."""
    recorded = cfg.sim
    if recorded is None:
        recorded = calibration.sim_truth(cfg, DEFAULT_SIM_SCALE_ERROR, DEFAULT_SIM_RADIUS_ERROR)
    given = calibration.sim_truth(cfg, args.sim_scale_error or 0.0, args.sim_radius_error or 0.0)
    return SimTruth(
        recorded.base_radius if args.sim_radius_error is None else given.base_radius,
        recorded.position_scale if args.sim_scale_error is None else given.position_scale)


def _digits(cfg: ChassisConfig, m: Measurements) -> int:
    """Significant digits the measurements support: a tape's millimetre and a floor
    mark's degree; for the simulator's truth, one encoder count (what the odometry
    resolves)."""
    per_count = 1.0 / min(abs(w.position_scale) for w in cfg.wheels)  # m of rim travel
    by_hand = {"distance": m.distance_source != TRUTH, "angle": m.angle_source != TRUTH}
    return calibration.measured_digits(
        m.distance_measured, m.angle_measured,
        calibration.DISTANCE_RESOLUTION_M if by_hand["distance"] else per_count,
        calibration.ANGLE_RESOLUTION_RAD if by_hand["angle"] else
        per_count / max(cfg.kinematics().base_radius))


class _RunError(Exception):
    """The calibration run could not finish (exit 1)."""


def run_guided(args: argparse.Namespace) -> int:
    """The guided run, its correction printed (and written with --write)."""
    try:
        cfg, m = guided_run(args)
    except _RunError as exc:
        print(f"omnican: error: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    try:
        correction = calibration.guided_correction(len(cfg.wheels), m.distance_odometry,
                                                   m.distance_measured, m.angle_odometry,
                                                   m.angle_measured)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    correction = correction.with_digits(_digits(cfg, m))
    edits = edits_of(cfg, correction)  # before --write may replace the --config file
    if args.write:
        write_config(args.write, cfg, correction, m.sim)
    if args.json:
        print(json.dumps({
            "source": {"distance": m.distance_source, "angle": m.angle_source},
            "distance": {"odometry": m.distance_odometry, "measured": m.distance_measured},
            "angle_rad": {"odometry": m.angle_odometry, "measured": m.angle_measured},
            "scale_factor": correction.wheel_factors[0],
            "radius_factor": correction.radius_factor,
            "wheels": wheel_changes(cfg, correction),
            "base_radius": [cfg.chassis.base_radius, new_radius(edits)],
            "written": args.write,
        }))
        return EXIT_OK
    print(f"straight: odometry {m.distance_odometry:.4f} m, measured "
          f"{m.distance_measured:.4f} m ({m.distance_source})")
    print(f"spin:     odometry {math.degrees(m.angle_odometry):.2f} deg, measured "
          f"{math.degrees(m.angle_measured):.2f} deg ({m.angle_source})")
    print_correction(cfg, correction, edits)
    if m.sim is not None:
        options = calibration.sim_options(cfg, m.sim)
        factors = [f"{f:.5f}" for f in options["true_scale"]]
        scale = (f"scale factor {factors[0]}" if len(set(factors)) == 1 else
                 "scale factors " + ", ".join(factors))
        radius = cfg.chassis.base_radius if m.sim.base_radius is None else m.sim.base_radius
        print(f"simulator truth: {scale}, base_radius {radius:.6g} m")
    print_written(args.write)
    return EXIT_OK
