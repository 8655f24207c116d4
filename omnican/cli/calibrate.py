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

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from omnican.analysis import calibration
from omnican.analysis.calibration import Correction, FitResult, FitRun
from omnican.cli.common import (
    EXIT_FAILURE,
    EXIT_OK,
    UsageError,
    add_bus_arguments,
    add_record_argument,
    add_sim_time_arguments,
    bus_overrides,
    finite_float,
    load,
    positive_float,
    progress_bar,
    recording,
    session,
)
from omnican.command import motion
from omnican.config import WHEEL_EDS, ChassisConfig, SimTruth
from omnican.core.odometry import Pose2D
from omnican.errors import BaseStoppedError, ConfigError
from omnican.record import replay

DEFAULT_SIM_SCALE_ERROR = 0.03
DEFAULT_SIM_RADIUS_ERROR = 0.02
MAX_ASK_TRIES = 3
TRUTH = "simulator ground truth"


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


def parse_pose(text: str) -> tuple[float, float, float]:
    """``X,Y,THETA`` (m, m, rad; THETA may end in ``deg``)."""
    parts = [p.strip() for p in text.split(",")]
    if len(parts) != 3:
        raise UsageError(f"--pose {text!r}: give X,Y,THETA (m, m, rad or e.g. 90deg)")
    theta_text = parts[2].lower()
    degrees = theta_text.endswith("deg")
    try:
        values = [float(parts[0]), float(parts[1]),
                  float(theta_text[:-3] if degrees else theta_text)]
    except ValueError:
        raise UsageError(f"--pose {text!r}: not three numbers") from None
    if not all(math.isfinite(v) for v in values):
        raise UsageError(f"--pose {text!r}: must be finite numbers")
    if degrees:
        values[2] = math.radians(values[2])
    return values[0], values[1], values[2]


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


# ---------------------------------------------------------------- the guided run


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
    straight = motion.straight(args.distance, args.speed)
    spin = motion.spin(angle, args.omega)
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


# ---------------------------------------------------------------- output


def _pct(factor: float) -> str:
    return f"{(factor - 1.0) * 100:+.2f} %"


def _changes(cfg: ChassisConfig, c: Correction) -> list[dict[str, Any]]:
    corrected = c.apply(cfg)

    def written(value: float) -> float:
        return float(calibration.format_number(value, c.digits))

    out = []
    for i, (a, b) in enumerate(zip(cfg.wheels, corrected.wheels, strict=True)):
        out.append({"wheel": i, "node_id": a.node_id, "axis": a.axis,
                    "factor": b.position_scale / a.position_scale,
                    "velocity_scale": [a.velocity_scale, written(b.velocity_scale)],
                    "position_scale": [a.position_scale, written(b.position_scale)]})
    return out


def _edits(cfg: ChassisConfig, c: Correction) -> list[calibration.ConfigEdit]:
    """The numbers ``--write`` changes, in the config file's own terms (``wheel_radius``
    where the file gives physical parameters); for the demo base, which has no file,
    the scales and the radius a new file gets."""
    if cfg.source is not None:
        try:
            text = Path(cfg.source).read_text(encoding="utf-8")
        except OSError as exc:
            raise ConfigError(f"cannot read {cfg.source}: {exc.strerror or exc}") from None
        return calibration.edit_config(text, c)[1]
    corrected = c.apply(cfg)
    edits = []
    for i, (a, b) in enumerate(zip(cfg.wheels, corrected.wheels, strict=True)):
        for key in ("velocity_scale", "position_scale"):
            edits.append(calibration.ConfigEdit(
                i, key, getattr(a, key),
                float(calibration.format_number(getattr(b, key), c.digits))))
    edits.append(calibration.ConfigEdit(None, "base_radius", cfg.chassis.base_radius, float(
        calibration.format_number(corrected.chassis.base_radius, c.digits))))
    return edits


def _print_correction(cfg: ChassisConfig, c: Correction,
                      edits: list[calibration.ConfigEdit]) -> None:
    """Old -> new of every number --write changes (``edits``: read from the config as it
    was, before any --write replaced it)."""
    common = len(set(c.wheel_factors)) == 1
    if common:
        print(f"wheel scale factor {c.wheel_factors[0]:.5f} ({_pct(c.wheel_factors[0])}): "
              "true counts per metre / configured")
    for i, (w, s) in enumerate(zip(cfg.wheels, c.wheel_factors, strict=True)):
        name = f"wheel {i} (node {w.node_id}" + (f" axis {w.axis})" if w.axis else ")")
        factor = "" if common else f" factor {s:.5f} ({_pct(s)}):"
        changes = ", ".join(f"{e.key} {e.old:.7g} -> {e.new:.7g}" for e in edits if e.wheel == i)
        print(f"  {name}:{factor} {changes or 'nothing to change'}")
    for e in edits:
        if e.wheel is None:
            print(f"{e.key} {e.old:.7g} -> {e.new:.7g} m ({_pct(c.radius_factor)})")
    if any(abs(f - 1.0) > 0.2 for f in (*c.wheel_factors, c.radius_factor)):
        print("omnican: warning: a correction above 20 %: check the measurements and the "
              "config's units", file=sys.stderr)


