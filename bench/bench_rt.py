"""The control loop on a busy machine: late cycles, its longest gap and the drives'
heartbeat-consumer trips beside CPU hogs, with and without real-time priority.

Issue 30 item 5: with other work on a 2-core robot computer the loop missed the host
heartbeat, every drive's consumer tripped (EMCY 8130h) and the base stopped. This runs,
beside ``--hogs`` child processes at normal priority (``while True: pass``, killed at
the end whatever happens, Ctrl-C included), for ``--duration`` seconds each:

* ``normal``: the loop at normal priority, the garbage collector as Python leaves it
  (the code before issue 30; ``chassis.rt_priority = 0`` and ``gc.unfreeze()``);
* ``frozen``: normal priority, start-up frozen out of the collector (``gc.freeze``);
* ``rt``: SCHED_FIFO at ``chassis.rt_priority`` (default 50) and frozen: the default.

Each runs the base in a process of its own (the one under test: its loop, the main
thread commanding a circle at 50 Hz, nothing else) against ``omnican sim`` in another,
over the simulator's loopback hub. The simulator stands for the drives, which the host's
load never reaches: its threads run SCHED_FIFO 60 where this process may (root,
CAP_SYS_NICE), so that its own lateness is not taken for the host's. Measured in the
host: late cycles (starting more than a fifth of a period late), the longest gap between
two cycle starts, gaps over 100 ms, every drive's EMCY 8130h (heartbeat consumer: the
host's heartbeat lost), the stops and their reasons (each recovered to go on), and the
garbage collector's collections and longest pause per generation (``gc.callbacks``).

Run: ``python bench/bench_rt.py`` (600 s per setting); ``--duration 60`` for a short
run; ``--settings rt,normal`` for some. Prints one JSON object per setting, then a table.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
SETTINGS = ("normal", "frozen", "rt")
SIM_PRIORITY = 60  # the simulated drives: above the host's loop, as hardware is
EMCY_HEARTBEAT = 0x8130

# A hog dies with the bench even when the bench is killed (PR_SET_PDEATHSIG = 1, SIGKILL).
HOG = ("import ctypes, signal\n"
       "try:\n    ctypes.CDLL(None).prctl(1, 9)\nexcept Exception:\n    pass\n"
       "signal.signal(signal.SIGINT, signal.SIG_DFL)\n"
       "while True:\n    pass\n")


def _env() -> dict[str, str]:
    path = os.environ.get("PYTHONPATH")
    return {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{path}" if path else str(ROOT)}


# ---------------------------------------------------------------- the host (one setting)


def run_host(args: argparse.Namespace) -> None:
    """The base under test, in this process: one setting for ``args.duration`` s."""
    import gc
    from dataclasses import replace

    from omnican import Chassis, default_config
    from omnican.chassis.runner import ThreadRunner
    from omnican.errors import DriveError

    pauses: dict[int, list[float]] = {0: [], 1: [], 2: []}
    started = [0.0]

    def on_gc(phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            started[0] = time.perf_counter()
        else:
            pauses[info["generation"]].append(time.perf_counter() - started[0])

    setting = args.host
    cfg = default_config(bus={"interface": "remote", "channel": args.url})
    cfg = replace(cfg, chassis=replace(cfg.chassis, rate_hz=float(args.rate),
                                       heartbeat_ms=args.heartbeat_ms,
                                       rt_priority=args.rt_priority if setting == "rt" else 0))
    stops: Counter[str] = Counter()
    emcy = [0]
    with Chassis.open(cfg) as base:
        runner = base._runner
        assert isinstance(runner, ThreadRunner)
        if setting == "normal":
            gc.unfreeze()  # the collector as it was before issue 30
        frozen = gc.get_freeze_count()

        def on_emcy(error: Any) -> None:
            if error.code == EMCY_HEARTBEAT:
                emcy[0] += 1

        for node in base.nodes:
            node.remote.emcy.add_callback(on_emcy)
        gaps: list[float] = []
        last = [-1.0]
        inner = runner.cycle

        def timed(now: float) -> None:
            if last[0] > 0:
                gaps.append(now - last[0])
            last[0] = now
            inner(now)

        runner.cycle = timed
        gc.callbacks.append(on_gc)
        count0 = gc.get_count()[0]
        late0, cpu0 = runner.late, runner.cpu_s
        t0 = time.monotonic()
        end = t0 + args.duration
        while time.monotonic() < end:
            reason = base.status.stopped_reason
            if reason is not None:
                stops[re.sub(r"[-+]?\d+(\.\d+)?", "#", reason)[:90]] += 1
                try:
                    base.recover()
                except DriveError:
                    time.sleep(0.5)
                continue
            base.set_velocity(0.2, 0.0, 0.5)
            time.sleep(0.02)
        elapsed = time.monotonic() - t0
        runner.cycle = inner
        gc.callbacks.remove(on_gc)
        late, cpu, trips = runner.late - late0, runner.cpu_s - cpu0, emcy[0]
        # Net container objects made over the run by every thread (while none was
        # collected: the collector's own count), then what a full collection of this heap
        # costs, the longest a gen-2 pause could be (after the figures above: it holds the
        # loop up meanwhile).
        allocated = gc.get_count()[0] - count0 if not pauses[0] else None
        walked, full, full_cpu = len(gc.get_objects()), [], []
        for _ in range(3):
            t, c = time.perf_counter(), time.thread_time()
            gc.collect()
            full.append(time.perf_counter() - t)
            full_cpu.append(time.thread_time() - c)
        realtime = runner.realtime
    period = 1.0 / args.rate
    gaps.sort()
    print(json.dumps({
        "setting": setting, "realtime": realtime, "frozen_objects": frozen,
        "seconds": round(elapsed, 1), "cycles": len(gaps) + 1, "late": late,
        "late_pct": round(100.0 * late / max(len(gaps), 1), 3),
        "max_gap_ms": round(1000 * gaps[-1], 1) if gaps else None,
        "p999_gap_ms": round(1000 * gaps[int(0.999 * (len(gaps) - 1))], 2) if gaps else None,
        "gaps_over_2_periods": sum(g > 2 * period for g in gaps),
        "gaps_over_100ms": sum(g > 0.1 for g in gaps),
        "emcy_8130": trips, "stops": sum(stops.values()), "reasons": dict(stops),
        "loop_cpu_us_per_cycle": round(1e6 * cpu / max(len(gaps), 1), 1),
        "gc_collections": [len(pauses[g]) for g in (0, 1, 2)],
        "gc_max_pause_ms": [round(1000 * max(pauses[g], default=0.0), 3) for g in (0, 1, 2)],
        "gc_total_pause_ms": round(1000 * sum(sum(p) for p in pauses.values()), 1),
        "gc_net_allocations": allocated,
        "gc_full_collection_ms": [round(1000 * min(full), 2), round(1000 * max(full), 2)],
        "gc_full_collection_cpu_ms": round(1000 * min(full_cpu), 2),
        "gc_tracked_objects": walked,
        "load": [round(x, 1) for x in os.getloadavg()],
    }), flush=True)


# ---------------------------------------------------------------- the bench


def boost(pid: int, priority: int) -> bool:
    """Every thread of process ``pid`` SCHED_FIFO at ``priority`` (the threads they start
    inherit it); False if not permitted."""
    try:
        for name in os.listdir(f"/proc/{pid}/task"):
            os.sched_setscheduler(int(name), os.SCHED_FIFO, os.sched_param(priority))
    except PermissionError:
        return False
    return True


class Sim:
    """``omnican sim`` on a loopback hub, in a process of its own."""

    def __init__(self) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "omnican", "sim", "--serve", "127.0.0.1:0"],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
            text=True, env=_env())
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        match = re.search(r"(ws://\S+)", line)
        if not match:
            self.close()
            raise SystemExit(f"bench_rt: omnican sim did not start: {line!r}")
        self.url = match[1]
        self.boosted = boost(self.proc.pid, SIM_PRIORITY)

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.communicate(timeout=10)


def run_setting(setting: str, args: argparse.Namespace) -> dict[str, Any]:
    sim = Sim()
    try:
        cmd = [sys.executable, str(Path(__file__).resolve()), "--host", setting,
               "--url", sim.url, "--duration", str(args.duration), "--rate", str(args.rate),
               "--heartbeat-ms", str(args.heartbeat_ms), "--rt-priority", str(args.rt_priority)]
        host = subprocess.run(cmd, capture_output=True, text=True, env=_env(), check=False,
                              timeout=args.duration + 120)
        lines = [s for s in host.stdout.splitlines() if s.startswith("{")]
        if host.returncode != 0 or not lines:
            tail = " | ".join(host.stderr.strip().splitlines()[-3:])
            raise SystemExit(f"bench_rt: the {setting} host failed ({host.returncode}): {tail}")
        result: dict[str, Any] = json.loads(lines[-1])
        result["sim_fifo"] = sim.boosted
        return result
    finally:
        sim.close()


def table(results: list[dict[str, Any]], args: argparse.Namespace) -> str:
    def row(label: str, fn: Any) -> str:
        return f"| {label} | " + " | ".join(str(fn(r)) for r in results) + " |"

    head = "| | " + " | ".join(r["setting"] for r in results) + " |"
    rows = [
        head, "|---" * (len(results) + 1) + "|",
        row("loop priority", lambda r: f"SCHED_FIFO {args.rt_priority}" if r["realtime"]
            else "normal"),
        row("start-up frozen (objects)", lambda r: f"{r['frozen_objects']:,}"),
        row("cycles", lambda r: f"{r['cycles']:,}"),
        row("late cycles (> 1/5 period)", lambda r: f"{r['late']} ({r['late_pct']} %)"),
        row("longest gap", lambda r: f"{r['max_gap_ms']} ms"),
        row("gap p99.9", lambda r: f"{r['p999_gap_ms']} ms"),
        row("gaps > 2 periods / > 100 ms", lambda r: f"{r['gaps_over_2_periods']} / "
            f"{r['gaps_over_100ms']}"),
        row("EMCY 8130h (host heartbeat lost)", lambda r: r["emcy_8130"]),
        row("stops", lambda r: r["stops"]),
        row("loop CPU per cycle", lambda r: f"{r['loop_cpu_us_per_cycle']} us"),
        row("GC collections gen 0/1/2", lambda r: "/".join(map(str, r["gc_collections"]))),
        row("longest GC pause gen 0/1/2", lambda r: "/".join(map(str, r["gc_max_pause_ms"]))
            + " ms"),
        row("net container allocations (run)", lambda r: r["gc_net_allocations"]),
        row("a full collection (gc.collect: wall min-max of 3; CPU)", lambda r: "-".join(
            map(str, r["gc_full_collection_ms"])) + f" ms; {r['gc_full_collection_cpu_ms']} ms "
            f"({r['gc_tracked_objects']:,} objects)"),
        row("load average at the end", lambda r: r["load"][0]),
    ]
    return "\n".join(rows)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--duration", type=float, default=600.0, help="seconds per setting")
    p.add_argument("--hogs", type=int, default=4, help="CPU hogs at normal priority")
    p.add_argument("--rate", type=float, default=100.0, help="control loop rate, Hz")
    p.add_argument("--heartbeat-ms", type=int, default=100, help="chassis.heartbeat_ms")
    p.add_argument("--rt-priority", type=int, default=50, help="chassis.rt_priority for rt")
    p.add_argument("--settings", default=",".join(SETTINGS),
                   help=f"which, in order (of {', '.join(SETTINGS)})")
    p.add_argument("--host", choices=SETTINGS, help=argparse.SUPPRESS)
    p.add_argument("--url", help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.host:
        run_host(args)
        return
    settings = [s.strip() for s in args.settings.split(",") if s.strip()]
    for s in settings:
        if s not in SETTINGS:
            p.error(f"unknown setting {s!r} (of {', '.join(SETTINGS)})")

    def terminate(signum: int, frame: Any) -> None:
        raise SystemExit(128 + signum)

    signal.signal(signal.SIGTERM, terminate)  # the hogs' finally runs on SIGTERM too
    hogs: list[subprocess.Popen[bytes]] = []
    results = []
    try:
        for _ in range(args.hogs):
            hogs.append(subprocess.Popen([sys.executable, "-c", HOG],
                                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        for s in settings:
            result = run_setting(s, args)
            print(json.dumps(result), flush=True)
            results.append(result)
    finally:
        for hog in hogs:
            hog.kill()
        for hog in hogs:
            hog.wait()
    print(f"\n{args.hogs} CPU hogs, {os.cpu_count()} CPUs, {args.rate:g} Hz, heartbeat "
          f"{args.heartbeat_ms} ms, {args.duration:g} s per setting; the simulated drives "
          f"{'SCHED_FIFO ' + str(SIM_PRIORITY) if all(r['sim_fifo'] for r in results) else 'at normal priority (not permitted)'}\n")
    print(table(results, args))


if __name__ == "__main__":
    main()
