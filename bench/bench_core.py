"""Throughput of the pure core: vectorised kinematics and odometry updates.

Prints one JSON object per line. Run: ``python bench/bench_core.py``.
"""

from __future__ import annotations

import json
import time

import numpy as np

from omnican import Odometry, OmniKinematics, Twist
from omnican.core.limits import VelocityLimiter, VelocityLimits


def rate(fn, n: int, repeat: int = 5) -> float:  # type: ignore[no-untyped-def]
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return n / best


def main() -> None:
    kin = OmniKinematics.from_layout("b21", base_radius=0.19)
    rng = np.random.default_rng(0)
    m = 1_000_000
    twists = rng.uniform(-1, 1, size=(m, 3))
    speeds = kin.to_wheel_speeds_array(twists)
    print(json.dumps({"bench": "kinematics.to_wheel_speeds_array", "rows": m,
                      "twists_per_s": round(rate(lambda: kin.to_wheel_speeds_array(twists), m))}))
    print(json.dumps({"bench": "kinematics.to_twist_array", "rows": m,
                      "twists_per_s": round(rate(lambda: kin.to_twist_array(speeds), m))}))
    print(json.dumps({"bench": "kinematics.desaturate (vectorised)", "rows": m,
                      "rows_per_s": round(rate(lambda: kin.desaturate(speeds, 0.5), m))}))
    n = 20_000
    t = Twist(0.3, 0.1, 0.5)
    print(json.dumps({"bench": "kinematics.to_wheel_speeds (scalar)", "calls": n,
                      "calls_per_s": round(rate(lambda: [kin.to_wheel_speeds(t) for _ in range(n)], n))}))

    travel = np.cumsum(np.tile(kin.to_wheel_speeds(t) * 0.001, (n, 1)), axis=0)

    def odo_run() -> None:
        odo = Odometry(kin)
        for row in travel:
            odo.update(row, 0.001)

    print(json.dumps({"bench": "odometry.update", "updates": n,
                      "updates_per_s": round(rate(odo_run, n))}))
    lim = VelocityLimiter(VelocityLimits(1.0, 3.0, 1.0, 3.0, 2.0, 6.0, 1.0), kin)
    print(json.dumps({"bench": "limits.VelocityLimiter.step", "steps": n,
                      "steps_per_s": round(rate(lambda: [lim.step(t, 0.001) for _ in range(n)], n))}))


if __name__ == "__main__":
    main()
