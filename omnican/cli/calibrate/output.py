"""What omnican calibrate prints of a correction and how --write writes it: the numbers
it changes (in the config file's own terms), the corrected config file."""

from __future__ import annotations

import os
import sys
import tempfile
from dataclasses import replace
from pathlib import Path
from typing import Any

from omnican.analysis import calibration
from omnican.analysis.calibration import Correction
from omnican.config import WHEEL_EDS, ChassisConfig, SimTruth
from omnican.errors import ConfigError


def _pct(factor: float) -> str:
    return f"{(factor - 1.0) * 100:+.2f} %"


def wheel_changes(cfg: ChassisConfig, c: Correction) -> list[dict[str, Any]]:
    """Per wheel, for --json: its factor and its scales, configured and corrected."""
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


def edits_of(cfg: ChassisConfig, c: Correction) -> list[calibration.ConfigEdit]:
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


def print_correction(cfg: ChassisConfig, c: Correction,
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


def new_radius(edits: list[calibration.ConfigEdit]) -> float | None:
    """The corrected base radius among ``edits`` (None: the config gives none to edit)."""
    return next((e.new for e in edits if e.wheel is None and e.key == "base_radius"), None)


def print_written(path: str | None) -> None:
    if path:
        print(f"wrote the corrected config to {path}")
    else:
        print("nothing written: add --write OUT.toml to save the corrected config (OUT may "
              "be the --config file)")
