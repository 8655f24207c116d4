"""Can a front end stall the wheels? The control loop at 100 Hz against the simulated
base, with no front end, then with every front end at once: the Foxglove live view with a
client subscribed to every topic, an MCAP recording and the ROS 2 bridge (Cyclone DDS on
loopback only, multicast off). Both runs in one process, interleaved, so the machine's
load is the same for both.

Prints one JSON object per run and a last one side by side: late cycles (starting more
than a fifth of a period late), the longest gap between two cycles, the 99th percentile
gap, and the ratio of each with front ends to without. The goal: within 1.5x.

Run: ``python bench/bench_frontends.py`` (``--seconds 10 --rounds 2 --rate 100``).
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from bench_chassis import config, cycle_starts, emit
from bench_record import _Watcher

from omnican import Chassis
from omnican.record.recording import FileRecording
from omnican.sim import SimulatedBase
from omnican.telemetry.attach import feed_of


def one_run(rate_hz: float, seconds: float, frontends: bool, tmp: Path) -> dict[str, Any]:
    cfg = config(rate_hz)
    record = tmp / f"frontends-{time.monotonic_ns()}.mcap" if frontends else None
    with SimulatedBase.from_config(cfg) as sim, Chassis.open(
            cfg, record=FileRecording(record) if record else None) as base, \
            contextlib.ExitStack() as stack:
        runner = base._runner
        starts = cycle_starts(base)
        messages = None
        if frontends:
            from omnican.live import watch
            from omnican.telemetry.attach import add_truth

            add_truth(base, sim)  # as a command's session does
            view = stack.enter_context(watch(base, sim, "127.0.0.1:0"))
            assert view is not None
            watcher = _Watcher(view.url)
            watcher.start()
            stack.callback(watcher.join)
            stack.callback(watcher.stop_event.set)
            messages = watcher
            try:
                from omnican.ros2.bridge import Bridge
                from omnican.ros2.settings import Ros2Settings
                from omnican.ros2.transport import DdsTransport

                settings = Ros2Settings().with_loopback()
                transport = DdsTransport(settings)
                stack.callback(transport.close)
                stack.enter_context(Bridge(base, settings, transport, sim=sim))
            except ImportError:
                print("# no cyclonedds: the run goes without the ROS 2 bridge")
        time.sleep(1.0)  # set-up done, subscriptions made
        starts.clear()
        late0, cycles0 = runner.late, base.status.cycles
        msgs0 = messages.messages if messages is not None else 0
        t0 = time.monotonic()
        while time.monotonic() - t0 < seconds:
            base.set_velocity(0.3, 0.1, 0.2)
            time.sleep(0.02)
        elapsed = time.monotonic() - t0
        cycles = base.status.cycles - cycles0
        late = runner.late - late0
        gaps = sorted(b - a for a, b in itertools.pairwise(starts))
        out = dict(bench="frontends", rate_hz=rate_hz,
                   frontends="live view + MCAP + ROS 2" if frontends else "none",
                   seconds=round(elapsed, 2), cycles=cycles,
                   late_fraction=round(late / max(cycles, 1), 4),
                   longest_gap_ms=round(1e3 * gaps[-1], 2) if gaps else None,
                   p99_gap_ms=round(1e3 * gaps[int(0.99 * (len(gaps) - 1))], 2) if gaps else None,
                   telemetry_dropped=feed_of(base).dropped)
        if messages is not None:
            out["viewer_messages_per_s"] = round((messages.messages - msgs0) / elapsed)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rate", type=float, default=100.0)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--rounds", type=int, default=2)
    args = parser.parse_args()
    runs: dict[bool, list[dict[str, Any]]] = {False: [], True: []}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.rounds):
            for frontends in (False, True):
                run = one_run(args.rate, args.seconds, frontends, Path(tmp))
                runs[frontends].append(run)
                emit(**run)

    def worst(key: str, frontends: bool) -> float:
        return max(float(r[key] or 0.0) for r in runs[frontends])

    def mean(key: str, frontends: bool) -> float:
        return statistics.fmean(float(r[key] or 0.0) for r in runs[frontends])

    def ratio(a: float, b: float) -> float | None:
        return round(a / b, 2) if b else None

    emit(bench="frontends.summary", rate_hz=args.rate,
         late_fraction_none=round(mean("late_fraction", False), 4),
         late_fraction_all=round(mean("late_fraction", True), 4),
         late_ratio=ratio(mean("late_fraction", True), mean("late_fraction", False)),
         longest_gap_ms_none=worst("longest_gap_ms", False),
         longest_gap_ms_all=worst("longest_gap_ms", True),
         longest_gap_ratio=ratio(worst("longest_gap_ms", True), worst("longest_gap_ms", False)),
         p99_gap_ms_none=round(mean("p99_gap_ms", False), 2),
         p99_gap_ms_all=round(mean("p99_gap_ms", True), 2))


if __name__ == "__main__":
    main()
