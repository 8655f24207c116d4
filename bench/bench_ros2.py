"""ROS 2 bridge benchmark against the simulated base: prints one JSON object per line.

Figures, without a network: the rates the bridge achieves for odom, joint_states and
diagnostics, the control loop's rate and late cycles with and without the bridge, and
the CPU cost of building and serialising each message (what a DDS writer is handed).

Figures over DDS (``--flood``; Cyclone DDS on loopback only, multicast off, as
``omnican ros2 --sim`` runs): the control loop's longest gap between two cycles and its
late cycles while another process publishes cmd_vel at 20 Hz (a nav stack) and while it
floods cmd_vel at 10 kHz, and what the bridge took, parsed and dropped meanwhile.

Run: ``python bench/bench_ros2.py`` (about 20 s; ``--seconds`` to change the runs);
``python bench/bench_ros2.py --flood`` (about 30 s).
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Callable
from typing import Any

from bench_chassis import cycle_starts

from omnican import Chassis, default_config
from omnican.ros2 import msgs
from omnican.ros2.bridge import Bridge
from omnican.ros2.settings import Ros2Settings
from omnican.ros2.transport import TopicQos
from omnican.sim import SimulatedBase


def emit(**fields: Any) -> None:
    print(json.dumps(fields), flush=True)


class SerialisingTransport:
    """Serialises every message as a DDS writer would, and counts them; what the bench
    puts into :attr:`inbox` is what the bridge's readers take."""

    def __init__(self) -> None:
        self.count: dict[str, int] = {}
        self.cpu_s: dict[str, float] = {}
        self.inbox: dict[str, list[Any]] = {}
        self.lock = threading.Lock()

    def publisher(self, topic: str, msg_type: type, qos: TopicQos) -> Callable[[Any], None]:
        self.count[topic] = 0
        self.cpu_s[topic] = 0.0

        def publish(msg: Any) -> None:
            t0 = time.thread_time()
            msg.serialize(use_version_2=False)
            self.cpu_s[topic] += time.thread_time() - t0
            self.count[topic] += 1
        return publish

    def reader(self, topic: str, msg_type: type, qos: TopicQos) -> Callable[[], list[Any]]:
        self.inbox[topic] = []

        def take() -> list[Any]:
            with self.lock:
                got, self.inbox[topic] = self.inbox[topic][-qos.depth:], []
            return got
        return take

    def put(self, topic: str, data: bytes) -> None:
        from omnican.ros2.transport import Received

        with self.lock:
            self.inbox[topic].append(Received(1, data))

    def writer_guid(self, topic: str, writer: int) -> str:
        return f"{writer:032x}"

    def publications(self) -> list[Any]:
        return []

    def close(self) -> None:
        pass


def run(seconds: float, bridge_on: bool) -> None:
    cfg = default_config(bus={"interface": "virtual", "channel": f"bench-{uuid.uuid4().hex[:8]}"})
    transport = SerialisingTransport()
    twist = msgs.Twist(msgs.Vector3(0.3, 0.1, 0.0), msgs.Vector3(0.0, 0.0, 0.5))
    data = twist.serialize(use_version_2=False)
    with SimulatedBase.from_config(cfg) as sim, Chassis.open(cfg) as base:
        bridge = Bridge(base, Ros2Settings(), transport, sim=sim) if bridge_on else None
        if bridge is not None:
            bridge.start()
        cpu0, cycles0, late0 = base.loop_cpu_s, base.status.cycles, base.status.late_fraction
        t0 = time.monotonic()
        end = t0 + seconds
        while time.monotonic() < end:
            if bridge is not None:
                transport.put("/cmd_vel", data)
            else:
                base.set_velocity(0.3, 0.1, 0.5)
            time.sleep(0.05)  # cmd_vel at 20 Hz
        elapsed = time.monotonic() - t0
        status = base.status
        fields: dict[str, Any] = {
            "bridge": bridge_on,
            "seconds": round(elapsed, 2),
            "loop_hz": round((status.cycles - cycles0) / elapsed, 1),
            "late_fraction": round(status.late_fraction, 4),
            "late_fraction_at_start": round(late0, 4),
            "loop_cpu_us_per_cycle": round((base.loop_cpu_s - cpu0) /
                                           max(1, status.cycles - cycles0) * 1e6, 1),
        }
        if bridge is not None:
            bridge.close()
            rates = bridge.achieved_rates()
            fields["rates_hz"] = {k: round(v, 2) for k, v in rates.items()}
            fields["serialise_us_per_message"] = {
                topic: round(transport.cpu_s[topic] / n * 1e6, 1)
                for topic, n in transport.count.items() if n}
            fields["cmd_vel_received"] = bridge.cmd_vel_count
        emit(**fields)


# ------------------------------------------------------------ over DDS: a flood


