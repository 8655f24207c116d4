"""Chassis benchmark against the simulated base: prints one JSON object per line.

Figures: loop rate and late cycles at 100/500/1000 Hz, command-to-RPDO latency,
worst-case bits per cycle and bus load, open-to-enabled time, and odometry error
against ground truth after a square. The SYNC jitter and CPU figures here come from a
receiver of its own on the channel (every host send then copies each frame once
more): for what a cycle costs, beside its floor and a plain canopen loop, run
bench/bench_cycle.py.

Run: ``python bench/bench_chassis.py`` (about a minute; ``--quick`` for a shorter run).
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import threading
import time
import uuid
from dataclasses import replace
from typing import Any

import can
import canopen
import numpy as np

from omnican import Chassis, default_config
from omnican.chassis.runner import ThreadRunner
from omnican.config import ChassisConfig
from omnican.sim import SimulatedBase


def emit(**fields: Any) -> None:
    print(json.dumps(fields), flush=True)


def config(rate_hz: float, wheels: int = 3) -> ChassisConfig:
    """The demo base at ``rate_hz``; ``wheels`` other than 3: that many of its wheels,
    one node each, spread evenly around the centre."""
    cfg = default_config(bus={"interface": "virtual", "channel": f"bench-{uuid.uuid4().hex[:8]}"})
    cfg = replace(cfg, chassis=replace(cfg.chassis, rate_hz=rate_hz, max_accel=2.0,
                                        max_angular_accel=6.0))
    if wheels == 3:
        return cfg
    one = cfg.wheels[0]
    return replace(cfg, chassis=replace(cfg.chassis, layout=None), wheels=tuple(
        replace(one, node_id=i + 1, angle_deg=360.0 * i / wheels) for i in range(wheels)))


def loop_thread(base: Chassis) -> threading.Thread:
    """The real-time loop thread of ``base``."""
    runner = base._runner
    assert isinstance(runner, ThreadRunner), "a real-time base"
    return runner.thread


def cycle_starts(base: Chassis) -> list[float]:
    """The start time of each control cycle from now on: the runner's cycle, wrapped to
    note when it began (the list grows while the base runs)."""
    runner = base._runner
    starts: list[float] = []
    cycle = runner.cycle

    def timed(now: float) -> None:
        starts.append(now)
        cycle(now)

    runner.cycle = timed
    return starts


def thread_cpu(thread: threading.Thread) -> float:
    """CPU seconds a thread has used (Linux per-thread clock)."""
    assert thread.ident is not None
    return time.clock_gettime(time.pthread_getcpuclockid(thread.ident))


def notifier_threads(network: canopen.Network) -> list[threading.Thread]:
    readers = getattr(network.notifier, "_readers", [])
    return [r for r in readers if isinstance(r, threading.Thread)]


def percentile(values: Any, q: float) -> float:
    """The q-th percentile of a list or an array; NaN when empty."""
    arr = np.asarray(values, dtype=float)
    return float(np.percentile(arr, q)) if arr.size else float("nan")


class SyncListener(can.Listener):
    def __init__(self) -> None:
        self.sync_times: list[float] = []
        self.rpdo: list[tuple[float, bytes]] = []

    def on_message_received(self, msg: can.Message) -> None:
        if msg.arbitration_id == 0x80:
            self.sync_times.append(msg.timestamp)
        elif msg.arbitration_id == 0x301:
            self.rpdo.append((msg.timestamp, bytes(msg.data)))


def bench_rate(rate_hz: float, seconds: float) -> None:
    cfg = config(rate_hz)
    assert cfg.bus is not None
    listener = SyncListener()
    with SimulatedBase.from_config(cfg), Chassis.open(cfg) as base:
        spy = can.Bus(**cfg.bus)
        notifier = can.Notifier(spy, [listener], timeout=0.1)
        thread = loop_thread(base)
        notif = notifier_threads(base.bus.network)
        time.sleep(0.2)
        cycles0 = base.status.cycles
        late0 = base._runner.late
        loop0 = thread_cpu(thread)
        cpu0 = loop0 + sum(thread_cpu(t) for t in notif)
        t0 = time.monotonic()
        listener.sync_times.clear()
        end = t0 + seconds
        while time.monotonic() < end:
            base.set_velocity(0.3 * math.sin(time.monotonic()), 0.1, 0.2)
            time.sleep(0.01)
        elapsed = time.monotonic() - t0
        cycles = base.status.cycles - cycles0
        loop_cpu = thread_cpu(thread) - loop0
        cpu = thread_cpu(thread) + sum(thread_cpu(t) for t in notif) - cpu0
        late = base._runner.late - late0
        periods = np.diff(np.array(listener.sync_times))
        jitter = np.abs(periods - 1.0 / rate_hz) * 1e6
        bits = base.cycle_bits()
        # Command-to-RPDO latency: from rest, a step command; node 1's first RPDO (0x301)
        # with a new target.
        base.stop()
        time.sleep(0.5)
        latencies = []
        for _ in range(30):
            listener.rpdo.clear()
            time.sleep(0.05 + np.random.default_rng().uniform(0, 1.0 / rate_hz))
            before = listener.rpdo[-1][1] if listener.rpdo else None
            t_cmd = time.time()
            base.set_velocity(0.0, 0.2, 0.0)  # sideways: moves wheel 1 (node 1) too
            deadline = time.monotonic() + 0.5
            found = None
            while time.monotonic() < deadline and found is None:
                for ts, data in list(listener.rpdo):
                    if ts >= t_cmd and data != before:
                        found = ts
                        break
                time.sleep(0.0005)
            if found is not None:
                latencies.append((found - t_cmd) * 1e6)
            base.stop()
            time.sleep(0.3)
        notifier.stop()
        spy.shutdown()
        emit(bench="chassis.loop", rate_hz=rate_hz, seconds=round(elapsed, 2),
             achieved_hz=round(cycles / elapsed, 1),
             late_cycle_fraction=round(late / max(cycles, 1), 4),
             sync_jitter_us_p50=round(percentile(list(jitter), 50), 1),
             sync_jitter_us_p99=round(percentile(list(jitter), 99), 1),
             host_cpu_us_per_cycle=round(cpu / max(cycles, 1) * 1e6, 1),
             of_which_loop_thread_us=round(loop_cpu / max(cycles, 1) * 1e6, 1),
             cmd_to_rpdo_us_p50=round(percentile(latencies, 50), 1),
             cmd_to_rpdo_us_p99=round(percentile(latencies, 99), 1),
             worst_case_bits_per_cycle=bits,
             bus_load_500k=round(bits * rate_hz / 500_000, 3),
             bus_load_1M=round(bits * rate_hz / 1_000_000, 3))


def bench_startup(repeat: int) -> None:
    times = []
    for _ in range(repeat):
        cfg = config(100)
        with SimulatedBase.from_config(cfg):
            t0 = time.monotonic()
            base = Chassis.open(cfg)
            times.append(time.monotonic() - t0)
            base.close()
    emit(bench="chassis.open_to_enabled", runs=repeat, median_s=round(statistics.median(times), 3),
         max_s=round(max(times), 3))


def bench_square(rate_hz: float, side_m: float, speed: float) -> None:
    cfg = config(rate_hz)
    with SimulatedBase.from_config(cfg) as sim, Chassis.open(cfg) as base:
        sim.reset_truth()
        base.reset_pose()

        def hold(vx: float, wz: float, seconds: float) -> None:
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                base.set_velocity(vx, 0.0, wz)
                time.sleep(0.01)

        t0 = time.monotonic()
        for _ in range(4):
            hold(speed, 0.0, side_m / speed)
            hold(0.0, math.pi / 2, 1.0)
        base.stop()
        time.sleep(1.0)
        truth, pose = sim.true_pose, base.pose
        emit(bench="chassis.odometry_square", rate_hz=rate_hz, side_m=side_m,
             path_m=4 * side_m, seconds=round(time.monotonic() - t0, 1),
             true_pose=[round(truth.x, 4), round(truth.y, 4), round(truth.theta, 4)],
             position_error_mm=round(pose.distance_to(truth) * 1000, 2),
             heading_error_mrad=round(abs(pose.theta - truth.theta) * 1000, 2))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true", help="shorter runs")
    args = parser.parse_args()
    seconds = 2.0 if args.quick else 5.0
    for rate in (100.0, 500.0, 1000.0):
        bench_rate(rate, seconds)
    bench_startup(3 if args.quick else 7)
    side = 0.5 if args.quick else 2.0
    for rate in (20.0, 1000.0):
        bench_square(rate, side, 0.8)


if __name__ == "__main__":
    main()
