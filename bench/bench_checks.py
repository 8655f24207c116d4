"""What each safety check costs a control cycle, in instructions: bench_instructions'
lock-step run (100 Hz, three wheels, the host side counted by callgrind) once with
everything, then once per check with that check replaced by a stand-in that does
nothing (put in after the base is up and enabled, so start-up is the same), each in a
process of its own. A check's cost is the difference: repeatable (to a few hundred at 100 Hz), unlike
bench_attribute's stretches of one run, whose states differ by more than most parts
cost. Beside them the minimal loop (the floor, bench_cycle's), and what the floor plus
every check comes to: the least a cycle that keeps every check could cost were
everything else free.

A stand-in changes nothing else in these runs: the base drives the same commands, no
check would have fired, and what a check would have latched never comes.

Run: ``python bench/bench_checks.py`` (nine runs under valgrind, a few minutes);
``--rate 1000``; ``--cycles 1000``. Prints one JSON object per run, then the table.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_instructions import build_toggle, measure


def _nothing(*_a: Any, **_k: Any) -> None:
    return None


def _knock_chassis_checks(base: Any) -> None:
    from omnican.chassis.checks import ChassisChecks

    def check(self: Any, now: float, sup: Any) -> None:
        self.next_at = math.inf  # never due again

    ChassisChecks.check = check  # type: ignore[method-assign]


def _knock_supervisor(base: Any) -> None:
    from omnican.chassis.supervisor import NodeSupervisor

    NodeSupervisor.check = _nothing  # type: ignore[method-assign]


def _knock_tracking(base: Any) -> None:
    from omnican.chassis.checks import ChassisChecks

    ChassisChecks._check_tracking = _nothing  # type: ignore[method-assign]


def _knock_values(base: Any) -> None:
    from omnican.chassis.checks import ChassisChecks

    ChassisChecks._refresh = _nothing  # type: ignore[method-assign]


def _knock_node_watch(base: Any) -> None:
    # The supervisor's look at each node (reboot, NMT, SDO aborts, heartbeat, faults):
    # its check with only the chassis checks left in it.
    from omnican.chassis.supervisor import NodeSupervisor

    def check(self: Any, now: float, all_enabled: bool = False) -> None:
        if now >= self.checks.next_at:
            self.checks.check(now, self)

    NodeSupervisor.check = check  # type: ignore[method-assign]


def _knock_bus_watch(base: Any) -> None:
    from omnican.io.bus_watch import BusWatch

    BusWatch.check = _nothing  # type: ignore[method-assign]


def _knock_pose(base: Any) -> None:
    # Odometry.step less the pose: it still hands the speed window a step (of zero).
    from omnican.core.odometry import Odometry

    zero = (0.0, 0.0, 0.0)

    def step(self: Any, travel: list[float], dt_s: float | None = None) -> Any:
        last, self._last = self._last, travel
        return None if last is None else zero

    Odometry.step = step  # type: ignore[method-assign]


def _knock_snapshot(base: Any) -> None:
    loop = base._loop
    kept = loop.snapshot
    loop._make_snapshot = lambda now, command=(0.0, 0.0, 0.0): kept


# name -> (what is left out, how). The checks first, then what is not a check.
KNOCKOUTS: dict[str, tuple[str, Callable[[Any], None]]] = {
    "chassis_checks": ("chassis checks: tracking, standstill, lift, e-stop, battery, CAN "
                       "controller, health values (10 Hz and 5 Hz)", _knock_chassis_checks),
    "tracking": ("of which tracking, standstill and following error (10 Hz)", _knock_tracking),
    "values": ("of which the health values, lift, e-stop and battery (5 Hz)", _knock_values),
    "node_watch": ("the supervisor's look at each node: reboot, NMT state, SDO aborts, "
                   "heartbeat lost, faults", _knock_node_watch),
    "supervisor": ("both of the above (NodeSupervisor.check)", _knock_supervisor),
    "bus_watch": ("the bus watch (down / back)", _knock_bus_watch),
    "pose": ("the pose (Odometry.step's SE(2) composition)", _knock_pose),
    "snapshot": ("the snapshot every thread reads (_make_snapshot)", _knock_snapshot),
}
CHECKS = ("supervisor", "bus_watch")  # summed: every check the cycle makes


def _run(rate: float, cycles: int, tmp: Path, knockout: str) -> int:
    """bench_instructions' count of omnican's cycle with ``knockout`` applied ("none":
    everything)."""
    os.environ["OMNICAN_KNOCKOUT"] = "" if knockout == "none" else knockout
    try:
        return int(measure(rate, cycles, tmp, tmp, "omnican")["instructions_per_cycle"])
    finally:
        os.environ.pop("OMNICAN_KNOCKOUT", None)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rate", type=float, default=100.0)
    parser.add_argument("--cycles", type=int, default=300)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        why = build_toggle(tmp)
        if why is not None:
            print(f"bench_checks: cannot count instructions here: {why}", file=sys.stderr)
            raise SystemExit(2)
        whole = _run(args.rate, args.cycles, tmp, "none")
        print(json.dumps({"bench": "check_cost", "rate_hz": args.rate, "run": "everything",
                          "instructions_per_cycle": whole}), flush=True)
        cost: dict[str, int] = {}
        for name, (what, _) in KNOCKOUTS.items():
            without = _run(args.rate, args.cycles, tmp, name)
            cost[name] = whole - without
            print(json.dumps({"bench": "check_cost", "rate_hz": args.rate, "run": name,
                              "left_out": what, "instructions_per_cycle": without,
                              "cost": cost[name]}), flush=True)
        minimal = measure(args.rate, args.cycles, tmp, tmp, "minimal")["instructions_per_cycle"]
        checks = sum(cost[c] for c in CHECKS)
        print(json.dumps({"bench": "check_cost.summary", "rate_hz": args.rate,
                          "omnican": whole, "minimal": minimal, "checks": checks,
                          "minimal_plus_checks": minimal + checks,
                          "floor_with_checks_per_minimal": round((minimal + checks) / minimal, 3),
                          "omnican_per_minimal": round(whole / minimal, 3),
                          "rest": whole - minimal - checks}), flush=True)
        print(f"\n| left out ({args.rate:g} Hz, {args.cycles} cycles) | instructions per cycle |")
        print("|---|---|")
        for name, (what, _) in KNOCKOUTS.items():
            print(f"| {what} | {cost[name]:,} |")
        print(f"| every check (the supervisor's and the bus watch) | {checks:,} |")
        print(f"\nomnican {whole:,}; minimal loop {minimal:,}; minimal + every check "
              f"{minimal + checks:,} ({(minimal + checks) / minimal:.2f}x the minimal loop); "
              f"omnican {whole / minimal:.2f}x")


if __name__ == "__main__":
    main()
