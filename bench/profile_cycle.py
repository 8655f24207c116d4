"""Where a lock-step control cycle's time goes, per Python function: cProfile over the
host side only (the simulated drives' own work is switched out, as in
bench_instructions), or over the simulated drives only (``--side sim``), or over both
(``--side all``: a ``drive --sim --fast`` run's own split).

Run: ``python bench/profile_cycle.py`` (100 Hz, 2000 cycles, top 25 by own time);
``--rate 1000``; ``--side sim``; ``--top 40``. Prints a table (function, calls per cycle,
own microseconds per cycle, share) and, first, one JSON line of totals. cProfile's own
overhead inflates small functions: rank by it, measure by bench_instructions.
"""

from __future__ import annotations

import argparse
import cProfile
import json
import math
import pstats
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rate", type=float, default=100.0)
    parser.add_argument("--cycles", type=int, default=2000)
    parser.add_argument("--side", choices=("host", "sim", "all"), default="host")
    parser.add_argument("--top", type=int, default=25)
    args = parser.parse_args()

    from bench_chassis import config

    from omnican import Chassis
    from omnican.clock import SimClock
    from omnican.sim import SimulatedBase

    cfg = config(args.rate, 3)
    clock = SimClock()
    prof = cProfile.Profile(time.process_time)  # CPU time: a loaded machine moves it least
    owners: list[str] = []
    side = args.side

    def counted(owner: str) -> bool:
        return side in ("all", owner)

    def wrap(owner: str, fn: Any) -> Any:
        def run(*a: Any, **k: Any) -> Any:
            before = bool(owners) and counted(owners[-1])
            owners.append(owner)
            if counted(owner) != before:
                (prof.enable if counted(owner) else prof.disable)()
            try:
                return fn(*a, **k)
            finally:
                owners.pop()
                after = bool(owners) and counted(owners[-1])
                if after != counted(owner):
                    (prof.enable if after else prof.disable)()
        return run

    with SimulatedBase.from_config(cfg, clock=clock) as sim, \
            Chassis.open(cfg, clock=clock) as base:
        clock.sleep(0.3)
        host_bus = base.bus.network.bus
        host_bus.set_receiver(wrap("host", host_bus._receiver))  # type: ignore[union-attr]
        base._runner.cycle = wrap("host", base._runner.cycle)
        sim_bus = sim.network.bus
        sim_bus.set_receiver(wrap("sim", sim_bus._receiver))
        ticks = sim.scheduler._ticks
        ticks[:] = [wrap("sim", tick) for tick in ticks]
        c0 = base.status.cycles
        for k in range(max(args.cycles // 10, 1)):
            base.set_velocity(0.3 * math.sin(k * 0.01), 0.1, 0.2)
            clock.sleep(10 / args.rate)
        n = base.status.cycles - c0
    stats = pstats.Stats(prof)
    rows = []
    total = 0.0
    for (file, line, name), (_cc, nc, tt, _ct, _callers) in stats.stats.items():  # type: ignore[attr-defined]
        total += tt
        short = file.split("/omnican/")[-1] if "/omnican/" in file else Path(file).name
        rows.append((tt, nc, f"{short}:{line}({name})"))
    rows.sort(reverse=True)
    print(json.dumps({"bench": "profile_cycle", "side": side, "rate_hz": args.rate,
                      "cycles": n, "us_per_cycle": round(total / n * 1e6, 1)}))
    print(f"{'own us/cycle':>12} {'share':>6} {'calls/cycle':>11}  function")
    for tt, nc, name in rows[:args.top]:
        print(f"{tt / n * 1e6:12.2f} {tt / total:6.1%} {nc / n:11.2f}  {name}")


if __name__ == "__main__":
    main()