def write_config(path: str, cfg: ChassisConfig, c: Correction,
                 sim: SimTruth | None = None) -> None:
    """Write the corrected config: the source TOML edited in place, or (for the demo
    base, which has no file) a complete new one; with ``sim``, its [sim] table says so
    (the simulated base calibrated). Atomic: a temporary file, renamed."""
    out = Path(path)
    if sim is not None:
        cfg = replace(cfg, sim=sim)
    corrected = c.apply(cfg)
    if cfg.source is not None:
        try:
            text = Path(cfg.source).read_text(encoding="utf-8")
        except OSError as exc:
            raise ConfigError(f"cannot read {cfg.source}: {exc.strerror or exc}") from None
        new = calibration.edit_config_text(text, c)
        if sim is not None:
            new = calibration.set_sim_table(new, sim)
        src_dir = Path(cfg.source).resolve().parent
        if out.resolve().parent != src_dir and any(w.eds != WHEEL_EDS for w in cfg.wheels):
            print(f"omnican: warning: {out} is not next to {cfg.source}: relative eds paths "
                  "in it now resolve from its own directory", file=sys.stderr)
    else:
        new = calibration.render_config(
            corrected, "omnican config written by 'omnican calibrate' for the built-in demo "
            "base\n(three bundled drives, nodes 1-3), with the calibrated scales and radius.",
            c.digits)
    calibration.check_edited(new, corrected, str(out), rel_tol=10.0 ** (1 - c.digits))
    if sim is not None:
        calibration.check_sim(new, sim, str(out))
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{out.name}.", dir=out.parent)
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(new)
        os.replace(tmp, out)
    except OSError as exc:
        raise ConfigError(f"cannot write {out}: {exc.strerror or exc}") from None


def _print_fit(fit: FitResult, names: list[str]) -> None:
    print(f"fit of {len(names)} recording{'s' if len(names) > 1 else ''}: {fit.note} "
          f"({fit.iterations} Gauss-Newton iterations)")
    print("end poses, fitted - measured (before -> after the fit):")
    for name, before, after in zip(names, fit.residual_before, fit.residual_after, strict=True):
        print(f"  {name}: dx {before[0] * 1000:+.1f} -> {after[0] * 1000:+.1f} mm, "
              f"dy {before[1] * 1000:+.1f} -> {after[1] * 1000:+.1f} mm, "
              f"dtheta {math.degrees(before[2]):+.2f} -> {math.degrees(after[2]):+.2f} deg")


def _run_fit(args: argparse.Namespace) -> int:
    cfg = load(args)
    runs = []
    for path, pose in zip(args.fit, args.pose, strict=True):
        measured = parse_pose(pose)
        rep = replay.load(path, cfg)
        if rep.complete_syncs < 2:
            raise UsageError(f"{path}: no position samples of the --config base (recorded on "
                             "another base? give its --config)")
        runs.append(FitRun(rep.counts, measured, Path(path).name))
    try:
        result = calibration.fit(runs, cfg, args.model)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    # The end poses were measured by hand: the corrected numbers carry what a tape and a
    # floor mark resolve over the longest run and the largest turn.
    digits = calibration.measured_digits(
        max(math.hypot(r.measured[0], r.measured[1]) for r in runs),
        max(abs(r.measured[2]) for r in runs))
    result = replace(result, correction=result.correction.with_digits(digits))
    names = [r.name for r in runs]
    edits = _edits(cfg, result.correction)  # before --write may replace the --config file
    if args.write:
        write_config(args.write, cfg, result.correction)
    if args.json:
        print(json.dumps({
            "model": result.model,
            "wheel_factors": list(result.correction.wheel_factors),
            "radius_factor": result.correction.radius_factor,
            "wheels": _changes(cfg, result.correction),
            "base_radius": [cfg.chassis.base_radius, _radius(edits)],
            "residual_before": result.residual_before.tolist(),
            "residual_after": result.residual_after.tolist(),
            "recordings": names,
            "written": args.write,
        }))
        return EXIT_OK
    _print_fit(result, names)
    _print_correction(cfg, result.correction, edits)
    _print_written(args.write)
    return EXIT_OK


def _radius(edits: list[calibration.ConfigEdit]) -> float | None:
    return next((e.new for e in edits if e.wheel is None and e.key == "base_radius"), None)


def _print_written(path: str | None) -> None:
    if path:
        print(f"wrote the corrected config to {path}")
    else:
        print("nothing written: add --write OUT.toml to save the corrected config (OUT may "
              "be the --config file)")


def run(args: argparse.Namespace) -> int:
    _check_args(args)
    if args.fit:
        return _run_fit(args)
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
    edits = _edits(cfg, correction)  # before --write may replace the --config file
    if args.write:
        write_config(args.write, cfg, correction, m.sim)
    if args.json:
        print(json.dumps({
            "source": {"distance": m.distance_source, "angle": m.angle_source},
            "distance": {"odometry": m.distance_odometry, "measured": m.distance_measured},
            "angle_rad": {"odometry": m.angle_odometry, "measured": m.angle_measured},
            "scale_factor": correction.wheel_factors[0],
            "radius_factor": correction.radius_factor,
            "wheels": _changes(cfg, correction),
            "base_radius": [cfg.chassis.base_radius, _radius(edits)],
            "written": args.write,
        }))
        return EXIT_OK
    print(f"straight: odometry {m.distance_odometry:.4f} m, measured "
          f"{m.distance_measured:.4f} m ({m.distance_source})")
    print(f"spin:     odometry {math.degrees(m.angle_odometry):.2f} deg, measured "
          f"{math.degrees(m.angle_measured):.2f} deg ({m.angle_source})")
    _print_correction(cfg, correction, edits)
    if m.sim is not None:
        options = calibration.sim_options(cfg, m.sim)
        factors = [f"{f:.5f}" for f in options["true_scale"]]
        scale = (f"scale factor {factors[0]}" if len(set(factors)) == 1 else
                 "scale factors " + ", ".join(factors))
        radius = cfg.chassis.base_radius if m.sim.base_radius is None else m.sim.base_radius
        print(f"simulator truth: {scale}, base_radius {radius:.6g} m")
    _print_written(args.write)
    return EXIT_OK
