"""What a base on Zenoh costs and what a fleet of them does, on one loopback router.

``--part loop`` (in one process): the simulated base at 100 Hz with its Zenoh front end
(every topic published to an in-process router on 127.0.0.1, a cmd_vel publisher at
20 Hz driving it) against the same base driven directly with no front end; rounds
interleave. Per run: the control loop's CPU per cycle and its longest gap between cycles
(the front end is a telemetry sink: nothing of it runs on the loop thread), the CPU of
every thread by name, and what one base puts on the network: messages and bytes per
second per topic (key, payload and attachment, as a subscriber to every key of another
session receives them).

``--part fleet``: ``--bases`` (10) ``omnican zenoh --sim`` processes, clients of one
router, and ``omnican.zenoh.fleet.Fleet`` in this process: the time from each base's
start (its process spawned; its front end up) to its row in the fleet view; each base
driven at 0.3 m/s by a cmd_vel publisher of its own, then the fleet stop: from the call
to every reply, and to the last base's wheels at rest on the simulators' truth (each
base's ``sim/true_pose``: at rest once it no longer moves); one base killed with SIGKILL:
the time until the fleet view shows it lost; messages and bytes per second per base; the
CPU of each base's process.

Run: ``python bench/bench_fleet.py`` (both parts; ``--part loop|fleet``, ``--seconds``,
``--rounds``, ``--bases``).
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import socket
import statistics
import threading
import time
from collections import defaultdict
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from bench_chassis import config, cycle_starts, emit
from bench_ros2 import thread_cpu_s

from omnican import Chassis
from omnican.sim import SimulatedBase
from omnican.telemetry import cdr
from omnican.zenoh import rmw

RATE_HZ = 100.0
CMD_HZ = 20.0
TWIST = "geometry_msgs/msg/Twist"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def _config(mode: str, endpoints: list[str], listen: bool = False) -> Any:
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("listen/endpoints" if listen else "connect/endpoints",
                      json.dumps(endpoints))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return conf


@contextmanager
def router() -> Iterator[str]:
    """A Zenoh router in this process on tcp/127.0.0.1:<free port>; yields its endpoint."""
    import zenoh

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = zenoh.open(_config("router", [endpoint], listen=True))
    try:
        yield endpoint
    finally:
        session.close()


def client(endpoint: str) -> Any:
    import zenoh

    return zenoh.open(_config("client", [endpoint]))


class Wire:
    """Counts what one session receives on every key: messages and bytes (key, payload,
    attachment) per key."""

    def __init__(self, session: Any, selector: str = "**") -> None:
        self.messages: dict[str, int] = defaultdict(int)
        self.bytes: dict[str, int] = defaultdict(int)
        self._lock = threading.Lock()
        self._sub = session.declare_subscriber(selector, self._on)

    def _on(self, sample: Any) -> None:
        key = str(sample.key_expr)
        size = len(key) + len(sample.payload.to_bytes())
        if sample.attachment is not None:
            size += len(sample.attachment.to_bytes())
        with self._lock:
            self.messages[key] += 1
            self.bytes[key] += size

    def take(self) -> tuple[dict[str, int], dict[str, int]]:
        """What came since the last take: (messages, bytes) per key."""
        with self._lock:
            out = dict(self.messages), dict(self.bytes)
            self.messages.clear()
            self.bytes.clear()
        return out

    def close(self) -> None:
        self._sub.undeclare()


class CmdVel:
    """A cmd_vel publisher in rmw_zenoh's format (what a ROS 2 node on rmw_zenoh sends)."""

    def __init__(self, session: Any, topic: str, gid: bytes) -> None:
        self.key = rmw.data_key(0, topic, TWIST, rmw.type_hash(TWIST))
        self._pub = session.declare_publisher(self.key)
        self._gid = gid
        self._seq = 0

    def send(self, vx: float) -> None:
        self._seq += 1
        data = cdr.encode(TWIST, {"linear": {"x": vx, "y": 0.0, "z": 0.0},
                                  "angular": {"x": 0.0, "y": 0.0, "z": 0.0}})
        self._pub.put(data, attachment=rmw.Attachment(self._seq, time.time_ns(),
                                                      self._gid).encode())

    def close(self) -> None:
        self._pub.undeclare()


def _topic(key: str) -> str:
    """The ROS topic of an rmw_zenoh data key (its chunks between the domain and the type)."""
    parts = key.split("/")
    return "/" + "/".join(parts[1:-2]) if len(parts) > 3 else key


