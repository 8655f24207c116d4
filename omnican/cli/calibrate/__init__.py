"""omnican calibrate: correct the wheel scales and the base radius of a config.

Guided (or scripted) run: the base drives --distance m straight ahead, then spins
--turns turns counter-clockwise in place. Measure how far it really went and how far
it really turned; the command asks for both when it runs in a terminal, or takes
--measured-distance and --measured-turns (or --measured-angle-deg). Under --sim the
simulated base is built a little wrong (--sim-scale-error, --sim-radius-error) and
its ground truth stands in for the measurements; --write records that base in the
config's [sim] table, so the next --sim run drives the same base (and finds the
corrections near zero). Without the options, a config's [sim] table says what the
simulated base is.

    scale s = odometry distance / measured distance
              (true counts per metre / configured: velocity_scale and position_scale
              are multiplied by s, wheel_radius divided by s)
    radius  R = R_config * (odometry angle / s) / measured angle

Fit: --fit RECORDING --pose X,Y,THETA (repeatable) fits per-wheel scales and the
base radius to recordings (omnican drive --record, or calibrate --record) and the
measured end pose of each (x forward, y left in the start pose's frame, m; THETA in
rad, or with a 'deg' suffix). Three equations per recording: one recording fits a
common scale and the radius, two or more a scale per wheel and the radius. Drive
open paths (a straight line, then a spin): a closed loop says little about the scale.

--write OUT.toml writes the corrected config, editing the numbers in place so
comments and layout stay (OUT may be the --config file itself).
"""

# The docstring above is the command's --help. Its parts: guided.py (the straight run
# and the spin), fit.py (--fit), output.py (what is printed, and --write).

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from omnican.analysis import calibration
from omnican.cli.calibrate.fit import parse_pose, run_fit
from omnican.cli.calibrate.guided import (
    DEFAULT_SIM_RADIUS_ERROR,
    DEFAULT_SIM_SCALE_ERROR,
    MAX_ASK_TRIES,
    TRUTH,
    Measurements,
    guided_run,
    run_guided,
    simulated_base,
)
from omnican.cli.calibrate.output import write_config
from omnican.cli.common import UsageError, finite_float, positive_float
from omnican.cli.session import (
    add_bus_arguments,
    add_record_argument,
    add_sim_time_arguments,
    bus_overrides,
)

__all__ = [
    "DEFAULT_SIM_RADIUS_ERROR",
    "DEFAULT_SIM_SCALE_ERROR",
    "MAX_ASK_TRIES",
    "TRUTH",
    "Measurements",
    "add_subparser",
    "guided_run",
    "parse_pose",
    "run",
    "simulated_base",
    "write_config",
]


def add_subparser(sub: Any) -> None:
    p = sub.add_parser("calibrate", help="calibrate the wheel scales and the base radius",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    run_g = p.add_argument_group("guided run")
    run_g.add_argument("--distance", type=positive_float, default=1.0, metavar="M",
                       help="straight distance to drive, m (default 1.0)")
    run_g.add_argument("--turns", type=positive_float, default=2.0, metavar="N",
                       help="turns to spin in place, counter-clockwise (default 2)")
    run_g.add_argument("--speed", type=positive_float, default=0.2, metavar="M/S",
                       help="straight-line speed (default 0.2)")
    run_g.add_argument("--omega", type=positive_float, default=1.0, metavar="RAD/S",
                       help="spin rate (default 1.0)")
    run_g.add_argument("--measured-distance", type=positive_float, metavar="M",
                       help="the distance the base really drove, m (else asked, or the "
                            "simulator's truth under --sim)")
    angle = run_g.add_mutually_exclusive_group()
    angle.add_argument("--measured-turns", type=finite_float, metavar="N",
                       help="the turns the base really spun")
    angle.add_argument("--measured-angle-deg", type=finite_float, metavar="DEG",
                       help="the angle the base really spun, degrees")
    add_record_argument(run_g, "record the run to FILE (e.g. for --fit later)")
    sim_g = p.add_argument_group("simulated base (--sim)")
    sim_g.add_argument("--sim-scale-error", type=finite_float, metavar="F",
                       help="the simulated wheels turn 1+F times the configured counts per m "
                            f"(default: the config's [sim] table, else {DEFAULT_SIM_SCALE_ERROR})")
    sim_g.add_argument("--sim-radius-error", type=finite_float, metavar="F",
                       help="the simulated base radius is 1+F times the configured one "
                            f"(default: the config's [sim] table, else {DEFAULT_SIM_RADIUS_ERROR})")
    fit_g = p.add_argument_group("fit to recordings (no bus)")
    fit_g.add_argument("--fit", action="append", metavar="RECORDING", default=[],
                       help="a recording made on the --config base (repeatable)")
    fit_g.add_argument("--pose", action="append", metavar="X,Y,THETA", default=[],
                       help="measured end pose of the matching --fit recording (m, m, rad; "
                            "THETA may end in 'deg'); write --pose=-0.1,0,0 when X is negative")
    fit_g.add_argument("--model", choices=["auto", *calibration.MODELS], default="auto",
                       help="what to fit (default auto: the most the recordings determine)")
    p.add_argument("--write", metavar="OUT.toml",
                   help="write the corrected config to OUT.toml (may be the --config file)")
    p.add_argument("--json", action="store_true", help="print the result as one JSON object")
    add_bus_arguments(p, sim_help="calibrate simulated drives in this process (a virtual bus), "
                                  "built slightly wrong so there is something to find")
    add_sim_time_arguments(p)
    p.set_defaults(func=run)


# ---------------------------------------------------------------- arguments


def _check_args(args: argparse.Namespace) -> None:
    if args.write and not Path(args.write).parent.is_dir():
        raise UsageError(f"--write {args.write}: no such directory {Path(args.write).parent}")
    measured = (args.measured_distance is not None or args.measured_turns is not None
                or args.measured_angle_deg is not None)
    sim_errors = args.sim_scale_error is not None or args.sim_radius_error is not None
    if args.fit or args.pose:
        if len(args.fit) != len(args.pose):
            raise UsageError(f"give one --pose per --fit recording ({len(args.fit)} recordings, "
                             f"{len(args.pose)} poses)")
        if args.sim or measured or sim_errors or args.record:
            raise UsageError("--fit works on recordings: it takes no --sim, --measured-*, "
                             "--sim-*-error or --record")
        if bus_overrides(args):
            raise UsageError("--fit touches no bus: drop the bus arguments")
        return
    if args.model != "auto":
        raise UsageError("--model is for --fit")
    if sim_errors and not args.sim:
        raise UsageError("--sim-scale-error and --sim-radius-error need --sim")
    for name in ("sim_scale_error", "sim_radius_error"):
        value = getattr(args, name)
        if value is not None and not -0.5 < value < 0.5:
            raise UsageError(f"--{name.replace('_', '-')} must lie within +-0.5, got {value}")
    turns = args.measured_turns
    if args.measured_angle_deg is not None:
        turns = args.measured_angle_deg / 360.0
    if turns is not None and turns <= 0:
        raise UsageError("the measured rotation must be positive (the spin is "
                         "counter-clockwise)")
    missing = args.measured_distance is None or turns is None
    if missing and not args.sim and not sys.stdin.isatty():
        raise UsageError("no terminal to ask for the measured values: give "
                         "--measured-distance and --measured-turns (or --measured-angle-deg), "
                         "or use --sim")


def run(args: argparse.Namespace) -> int:
    _check_args(args)
    if args.fit:
        return run_fit(args)
    return run_guided(args)
