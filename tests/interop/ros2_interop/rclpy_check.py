"""The interop scenario (scenario.py) as a real ROS 2 node: rclpy on Fast DDS.

Runs in the interop test's venv of PyPI's ROS 2 wheels, as a script (they re-launch
the interpreter to set the library path). Usage: python rclpy_check.py
"""

import sys
import time
from pathlib import Path

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, Twist
from nav_msgs.msg import Odometry
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import BatteryState, JointState
from std_msgs.msg import Empty

sys.path.insert(0, str(Path(__file__).resolve().parent))
import scenario


class RclpyPeer(scenario.Peer):
    def __init__(self, node):
        self.node = node
        self.seen = {"odom": [], "joints": [], "diag": [], "truth": [], "battery": []}

        def keep(key):
            return lambda msg: self.seen[key].append((time.monotonic(), msg))

        node.create_subscription(Odometry, "/odom", keep("odom"), 10)
        # robot_state_publisher reads joint_states best effort: so does this.
        node.create_subscription(JointState, "/joint_states", keep("joints"),
                                 QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT))
        node.create_subscription(DiagnosticArray, "/diagnostics", keep("diag"), 10)
        node.create_subscription(BatteryState, "/battery_state", keep("battery"), 10)
        node.create_subscription(PoseStamped, f"{scenario.NODE_TOPIC}/sim/true_pose",
                                 keep("truth"), 10)
        self.cmd = node.create_publisher(Twist, "/cmd_vel", 10)
        self.recover = node.create_publisher(Empty, f"{scenario.NODE_TOPIC}/recover", 10)

    def spin_once(self, timeout):
        rclpy.spin_once(self.node, timeout_sec=timeout)

    def send_cmd(self, vx, vy, wz):
        t = Twist()
        t.linear.x, t.linear.y, t.angular.z = float(vx), float(vy), float(wz)
        self.cmd.publish(t)

    def send_recover(self):
        self.recover.publish(Empty())

    def matched(self):
        return self.cmd.get_subscription_count() > 0 and self.recover.get_subscription_count() > 0

    def graph(self):
        return {name: types for name, types in self.node.get_topic_names_and_types()}


def main():
    rclpy.init()
    node = rclpy.create_node("interop_check")
    try:
        scenario.run(RclpyPeer(node))
    finally:
        node.destroy_node()
        rclpy.shutdown()


if __name__ == "__main__":
    main()
