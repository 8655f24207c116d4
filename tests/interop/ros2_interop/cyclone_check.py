"""A ROS 2 peer built on omnican's own Cyclone DDS message structs.

    python cyclone_check.py scenario DOMAIN   the interop scenario (scenario.py), tf too
    python cyclone_check.py tf DOMAIN         read /tf until stdin says "stop" (or closes)

Loopback only (the same settings ``omnican ros2 --localhost`` uses), run by the tests
inside a network namespace that has nothing but loopback.
"""

import json
import select
import sys
import time
from pathlib import Path
from typing import Any

from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from omnican.ros2 import msgs
from omnican.ros2.settings import Ros2Settings, cyclone_config

sys.path.insert(0, str(Path(__file__).resolve().parent))
import scenario

QOS = Qos(Policy.Reliability.Reliable(0), Policy.History.KeepLast(10),
          Policy.DataRepresentation(use_cdrv0_representation=True))


def participant(domain: int) -> tuple[Domain, DomainParticipant]:
    d = Domain(domain, cyclone_config(Ros2Settings().with_loopback()))
    return d, DomainParticipant(domain)


class CyclonePeer(scenario.Peer):
    def __init__(self, dp: DomainParticipant) -> None:
        self.seen: dict[str, list[tuple[float, Any]]] = {
            "odom": [], "joints": [], "diag": [], "truth": [], "tf": []}
        node = scenario.NODE_TOPIC
        self.readers = {
            "odom": DataReader(dp, Topic(dp, "rt/odom", msgs.Odometry), qos=QOS),
            "joints": DataReader(dp, Topic(dp, "rt/joint_states", msgs.JointState), qos=QOS),
            "diag": DataReader(dp, Topic(dp, "rt/diagnostics", msgs.DiagnosticArray), qos=QOS),
            "truth": DataReader(dp, Topic(dp, f"rt{node}/sim/true_pose", msgs.PoseStamped),
                                qos=QOS),
            "tf": DataReader(dp, Topic(dp, "rt/tf", msgs.TFMessage), qos=QOS),
        }
        self.cmd = DataWriter(dp, Topic(dp, "rt/cmd_vel", msgs.Twist), qos=QOS)
        self.recover = DataWriter(dp, Topic(dp, f"rt{node}/recover", msgs.Empty), qos=QOS)

    def spin_once(self, timeout: float) -> None:
        now = time.monotonic()
        for key, reader in self.readers.items():
            for sample in reader.take(64):
                if isinstance(sample, reader.topic.data_type):  # not an InvalidSample
                    self.seen[key].append((now, sample))
        time.sleep(timeout)

    def send_cmd(self, vx: float, vy: float, wz: float) -> None:
        self.cmd.write(msgs.Twist(msgs.Vector3(vx, vy, 0.0), msgs.Vector3(0.0, 0.0, wz)))

    def send_recover(self) -> None:
        self.recover.write(msgs.Empty())

    def matched(self) -> bool:
        return bool(self.cmd.get_matched_subscriptions()
                    and self.recover.get_matched_subscriptions())

    def graph(self) -> None:
        return None


def tf_summary(seen: list[tuple[float, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {"count": len(seen)}
    if seen:
        tf = seen[-1][1].transforms[0]
        tr = tf.transform.translation
        out["frames"] = [tf.header.frame_id, tf.child_frame_id]
        out["last_xy"] = [tr.x, tr.y]
        out["transforms_per_message"] = sorted({len(m.transforms) for _, m in seen})
    return out


def main() -> None:
    mode, domain = sys.argv[1], int(sys.argv[2])
    dom, dp = participant(domain)
    peer = CyclonePeer(dp)
    if mode == "scenario":
        results = scenario.run(peer)
        del results
        scenario.emit({"event": "tf", **tf_summary(peer.seen["tf"])})
        return
    while True:  # tf: until "stop" or EOF on stdin
        peer.spin_once(0.0)
        ready, _, _ = select.select([sys.stdin], [], [], 0.02)
        if ready and sys.stdin.readline().strip() in ("stop", ""):
            break
    print(json.dumps({"event": "done", **tf_summary(peer.seen["tf"])}), flush=True)
    del dom


if __name__ == "__main__":
    main()
