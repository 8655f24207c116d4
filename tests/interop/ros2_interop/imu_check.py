"""A real ROS 2 IMU driver's output (rclpy on Fast DDS): sensor_msgs/Imu on /imu/data at
100 Hz with the sensor-data QoS, stamped with the node's clock, against ``omnican ros2
--sim`` whose config has ``[imu] source = "ros2"``. Runs in the interop test's venv.

    python imu_check.py SECONDS RATE_HZ YAW_RATE

Prints {"event": "ready", ...}, then {"event": "done", "results": {...}}: what it sent and
the bridge's IMU counts from /diagnostics while it sent and after it stopped.
"""

import json
import sys
import time

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Imu


def emit(obj):
    print(json.dumps(obj), flush=True)


def main():
    seconds, rate_hz, yaw_rate = float(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3])
    rclpy.init()
    node = rclpy.create_node("imu_driver")
    diag = []
    results = {}
    try:
        node.create_subscription(DiagnosticArray, "/diagnostics", diag.append, 10)
        pub = node.create_publisher(Imu, "/imu/data", qos_profile_sensor_data)

        def spin_until(pred, timeout):
            end = time.monotonic() + timeout
            while time.monotonic() < end and not pred():
                rclpy.spin_once(node, timeout_sec=0.02)
            return bool(pred())

        def bridge():
            for array in reversed(diag):
                for s in array.status:
                    if s.name.endswith(": ros2 bridge"):
                        return {kv.key: kv.value for kv in s.values}
            return {}

        ok = spin_until(lambda: pub.get_subscription_count() > 0 and diag, 60.0)
        emit({"event": "ready", "ok": ok})
        results["ok"] = ok
        if not ok:
            return
        msg = Imu()
        msg.header.frame_id = "imu_link"
        msg.angular_velocity.z = yaw_rate
        msg.linear_acceleration.z = 9.81
        sent, t0 = 0, time.monotonic()
        while True:
            now = time.monotonic()
            if now - t0 >= seconds:
                break
            while sent < int((now - t0) * rate_hz) + 1:
                msg.header.stamp = node.get_clock().now().to_msg()
                pub.publish(msg)
                sent += 1
            rclpy.spin_once(node, timeout_sec=0.0)
            time.sleep(0.002)
        results["sent"] = sent
        results["rate_hz"] = sent / (time.monotonic() - t0)
        # The bridge's counts once they include what was sent (diagnostics come at 1 Hz)
        spin_until(lambda: int(bridge().get("imu_received", "0") or 0) >= sent, 15.0)
        results["after"] = bridge()
        # Silent now: the next diagnostics say for how long
        n = len(diag)
        spin_until(lambda: len(diag) > n + 1, 10.0)
        results["silent"] = bridge()
    finally:
        emit({"event": "done", "results": results})
        node.destroy_node()
        rclpy.shutdown()


if __name__ == "__main__":
    main()
