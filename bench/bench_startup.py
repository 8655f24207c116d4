"""How soon omnican is up: ``omnican --help``, ``--version``, and ``omnican drive --sim``
to "every drive enabled" and to its exit, as a user starts them (a new process each
time), beside the floor: a bare ``python -c pass`` on this machine.

"Every drive enabled" is when the ``-v`` log line saying so reaches the pipe, timed
from just before the process is spawned. The import figures come from
``python -X importtime`` for the same drive command: modules imported and their total
(self) import time, and the slowest few.

Run: ``python bench/bench_startup.py`` (about 20 s); ``--runs 20``. Prints one JSON
object per line, then a table.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import time
from typing import Any

DRIVE = ["drive", "--sim", "--vx", "0.1", "--duration", "0.1", "--json"]
ENABLED = b"every drive enabled"


def omnican(*args: str) -> list[str]:
    return [sys.executable, "-m", "omnican", *args]


def time_exit(argv: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
    return time.perf_counter() - t0


def time_drive() -> tuple[float, float]:
    """(seconds to the "every drive enabled" line, seconds to exit) of one drive run."""
    t0 = time.perf_counter()
    with subprocess.Popen(omnican("-v", *DRIVE), stdout=subprocess.DEVNULL,
                          stderr=subprocess.PIPE) as proc:
        assert proc.stderr is not None
        enabled = None
        for line in proc.stderr:
            if enabled is None and ENABLED in line:
                enabled = time.perf_counter() - t0
        rc = proc.wait()
    done = time.perf_counter() - t0
    if rc != 0 or enabled is None:
        raise SystemExit(f"omnican drive --sim failed (exit {rc})")
    return enabled, done


def import_profile(argv: list[str], top: int = 8) -> dict[str, Any]:
    """Modules imported by ``argv`` under -X importtime, their total self time and the
    slowest ``top`` (cumulative, top-level packages)."""
    done = subprocess.run([sys.executable, "-X", "importtime", *argv[1:]],
                          capture_output=True, text=True, check=False)
    rows = []
    for line in done.stderr.splitlines():
        m = re.match(r"import time:\s+(\d+) \|\s+(\d+) \|( *)(\S+)", line)
        if m:
            rows.append((int(m.group(1)), int(m.group(2)), len(m.group(3)), m.group(4)))
    roots = sorted((r for r in rows if r[2] == 1), key=lambda r: -r[1])[:top]
    return {"modules": len(rows), "self_ms_total": round(sum(r[0] for r in rows) / 1000, 1),
            "slowest_ms": {r[3]: round(r[1] / 1000, 1) for r in roots}}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=10, help="runs of each command (median)")
    args = parser.parse_args()
    env_note = {"python": sys.version.split()[0], "cpus": os.cpu_count()}
    results: list[dict[str, Any]] = []
    floor = statistics.median(time_exit([sys.executable, "-c", "pass"])
                              for _ in range(args.runs))
    results.append({"bench": "startup", "what": "python -c pass (floor)", "s": round(floor, 3)})
    for what in (["--help"], ["--version"]):
        s = statistics.median(time_exit(omnican(*what)) for _ in range(args.runs))
        results.append({"bench": "startup", "what": "omnican " + what[0], "s": round(s, 3)})
    runs = [time_drive() for _ in range(args.runs)]
    results.append({"bench": "startup", "what": "drive --sim: every drive enabled",
                    "s": round(statistics.median(r[0] for r in runs), 3),
                    "max_s": round(max(r[0] for r in runs), 3)})
    results.append({"bench": "startup", "what": "drive --sim: exit",
                    "s": round(statistics.median(r[1] for r in runs), 3),
                    "max_s": round(max(r[1] for r in runs), 3)})
    profile = import_profile(omnican(*DRIVE))
    results.append({"bench": "startup.imports", "what": "drive --sim", **profile})
    for r in results:
        print(json.dumps({**r, **env_note}))
    print()
    print(f"{'what':38} {'median s':>9}")
    for r in results:
        if "s" in r:
            print(f"{r['what']:38} {r['s']:9.3f}")
    print(f"imports of drive --sim: {profile['modules']} modules, "
          f"{profile['self_ms_total']} ms of their own; slowest: "
          + ", ".join(f"{k} {v} ms" for k, v in profile["slowest_ms"].items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