# ------------------------------------------------------------ one base: the loop's share


def loop_run(seconds: float, bridge_on: bool) -> dict[str, Any]:
    from omnican.zenoh.bridge import ZenohBridge, open_session
    from omnican.zenoh.settings import ZenohSettings

    cfg = config(RATE_HZ)
    with router() as endpoint, SimulatedBase.from_config(cfg) as sim, \
            Chassis.open(cfg) as base:
        starts = cycle_starts(base)
        watcher = client(endpoint)
        wire = Wire(watcher)
        session = bridge = cmd = None
        try:
            if bridge_on:
                settings = ZenohSettings(mode="client", connect=(endpoint,))
                session = open_session(settings)
                bridge = ZenohBridge(base, settings, session, sim=sim).start()
                cmd = CmdVel(watcher, bridge.cmd_topic, bytes(range(16)))
            time.sleep(1.0)  # the sessions meet, the base reaches speed
            wire.take()
            cpu0, cycles0, n0 = base.loop_cpu_s, base.status.cycles, len(starts)
            threads0 = thread_cpu_s()
            t0 = time.monotonic()
            while (now := time.monotonic()) < t0 + seconds:
                if cmd is not None:
                    cmd.send(0.3)
                else:
                    base.set_velocity(0.3, 0.0, 0.0)
                time.sleep(max(0.0, 1.0 / CMD_HZ - (time.monotonic() - now)))
            elapsed = time.monotonic() - t0
            messages, sizes = wire.take()
            threads = {k: v - threads0.get(k, 0.0) for k, v in thread_cpu_s().items()}
            window = starts[n0:]
            gaps = [b - a for a, b in itertools.pairwise(window)]
            cycles = base.status.cycles - cycles0
            out: dict[str, Any] = {
                "bench": "fleet.loop", "zenoh": bridge_on, "seconds": round(elapsed, 2),
                "true_vx": round(sim.true_twist.vx, 3),
                "loop_cpu_us_per_cycle": round((base.loop_cpu_s - cpu0) / max(1, cycles)
                                               * 1e6, 1),
                "loop_longest_gap_ms": round(max(gaps, default=0.0) * 1e3, 1),
                "cpu_percent_by_thread": {
                    k: round(v / elapsed * 100, 2)
                    for k, v in sorted(threads.items(), key=lambda kv: -kv[1])
                    if v / elapsed >= 0.001},
            }
            if bridge_on:
                per_topic: dict[str, list[float]] = {}
                for key, n in messages.items():
                    if key == cmd.key if cmd is not None else False:
                        continue
                    per_topic[_topic(key)] = [round(n / elapsed, 1),
                                              round(sizes[key] / elapsed)]
                out["per_topic_msgs_bytes_per_s"] = dict(sorted(per_topic.items()))
                out["msgs_per_s"] = round(sum(v[0] for v in per_topic.values()), 1)
                out["bytes_per_s"] = round(sum(v[1] for v in per_topic.values()))
            return out
        finally:
            if cmd is not None:
                cmd.close()
            if bridge is not None:
                bridge.close()
            if session is not None:
                session.close()
            wire.close()
            watcher.close()


def loop_part(seconds: float, rounds: int) -> None:
    runs: dict[bool, list[dict[str, Any]]] = {False: [], True: []}
    for _ in range(rounds):
        for on in (False, True):
            result = loop_run(seconds, on)
            emit(**result)
            runs[on].append(result)
    off, on = runs[False], runs[True]
    emit(bench="fleet.loop.summary",
         loop_cpu_us_per_cycle_without=statistics.median(r["loop_cpu_us_per_cycle"] for r in off),
         loop_cpu_us_per_cycle_with=statistics.median(r["loop_cpu_us_per_cycle"] for r in on),
         loop_longest_gap_ms_without=max(r["loop_longest_gap_ms"] for r in off),
         loop_longest_gap_ms_with=max(r["loop_longest_gap_ms"] for r in on),
         msgs_per_s=statistics.median(r["msgs_per_s"] for r in on),
         bytes_per_s=statistics.median(r["bytes_per_s"] for r in on))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--part", choices=("loop", "fleet", "both"), default="both")
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--bases", type=int, default=10)
    args = parser.parse_args()
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    if args.part in ("loop", "both"):
        loop_part(args.seconds, args.rounds)


if __name__ == "__main__":
    main()
