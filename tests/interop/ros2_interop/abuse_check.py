"""Hostile and buggy cmd_vel publishers, as real ROS 2 nodes (rclpy on Fast DDS), against
``omnican ros2 --sim``. Runs in the interop test's venv of PyPI's ROS 2 wheels.

    python abuse_check.py flood SECONDS RATE_HZ   Twist(0.3, 0, 0) as fast as RATE_HZ
    python abuse_check.py stamped                 TwistStamped on a Twist cmd_vel
    python abuse_check.py two                     two publishers: vx, then vy
    python abuse_check.py oversized               16 MB TwistStamped samples, then sane ones

Prints one JSON object per line: {"event": "ready", ...}, then {"event": "done",
"results": {...}}. It only acts and records; the test judges.
"""

import json
import sys
import time

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Twist, TwistStamped
from nav_msgs.msg import Odometry
from rclpy.duration import Duration


def emit(obj):
    print(json.dumps(obj), flush=True)


def level(status):
    lv = status.level
    return lv[0] if isinstance(lv, (bytes, bytearray)) else int(lv)


class Peer:
    def __init__(self, node):
        self.node = node
        self.odom = []
        self.diag = []
        node.create_subscription(Odometry, "/odom", self.odom.append, 10)
        node.create_subscription(DiagnosticArray, "/diagnostics",
                                 self.diag.append, 10)

    def spin_for(self, seconds):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            rclpy.spin_once(self.node, timeout_sec=0.01)

    def spin_until(self, pred, timeout):
        end = time.monotonic() + timeout
        while time.monotonic() < end and not pred():
            rclpy.spin_once(self.node, timeout_sec=0.02)
        return bool(pred())

    def twist(self):
        t = self.odom[-1].twist.twist
        return [t.linear.x, t.linear.y, t.angular.z]

    def bridge_values(self):
        for array in reversed(self.diag):
            for s in array.status:
                if s.name.endswith(": ros2 bridge"):
                    return {kv.key: kv.value for kv in s.values}
        return {}

    def worst_chassis_level(self, since=0):
        levels = [level(s) for array in self.diag[since:] for s in array.status
                  if s.name.endswith(": chassis")]
        return max(levels, default=None)


def twist(vx, vy, wz):
    t = Twist()
    t.linear.x, t.linear.y, t.angular.z = float(vx), float(vy), float(wz)
    return t


def pace(peer, seconds, rate_hz, publish):
    """publish() at rate_hz for seconds, spinning for odom and diagnostics meanwhile;
    returns how many were published."""
    n, t0 = 0, time.monotonic()
    next_spin = t0
    end = t0 + seconds
    while True:
        now = time.monotonic()
        if now >= end:
            return n
        due = int((now - t0) * rate_hz) + 1
        while n < due:
            publish()
            n += 1
        if now >= next_spin:
            rclpy.spin_once(peer.node, timeout_sec=0.0)
            next_spin = now + 0.01
        elif rate_hz < 1000:
            time.sleep(min(0.005, 1.0 / rate_hz))


def flood(peer, seconds, rate_hz):
    pub = peer.node.create_publisher(Twist, "/cmd_vel", 10)
    ok = peer.spin_until(lambda: pub.get_subscription_count() > 0 and peer.odom
                         and peer.diag, 30.0)
    emit({"event": "ready", "ok": ok})
    results = {"ok": ok}
    if not ok:
        return results
    n_diag = len(peer.diag)
    before = peer.bridge_values()
    msg = twist(0.3, 0.0, 0.0)
    t0 = time.monotonic()
    sent = pace(peer, seconds, rate_hz, lambda: pub.publish(msg))
    elapsed = time.monotonic() - t0
    results.update(sent=sent, rate_hz=sent / elapsed, moving_twist=peer.twist())
    peer.spin_for(1.5)  # the next diagnostics: the bridge's counts after the flood
    results.update(before=before, after=peer.bridge_values(),
                   worst_chassis_level=peer.worst_chassis_level(n_diag))
    pace(peer, 1.5, 20.0, lambda: pub.publish(msg))  # still drives at a sane rate
    results["after_flood_twist"] = peer.twist()
    return results


def stamped(peer):
    pub = peer.node.create_publisher(TwistStamped, "/cmd_vel", 10)
    ok = peer.spin_until(lambda: bool(peer.odom), 30.0)
    emit({"event": "ready", "ok": ok})
    results = {"ok": ok}
    if not ok:
        return results
    msg = TwistStamped()
    msg.header.frame_id = "base_link"
    msg.twist = twist(0.3, 0.0, 0.0)
    pace(peer, 3.0, 20.0, lambda: pub.publish(msg))
    results["twist"] = peer.twist()
    results["matched"] = pub.get_subscription_count()
    return results


def oversized(peer):
    pub = peer.node.create_publisher(TwistStamped, "/cmd_vel", 10)
    ok = peer.spin_until(lambda: pub.get_subscription_count() > 0 and peer.odom, 30.0)
    emit({"event": "ready", "ok": ok})
    results = {"ok": ok}
    if not ok:
        return results
    huge = TwistStamped()
    huge.header.frame_id = "x" * (16 << 20)
    huge.twist = twist(0.5, 0.0, 0.0)
    acked = []
    for _ in range(3):
        pub.publish(huge)
        # Reliable: omnican's Cyclone has it (and dropped it) once it is acknowledged.
        acked.append(pub.wait_for_all_acked(Duration(seconds=10)))
        peer.spin_for(0.3)
    results["huge_acked"] = acked
    results["after_huge_twist"] = peer.twist()
    sane = TwistStamped()
    sane.header.frame_id = "base_link"
    sane.twist = twist(0.2, 0.0, 0.0)
    pace(peer, 2.0, 20.0, lambda: pub.publish(sane))
    results["sane_twist"] = peer.twist()
    return results


def two(peer):
    first = peer.node.create_publisher(Twist, "/cmd_vel", 10)
    second = peer.node.create_publisher(Twist, "/cmd_vel", 10)
    ok = peer.spin_until(lambda: first.get_subscription_count() > 0
                         and second.get_subscription_count() > 0 and peer.odom, 30.0)
    emit({"event": "ready", "ok": ok})
    results = {"ok": ok}
    if not ok:
        return results
    a, b = twist(0.2, 0.0, 0.0), twist(0.0, 0.2, 0.0)

    def both():
        first.publish(a)
        second.publish(b)

    pace(peer, 0.5, 20.0, lambda: first.publish(a))  # the first drives
    pace(peer, 2.0, 20.0, both)  # the second joins: ignored
    results["both_twist"] = peer.twist()
    pace(peer, 2.0, 20.0, lambda: second.publish(b))  # the first stops: the second drives
    results["second_twist"] = peer.twist()
    results["bridge"] = peer.bridge_values()
    return results


def main():
    mode = sys.argv[1]
    rclpy.init()
    node = rclpy.create_node("abuse_check")
    results = {}
    try:
        peer = Peer(node)
        if mode == "flood":
            results = flood(peer, float(sys.argv[2]), float(sys.argv[3]))
        elif mode == "stamped":
            results = stamped(peer)
        elif mode == "oversized":
            results = oversized(peer)
        else:
            results = two(peer)
    finally:
        emit({"event": "done", "results": results})
        node.destroy_node()
        rclpy.shutdown()


if __name__ == "__main__":
    main()
