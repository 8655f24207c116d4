"""Every command tells the truth: what it prints is what it did (issue 11).

Each test drives the command through ``omnican.cli.main`` (or a subprocess) as a
user would, and reads its output."""

from __future__ import annotations

import contextlib
import io
import json
import math
import re
import sys
from pathlib import Path

import pytest

from omnican.cli import main

from .helpers import one_error_line

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "robot.toml"


def run_main(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(argv)
        except SystemExit as exc:  # argparse errors
            code = int(exc.code or 0)
    return code, out.getvalue(), err.getvalue()


# ---------------------------------------------------------------- 1: calibrate --write

PHYSICAL = """\
[chassis]
layout = "b21"
base_radius = 0.19
max_accel = 3.0
max_angular_accel = 12.0

[[wheel]]
node_id = 1
gear_ratio = 16
encoder_cpr = 4096
wheel_radius = 0.05     # m

[[wheel]]
node_id = 2
velocity_scale = 208607.6
position_scale = 208607.6

[[wheel]]
node_id = 3
velocity_scale = 208607.6
position_scale = 208607.6
"""


def test_calibrate_prints_what_it_writes_in_the_configs_own_terms(tmp_path: Path) -> None:
    cfg = tmp_path / "robot.toml"
    cfg.write_text(PHYSICAL)
    out_toml = tmp_path / "out.toml"
    code, out, err = run_main(["calibrate", "--sim", "--config", str(cfg), "--distance", "0.2",
                               "--turns", "0.25", "--speed", "0.5", "--omega", "3",
                               "--write", str(out_toml)])
    assert code == 0, err
    written = out_toml.read_text()
    # Every "key old -> new" the command prints is a line it wrote, and every number it
    # changed is printed.
    printed = re.findall(r"(\w+) (\S+) -> ([0-9.]+)", out)
    assert printed, out
    changed = [(a.split("=")[0].strip(), a.split("=")[1].split()[0],
                b.split("=")[1].split()[0])
               for a, b in zip(PHYSICAL.splitlines(), written.splitlines(), strict=True)
               if a != b]
    assert sorted((k, float(o), float(n)) for k, o, n in printed) == \
        sorted((k, float(o), float(n)) for k, o, n in changed)
    wheel0 = next(line for line in out.splitlines() if "wheel 0 (node 1)" in line)
    assert "wheel_radius 0.05 -> " in wheel0 and "velocity_scale" not in wheel0


# ---------------------------------------------------------------- 2: a missing extra


@pytest.mark.parametrize("argv", [
    ["plot", "run.log", "-o", "out.png"],
    ["plot", "--help"],
    ["plot"],
    ["-v", "plot", "--sim", "-o", "demo.png"],
])
def test_a_command_whose_extra_is_missing_says_which_to_install(
        argv: list[str], monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib now fails
    monkeypatch.delitem(sys.modules, "omnican.cli.plot", raising=False)
    code, out, err = run_main(argv)
    assert code == 2
    line = one_error_line(err)
    assert "'plot' needs matplotlib" in line and "pip install 'omnican[plot]'" in line
    assert "unrecognized arguments" not in line


def test_the_command_list_marks_the_unavailable_command(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    monkeypatch.delitem(sys.modules, "omnican.cli.plot", raising=False)
    code, out, _ = run_main(["--help"])
    assert code == 0
    assert re.search(r"plot\s+\(unavailable: needs matplotlib: pip install 'omnican\[plot\]'\)",
                     out), out
