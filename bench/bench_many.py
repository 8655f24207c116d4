"""Many drives: 3, 6 and 12 wheels (one node each) at 1 kHz on the virtual bus, in one
run: achieved loop rate, late cycles, the loop thread's CPU per cycle, and the bus bits
each cycle needs against what a 1 Mbit/s bus carries in one period; beside an idle
sleeper thread at the same rate (this machine's timer floor).

The simulated drives run in this process (python-can's virtual bus is in-process), so
past a few drives their threads compete with the loop for the interpreter: the late
and rate figures then show the simulator's load as much as omnican's. The bus figure
does not depend on the machine: on a real 1 Mbit/s bus, a cycle whose worst-case bits
exceed the period's budget cannot hold, whatever the CPU.

Run: ``python bench/bench_many.py`` (about 30 s); ``--wheels 3,6,12``; ``--rate 500``;
``--seconds 5``. Prints one JSON object per line, then a table.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import threading
import time
from typing import Any

from bench_chassis import config, loop_thread, thread_cpu

from omnican import Chassis
from omnican.plan.node import heartbeat_bits_per_s, max_rate_hz
from omnican.sim import SimulatedBase

BITRATE = 1_000_000
LATE = 0.2  # of a period, as the loop counts late cycles


def sleeper(rate_hz: float, seconds: float) -> dict[str, Any]:
    """An idle thread waking at ``rate_hz``: its late fraction (the timer's tail)."""
    period = 1.0 / rate_hz
    late = n = 0

    def run() -> None:
        nonlocal late, n
        next_t = time.monotonic()
        end = next_t + seconds
        while next_t < end:
            now = time.monotonic()
            if now - next_t > period * LATE:
                late += 1
            n += 1
            next_t += period
            delay = next_t - time.monotonic()
            if delay > 0:
                time.sleep(delay)

    t = threading.Thread(target=run)
    t.start()
    t.join()
    return {"bench": "many.sleeper", "rate_hz": rate_hz, "late_fraction": round(late / n, 4)}


def run_base(wheels: int, rate_hz: float, seconds: float) -> dict[str, Any]:
    cfg = config(rate_hz, wheels)
    with SimulatedBase.from_config(cfg), Chassis.open(cfg) as base:
        thread = loop_thread(base)
        time.sleep(0.3)
        cycles0, late0, cpu0 = base.status.cycles, base._runner.late, thread_cpu(thread)
        t0 = time.monotonic()
        end = t0 + seconds
        while time.monotonic() < end:
            base.set_velocity(0.3 * math.sin(time.monotonic()), 0.1, 0.2)
            time.sleep(0.01)
        elapsed = time.monotonic() - t0
        cycles = base.status.cycles - cycles0
        late = base._runner.late - late0
        cpu = thread_cpu(thread) - cpu0
        bits = base.cycle_bits()
        status = base.status
    budget = BITRATE / rate_hz
    return {"bench": "many", "wheels": wheels, "rate_hz": rate_hz,
            "achieved_hz": round(cycles / elapsed, 1),
            "late_fraction": round(late / max(cycles, 1), 4),
            "loop_cpu_us_per_cycle": round(cpu / max(cycles, 1) * 1e6, 1),
            "bus_bits_per_cycle": bits, "bits_per_period_at_1Mbit": round(budget),
            "bus_fraction_at_1Mbit": round(bits / budget, 3),
            # What `omnican check-config` reports: the highest rate within 80 % of the bus.
            "max_rate_hz_at_1Mbit_80pct": math.floor(max_rate_hz(
                bits, heartbeat_bits_per_s(cfg), BITRATE, 0.8)),
            "measured_bus_bits_per_s": round(status.bus_bits_per_s)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--wheels", default="3,6,12", help="comma-separated wheel counts")
    parser.add_argument("--rate", type=float, default=1000.0, help="loop rate, Hz")
    parser.add_argument("--seconds", type=float, default=5.0, help="seconds per run")
    args = parser.parse_args()
    rows = [sleeper(args.rate, args.seconds)]
    print(json.dumps(rows[0]), flush=True)
    for n in (int(w) for w in args.wheels.split(",")):
        rows.append(run_base(n, args.rate, args.seconds))
        print(json.dumps(rows[-1]), flush=True)
    print()
    print(f"{'wheels':>6} {'Hz':>8} {'late':>7} {'CPU us/cycle':>13} {'bits/cycle':>11} "
          f"{'of 1 Mbit/s':>12} {'max Hz (80 %)':>14}")
    print(f"{'sleeper':>6} {args.rate:8.1f} {rows[0]['late_fraction']:7.2%}")
    for r in rows[1:]:
        print(f"{r['wheels']:>6} {r['achieved_hz']:8.1f} {r['late_fraction']:7.2%} "
              f"{r['loop_cpu_us_per_cycle']:13.1f} {r['bus_bits_per_cycle']:11d} "
              f"{r['bus_fraction_at_1Mbit']:12.0%} {r['max_rate_hz_at_1Mbit_80pct']:14d}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
