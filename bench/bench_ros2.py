"""ROS 2 bridge benchmark against the simulated base, without a network: prints one JSON
object per line.

Figures: the rates the bridge achieves for odom, joint_states and diagnostics (its
publisher thread polls the chassis snapshot), the control loop's rate and late cycles
with and without the bridge, and the CPU cost of building and serialising each message
(what a DDS writer is handed).

Run: ``python bench/bench_ros2.py`` (about 20 s; ``--seconds`` to change the runs).
"""

from __future__ import annotations

import argparse
import json
import time
import uuid
from collections.abc import Callable
from typing import Any

from omnican import Chassis, default_config
from omnican.ros2 import msgs
from omnican.ros2.bridge import Bridge, TopicQos
from omnican.ros2.settings import Ros2Settings
from omnican.sim import SimulatedBase


def emit(**fields: Any) -> None:
    print(json.dumps(fields), flush=True)


class SerialisingTransport:
    """Serialises every message as a DDS writer would, and counts them."""

    def __init__(self) -> None:
        self.count: dict[str, int] = {}
        self.cpu_s: dict[str, float] = {}
        self.callbacks: dict[str, Callable[[Any], None]] = {}

    def publisher(self, topic: str, msg_type: type, qos: TopicQos) -> Callable[[Any], None]:
        self.count[topic] = 0
        self.cpu_s[topic] = 0.0

        def publish(msg: Any) -> None:
            t0 = time.thread_time()
            msg.serialize(use_version_2=False)
            self.cpu_s[topic] += time.thread_time() - t0
            self.count[topic] += 1
        return publish

    def subscribe(self, topic: str, msg_type: type, qos: TopicQos,
                  callback: Callable[[Any], None]) -> None:
        self.callbacks[topic] = callback

    def close(self) -> None:
        pass


def run(seconds: float, bridge_on: bool) -> None:
    cfg = default_config(bus={"interface": "virtual", "channel": f"bench-{uuid.uuid4().hex[:8]}"})
    transport = SerialisingTransport()
    twist = msgs.Twist(msgs.Vector3(0.3, 0.1, 0.0), msgs.Vector3(0.0, 0.0, 0.5))
    with SimulatedBase.from_config(cfg) as sim, Chassis.open(cfg) as base:
        bridge = Bridge(base, Ros2Settings(), transport, sim=sim) if bridge_on else None
        if bridge is not None:
            bridge.start()
        cpu0, cycles0, late0 = base.loop_cpu_s, base.status.cycles, base.status.late_fraction
        t0 = time.monotonic()
        end = t0 + seconds
        while time.monotonic() < end:
            if bridge is not None:
                transport.callbacks["/cmd_vel"](twist)
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seconds", type=float, default=8.0)
    args = parser.parse_args()
    run(args.seconds, bridge_on=False)
    run(args.seconds, bridge_on=True)


if __name__ == "__main__":
    main()
