"""omnican calibrate --fit: per-wheel scales and the base radius fitted to recordings and
the measured end pose of each (no bus)."""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import replace
from pathlib import Path

from omnican.analysis import calibration
from omnican.analysis.calibration import FitResult, FitRun
from omnican.cli.calibrate.output import (
    edits_of,
    new_radius,
    print_correction,
    print_written,
    wheel_changes,
    write_config,
)
from omnican.cli.common import EXIT_OK, UsageError
from omnican.cli.session import load
from omnican.record import replay


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


def _print_fit(fit: FitResult, names: list[str]) -> None:
    print(f"fit of {len(names)} recording{'s' if len(names) > 1 else ''}: {fit.note} "
          f"({fit.iterations} Gauss-Newton iterations)")
    print("end poses, fitted - measured (before -> after the fit):")
    for name, before, after in zip(names, fit.residual_before, fit.residual_after, strict=True):
        print(f"  {name}: dx {before[0] * 1000:+.1f} -> {after[0] * 1000:+.1f} mm, "
              f"dy {before[1] * 1000:+.1f} -> {after[1] * 1000:+.1f} mm, "
              f"dtheta {math.degrees(before[2]):+.2f} -> {math.degrees(after[2]):+.2f} deg")


def run_fit(args: argparse.Namespace) -> int:
    """The fit, its correction printed (and written with --write)."""
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
    edits = edits_of(cfg, result.correction)  # before --write may replace the --config file
    if args.write:
        write_config(args.write, cfg, result.correction)
    if args.json:
        print(json.dumps({
            "model": result.model,
            "wheel_factors": list(result.correction.wheel_factors),
            "radius_factor": result.correction.radius_factor,
            "wheels": wheel_changes(cfg, result.correction),
            "base_radius": [cfg.chassis.base_radius, new_radius(edits)],
            "residual_before": result.residual_before.tolist(),
            "residual_after": result.residual_after.tolist(),
            "recordings": names,
            "written": args.write,
        }))
        return EXIT_OK
    _print_fit(result, names)
    print_correction(cfg, result.correction, edits)
    print_written(args.write)
    return EXIT_OK