def flooder(domain: int, rate_hz: float, seconds: float) -> None:
    """The other process: cmd_vel (vx 0.3 m/s) at ``rate_hz`` for ``seconds``, loopback."""
    from cyclonedds.domain import Domain, DomainParticipant
    from cyclonedds.pub import DataWriter
    from cyclonedds.qos import Policy, Qos
    from cyclonedds.topic import Topic

    from omnican.ros2.settings import cyclone_config

    dom = Domain(domain, cyclone_config(Ros2Settings().with_loopback()))
    dp = DomainParticipant(domain)
    qos = Qos(Policy.Reliability.Reliable(0), Policy.History.KeepLast(10),
              Policy.DataRepresentation(use_cdrv0_representation=True))
    writer = DataWriter(dp, Topic(dp, "rt/cmd_vel", msgs.Twist), qos=qos)
    deadline = time.monotonic() + 20.0
    while not writer.get_matched_subscriptions() and time.monotonic() < deadline:
        time.sleep(0.05)
    print("ready", flush=True)
    msg = msgs.Twist(msgs.Vector3(0.3, 0.0, 0.0), msgs.Vector3())
    n, t0 = 0, time.monotonic()
    while (now := time.monotonic()) < t0 + seconds:
        due = int((now - t0) * rate_hz) + 1
        while n < due:
            writer.write(msg)
            n += 1
        if rate_hz < 1000:
            time.sleep(0.5 / rate_hz)
    print(json.dumps({"sent": n, "rate_hz": round(n / (time.monotonic() - t0), 1)}),
          flush=True)
    del writer, dp, dom


def thread_cpu_s() -> dict[str, float]:
    """CPU seconds of each of this process's threads, by name (Linux /proc), summed."""
    out: dict[str, float] = {}
    tick = os.sysconf("SC_CLK_TCK")
    python_names = {str(t.native_id): t.name for t in threading.enumerate()}
    for task in os.listdir("/proc/self/task"):
        try:
            with open(f"/proc/self/task/{task}/stat") as f:
                stat = f.read()
        except OSError:
            continue
        name = python_names.get(task) or stat[stat.index("(") + 1:stat.rindex(")")]
        fields = stat[stat.rindex(")") + 2:].split()
        out[name] = out.get(name, 0.0) + (int(fields[11]) + int(fields[12])) / tick
    return out


def flood_run(seconds: float, rate_hz: float, domain: int) -> None:
    from omnican.ros2.transport import DdsTransport

    cfg = default_config(bus={"interface": "virtual", "channel": f"bench-{uuid.uuid4().hex[:8]}"})
    settings = Ros2Settings(domain_id=domain).with_loopback()
    transport = DdsTransport(settings)
    with SimulatedBase.from_config(cfg) as sim, Chassis.open(cfg) as base:
        runner = base._runner
        starts = cycle_starts(base)
        bridge = Bridge(base, settings, transport, sim=sim).start()
        child = subprocess.Popen([sys.executable, __file__, "--flooder", str(domain),
                                  str(rate_hz), str(seconds)], stdout=subprocess.PIPE,
                                 text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
        assert child.stdout is not None
        ready = child.stdout.readline().strip() == "ready"
        late0 = runner.late
        cpu0 = thread_cpu_s()
        n0 = len(starts)
        t0 = time.monotonic()
        got0 = bridge.cmd_vel_count
        handled0 = getattr(bridge, "cmd_vel_parsed", bridge.cmd_vel_count)
        vx: list[float] = []
        while child.poll() is None and time.monotonic() < t0 + seconds + 30:
            vx.append(sim.true_twist.vx)  # the base's speed meanwhile, once a second
            time.sleep(1.0)
            if time.monotonic() > t0 + seconds + 0.5:
                break
        sent = json.loads(child.stdout.readline() or "{}")
        child.wait(timeout=30)
        elapsed = time.monotonic() - t0
        cpu = {k: v - cpu0.get(k, 0.0) for k, v in thread_cpu_s().items()}
        window = starts[n0:]
        gaps = [b - a for a, b in itertools.pairwise(window)]
        status = base.status
        fields: dict[str, Any] = {
            "flood_hz": rate_hz, "matched": ready, **{f"peer_{k}": v for k, v in sent.items()},
            "seconds": round(elapsed, 2),
            "loop_longest_gap_ms": round(max(gaps, default=0.0) * 1e3, 1),
            "loop_gaps_over_2_periods": sum(g > 2 * runner.period_s for g in gaps),
            "late_cycles": runner.late - late0, "cycles": len(window),
            "cmd_vel_received": bridge.cmd_vel_count - got0,
            "cmd_vel_parsed": getattr(bridge, "cmd_vel_parsed", bridge.cmd_vel_count) - handled0,
            "stopped_reason": status.stopped_reason,
            "true_vx_each_s": [round(v, 3) for v in vx],
            "cpu_percent_by_thread": {k: round(v / elapsed * 100, 1)
                                      for k, v in sorted(cpu.items(), key=lambda kv: -kv[1])
                                      if v / elapsed >= 0.01},
        }
        bridge.close()
        transport.close()
        emit(**fields)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seconds", type=float, default=8.0)
    parser.add_argument("--flood", action="store_true", help="the runs over DDS")
    parser.add_argument("--flooder", nargs=3, metavar=("DOMAIN", "HZ", "S"),
                        help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.flooder:
        flooder(int(args.flooder[0]), float(args.flooder[1]), float(args.flooder[2]))
        return
    if args.flood:
        domain = 100 + os.getpid() % 100
        flood_run(args.seconds, 20.0, domain)
        flood_run(args.seconds, 10_000.0, domain)
        return
    run(args.seconds, bridge_on=False)
    run(args.seconds, bridge_on=True)


if __name__ == "__main__":
    main()
