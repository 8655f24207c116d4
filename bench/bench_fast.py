"""How many times real time ``omnican drive --sim --fast`` runs: the simulated seconds of
a ``--square`` over the wall seconds it took, for the whole command as a user runs it
(start-up, opening the simulated base, the drive, closing: one new process each run)
and for the drive alone (``omnican.command.motion.run``, timed in the same process).
Wall seconds move with the machine's load; CPU seconds (the process's own, user and
system) much less: both are printed. Each run's JSON must be the one of the first run (lock-step is deterministic): a run
that differs says so.

Run: ``python bench/bench_fast.py`` (``--square 4``, 5 runs, 100 Hz: about 10 s);
``--rate 1000``; ``--runs 9``. Prints one JSON object per run, then the medians.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

# The command, with omnican.command.motion.run timed (its wall and CPU seconds on
# stderr). main() runs as the ``omnican`` script runs it (no argv: the process's own
# command), and the timer goes in once main() runs, as the command imports motion: what
# main() does before anything is imported holds as it does for a user.
_TIMED = r"""
import sys, time
import omnican.cli as cli
inner_main = cli._main
def hooked_main(words, **kw):
    from omnican.command import motion
    inner = motion.run
    def timed(*a, **k):
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            return inner(*a, **k)
        finally:
            print(f"MOTION_RUN_S {time.perf_counter() - t0:.6f} "
                  f"{time.process_time() - c0:.6f}", file=sys.stderr)
    motion.run = timed
    return inner_main(words, **kw)
cli._main = hooked_main
sys.exit(cli.main())
"""


def _config(rate_hz: float, where: Path) -> list[str]:
    """``--config`` for a rate other than the demo's (100 Hz: none): the example robot's
    config at ``rate_hz``."""
    if rate_hz == 100.0:
        return []
    example = Path(__file__).resolve().parents[1] / "examples" / "robot.toml"
    lines = [f"rate_hz = {rate_hz:g}" if line.split("=")[0].strip() == "rate_hz" else line
             for line in example.read_text().splitlines()]
    path = where / "fast.toml"
    path.write_text("\n".join(lines) + "\n")
    return ["--config", str(path)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--square", type=float, default=4.0)
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--rate", type=float, default=100.0)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        extra = _config(args.rate, Path(tmp))
        cmd = ["drive", *extra, "--sim", "--fast", "--square", f"{args.square:g}", "--json"]
        # As an installed omnican runs: from compiled bytecode. A first run (not counted)
        # compiles it into a cache of this run's own (PYTHONDONTWRITEBYTECODE would make
        # every run compile every module again: a third of a second here).
        env = dict(os.environ, PYTHONPYCACHEPREFIX=str(Path(tmp) / "pycache"))
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        subprocess.run([sys.executable, "-c", _TIMED, *cmd], check=False, capture_output=True,
                       env=env)
        first: str | None = None
        whole: list[float] = []
        drive: list[float] = []
        whole_cpu: list[float] = []  # CPU seconds: what a loaded machine moves least
        drive_cpu: list[float] = []
        simulated = 0.0
        for i in range(args.runs):
            t0 = time.perf_counter()
            r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
            done = subprocess.run([sys.executable, "-c", _TIMED, *cmd], check=False,
                                  capture_output=True, text=True, env=env)
            wall = time.perf_counter() - t0
            r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu = (r1.ru_utime + r1.ru_stime) - (r0.ru_utime + r0.ru_stime)
            if done.returncode != 0:
                raise SystemExit(f"bench_fast: omnican {' '.join(cmd)} failed: "
                                 f"{done.stderr.strip()[-500:]}")
            out = done.stdout.strip()
            first = out if first is None else first
            simulated = float(json.loads(out)["duration_s"])
            run_s, run_cpu = next((float(line.split()[1]), float(line.split()[2]))
                                  for line in done.stderr.splitlines()
                                  if line.startswith("MOTION_RUN_S"))
            whole.append(wall)
            drive.append(run_s)
            whole_cpu.append(cpu)
            drive_cpu.append(run_cpu)
            print(json.dumps({"bench": "fast.run", "run": i, "rate_hz": args.rate,
                              "simulated_s": simulated, "wall_s": round(wall, 3),
                              "drive_wall_s": round(run_s, 3), "cpu_s": round(cpu, 3),
                              "drive_cpu_s": round(run_cpu, 3),
                              "same_json": out == first}), flush=True)
        w, d = statistics.median(whole), statistics.median(drive)
        wc, dc = statistics.median(whole_cpu), statistics.median(drive_cpu)
        print(json.dumps({"bench": "fast", "rate_hz": args.rate, "square_m": args.square,
                          "simulated_s": simulated, "wall_s": round(w, 3),
                          "factor_whole_command": round(simulated / w, 1),
                          "drive_wall_s": round(d, 3),
                          "factor_drive": round(simulated / d, 1),
                          "cpu_s": round(wc, 3), "factor_whole_command_cpu": round(simulated / wc, 1),
                          "drive_cpu_s": round(dc, 3),
                          "factor_drive_cpu": round(simulated / dc, 1)}), flush=True)


if __name__ == "__main__":
    main()
