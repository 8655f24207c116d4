"""The base on a bus that loses frames: at each loss rate, ten opens of the simulated
base (each a different random pattern of losses, both ways, every kind of frame), and
for each that opened, a 1 m square driven as goal legs.

Prints one line per loss rate: opens that succeeded out of ten, squares completed,
the odometry's error against the simulator's true pose at the end (median and worst,
mm), and stops the base latched that nothing but the loss caused. Everything runs in
simulated time (lock-step), so the figures are the same on every run.

Run: ``python bench/bench_loss.py`` (``--rates 0.001,0.01,0.05 --runs 10``).
"""

from __future__ import annotations

import argparse
import logging
import statistics
import time
import uuid

from omnican import Chassis, default_config
from omnican.command import motion
from omnican.errors import OmnicanError
from omnican.sim import SimClock, SimulatedBase
from omnican.sim.link import LossyLink


def one_run(loss: float, seed: int) -> dict[str, object]:
    channel = f"bench-loss-{uuid.uuid4().hex[:8]}"
    cfg = default_config(bus={"interface": "virtual", "channel": channel})
    clock = SimClock()
    out: dict[str, object] = {"opened": False, "completed": False, "error_mm": None,
                              "stops": 0, "why": ""}
    with LossyLink(clock, channel, channel + "-drives", loss=loss, seed=seed) as link, \
            SimulatedBase.from_config(cfg, bus={"interface": "virtual",
                                                "channel": channel + "-drives"},
                                      clock=clock) as sim:
        try:
            base = Chassis.open(cfg, clock=clock)
        except OmnicanError as exc:
            out["why"] = str(exc)
            out["lost"], out["passed"] = link.stats.lost, link.stats.passed
            return out
        with base:
            out["opened"] = True
            plan, _ = motion.fit_to_limits(motion.square(1.0, speed=0.3), cfg)
            try:
                motion.run(base, plan)
                out["completed"] = True
            except motion.BaseStoppedError as exc:
                out["why"] = str(exc)
            out["stops"] = int(base.status.stopped_reason is not None)
            base.stop()
            clock.sleep(1.0)
            out["error_mm"] = 1000.0 * base.pose.distance_to(sim.true_pose)
        out["lost"] = link.stats.lost
        out["passed"] = link.stats.passed
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rates", default="0.001,0.01,0.05",
                        help="frame loss probabilities, comma-separated")
    parser.add_argument("--runs", type=int, default=10)
    args = parser.parse_args()
    logging.basicConfig(level=logging.ERROR)
    logging.getLogger("canopen.sdo.client").setLevel(logging.CRITICAL)  # we say what failed
    for loss in (float(r) for r in args.rates.split(",")):
        t0 = time.perf_counter()
        runs = [one_run(loss, seed) for seed in range(1, args.runs + 1)]
        errors = [float(r["error_mm"]) for r in runs if r["error_mm"] is not None]  # type: ignore[arg-type]
        lost = sum(int(r.get("lost", 0)) for r in runs)  # type: ignore[call-overload]
        passed = sum(int(r.get("passed", 0)) for r in runs)  # type: ignore[call-overload]
        print(f"loss {loss:.1%}: opened {sum(bool(r['opened']) for r in runs)}/{len(runs)}, "
              f"squares completed {sum(bool(r['completed']) for r in runs)}, "
              f"odometry error median {statistics.median(errors) if errors else float('nan'):.2f} mm "
              f"worst {max(errors) if errors else float('nan'):.2f} mm, "
              f"spurious stops {sum(int(r['stops']) for r in runs)} "  # type: ignore[call-overload]
              f"({lost} of {lost + passed} frames lost; {time.perf_counter() - t0:.1f} s)")
        for r in runs:
            if r["why"]:
                print(f"    {r['why']}")


if __name__ == "__main__":
    main()
