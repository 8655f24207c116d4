"""The benchmarks page's summary, measured in one run: instructions per control cycle
(omnican, the minimal hand-written loop, plain canopen; bench_instructions), SYNC jitter
on SocketCAN (loop-timed and kernel-timed, idle and beside two CPU hogs, at 100 Hz and
1 kHz; bench_sync_jitter in the vcan guest) and ``drive --sim --fast``'s real-time
factor (bench_fast), one after the other on the same machine, then the three tables.

The SYNC rows need the vcan guest (``tools/vcan-vm/run-in-vcan-vm``: QEMU; an emulated
CPU about 14x slower than the host's). Where it cannot run, the table says why and the
other figures are still measured.

Run: ``python bench/bench_summary.py`` (about 15 minutes); ``--quick`` (300 counted
cycles, 3 fast runs, 4 s per SYNC run: about 6 minutes); ``--no-guest``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
VM = ROOT / "tools" / "vcan-vm" / "run-in-vcan-vm"


def _rows(cmd: list[str], timeout_s: float) -> tuple[list[dict[str, Any]], str | None]:
    """Run a benchmark; its JSON lines (echoed as they come) and None, or why it failed."""
    print(f"# {' '.join(cmd)}", file=sys.stderr, flush=True)
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s,
                              cwd=ROOT, check=False)
    except subprocess.TimeoutExpired:
        return [], f"did not finish within {timeout_s:g} s"
    rows = []
    for line in done.stdout.splitlines():
        if line.startswith("{"):
            print(line, flush=True)
            rows.append(json.loads(line))
    if done.returncode != 0:
        tail = (done.stderr.strip().splitlines() or ["no output"])[-1]
        return rows, f"exit {done.returncode}: {tail}"
    return rows, None


def _instructions(cycles: int) -> tuple[list[dict[str, Any]], str | None]:
    return _rows([sys.executable, str(HERE / "bench_instructions.py"), "--rates", "100,1000",
                  "--cycles", str(cycles)], 3600)


def _fast(runs: int) -> tuple[list[dict[str, Any]], str | None]:
    return _rows([sys.executable, str(HERE / "bench_fast.py"), "--runs", str(runs)], 600)


def _jitter(seconds: float) -> tuple[list[dict[str, Any]], str | None]:
    if not VM.exists():
        return [], f"{VM} is missing"
    fast = max(seconds / 2, 2.0)
    return _rows([str(VM), "--timeout", "1800", "-q", "--", sys.executable,
                  str(HERE / "bench_sync_jitter.py"), "--schemes",
                  "omnican_loop,omnican_kernel", "--rates", "100,1000", "--hogs", "0,2",
                  "--seconds", f"{seconds:g}", "--fast-seconds", f"{fast:g}"], 2400)


def _table_instructions(rows: list[dict[str, Any]], why: str | None) -> None:
    print("\n| instructions per cycle (3 wheels, lock-step) | 100 Hz | 1 kHz |")
    print("|---|---|---|")
    ratio = {r["rate_hz"]: r for r in rows if r.get("bench") == "host_instructions.ratio"
             and r.get("wheels") == 3}
    if not ratio:
        print(f"| not measured: {why} | | |")
        return
    lo, hi = ratio.get(100.0, {}), ratio.get(1000.0, {})
    for key, name in (("omnican", "omnican `Chassis`"), ("minimal", "minimal loop"),
                      ("canopen", "plain canopen")):
        print(f"| {name} | {lo.get(key, 0):,} | {hi.get(key, 0):,} |")
    for key, name in (("omnican_per_minimal", "omnican / minimal"),
                      ("omnican_per_canopen", "omnican / plain canopen")):
        print(f"| {name} | {lo.get(key, '')} | {hi.get(key, '')} |")


def _table_jitter(rows: list[dict[str, Any]], why: str | None) -> None:
    print("\n| SYNC (vcan guest) | rate | hogs | \\|period dev\\| p50 / p99 / max ms | "
          "late RPDOs |")
    print("|---|---|---|---|---|")
    if not rows:
        print(f"| not measured: {why} | | | | |")
        return
    for r in rows:
        who = {"omnican_loop": "loop-timed", "omnican_kernel": "kernel-timed"}.get(
            r.get("scheme", ""), r.get("scheme", "?"))
        print(f"| {who} | {r['rate_hz']:g} Hz | {r['hogs']} | {r['abs_dev_p50_ms']:.2f} / "
              f"{r['abs_dev_p99_ms']:.2f} / {r['abs_dev_max_ms']:.2f} | "
              f"{r.get('late', '?')} of {r.get('cycles', '?')} |")
    if why:
        print(f"| (stopped: {why}) | | | | |")


def _table_fast(rows: list[dict[str, Any]], why: str | None) -> None:
    print("\n| `drive --sim --fast --square 4` | wall | CPU |")
    print("|---|---|---|")
    med = next((r for r in rows if r.get("bench") == "fast"), None)
    if med is None:
        print(f"| not measured: {why} | | |")
        return
    print(f"| whole command (x real time) | {med['factor_whole_command']} | "
          f"{med['factor_whole_command_cpu']} |")
    print(f"| the drive alone (x real time) | {med['factor_drive']} | "
          f"{med['factor_drive_cpu']} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--no-guest", action="store_true", help="leave the SYNC rows out")
    args = parser.parse_args()
    instr = _instructions(300 if args.quick else 1000)
    fast = _fast(3 if args.quick else 5)
    jitter = ([], "--no-guest") if args.no_guest else _jitter(4.0 if args.quick else 10.0)
    _table_instructions(*instr)
    _table_jitter(*jitter)
    _table_fast(*fast)


if __name__ == "__main__":
    main()
