"""A real ROS 2 IMU driving omnican's fused heading (rclpy on Fast DDS): sensor_msgs/Imu on
/imu/data at 100 Hz with the sensor-data QoS against ``omnican ros2 --sim`` whose config
has ``[imu] source = "ros2"``, while this node drives the base straight on /cmd_vel and
reads /odom (fused where an IMU is) and /odom/wheels (the wheels' alone). Runs in the
interop test's venv.

    python imu_fusion_check.py DRIVE_SECONDS YAW_RATE

The phases, each waited for on what omnican publishes (no fixed sleeps):

1. at rest, the gyro reading 0 (omnican learns its bias standing still): the headings;
2. straight ahead at 0.2 m/s for DRIVE_SECONDS while the gyro reads YAW_RATE, a turn the
   wheels do not see (they disagree beyond the fusion's gate: the wheels are taken to
   slip and the gyro is used);
3. at rest again, the gyro reading 0: the headings.

Prints {"event": "ready", ...}, then {"event": "done", "results": {...}}: the headings of
/odom and /odom/wheels before and after, /odom's yaw rate while driving, what was sent.
"""

import json
import math
import sys
import time

import rclpy
from geometry_msgs.msg import Twist
from nav_msgs.msg import Odometry
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Imu

IMU_HZ = 100.0
CMD_HZ = 20.0
SPEED = 0.2  # m/s, straight ahead
STEADY = 10  # this many odometry messages in a row show the state
WAIT_S = 60.0  # generous: the machine may be loaded


def emit(obj):
    print(json.dumps(obj), flush=True)


def yaw(odom):
    q = odom.pose.pose.orientation
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def wrap(a):
    return math.atan2(math.sin(a), math.cos(a))


def main():
    drive_s, yaw_rate = float(sys.argv[1]), float(sys.argv[2])
    rclpy.init()
    node = rclpy.create_node("imu_fusion_driver")
    seen = {"odom": [], "wheels": []}
    results = {}
    try:
        node.create_subscription(Odometry, "/odom", seen["odom"].append, 10)
        node.create_subscription(Odometry, "/odom/wheels", seen["wheels"].append, 10)
        imu_pub = node.create_publisher(Imu, "/imu/data", qos_profile_sensor_data)
        cmd_pub = node.create_publisher(Twist, "/cmd_vel", 10)
        imu = Imu()
        imu.header.frame_id = "imu_link"
        imu.linear_acceleration.z = 9.81
        state = {"gyro": 0.0, "imu_sent": 0, "imu_next": time.monotonic(), "cmd": None,
                 "cmd_next": time.monotonic(), "cmd_sent": 0, "turn_sent": 0.0}

        def tick():
            """Publish what is due: the IMU at 100 Hz always (never a burst after a
            stall: a real driver's samples are taken when they are stamped), the command
            at 20 Hz while there is one."""
            now = time.monotonic()
            if now >= state["imu_next"]:
                imu.angular_velocity.z = state["gyro"]
                imu.header.stamp = node.get_clock().now().to_msg()
                imu_pub.publish(imu)
                state["imu_sent"] += 1
                state["turn_sent"] += state["gyro"] / IMU_HZ
                state["imu_next"] = max(state["imu_next"] + 1.0 / IMU_HZ, now)
            if state["cmd"] is not None and now >= state["cmd_next"]:
                t = Twist()
                t.linear.x = state["cmd"]
                cmd_pub.publish(t)
                state["cmd_sent"] += 1
                state["cmd_next"] = max(state["cmd_next"] + 1.0 / CMD_HZ, now)
            rclpy.spin_once(node, timeout_sec=0.002)

        def spin_until(pred, timeout, at_least=0.0):
            start = time.monotonic()
            while time.monotonic() - start < timeout:
                if time.monotonic() - start >= at_least and pred():
                    return True
                tick()
            return bool(pred())

        def steady(key, vx, tol):
            last = seen[key][-STEADY:]
            return len(last) == STEADY and all(
                abs(o.twist.twist.linear.x - vx) <= tol and abs(o.twist.twist.linear.y) <= tol
                for o in last)

        def at_rest():
            return steady("wheels", 0.0, 1e-3)

        def headings():
            return {"fused": yaw(seen["odom"][-1]), "wheels": yaw(seen["wheels"][-1])}

        def fresh(since):
            """Both topics have STEADY messages more since the counts ``since``."""
            return (len(seen["odom"]) >= since[0] + STEADY
                    and len(seen["wheels"]) >= since[1] + STEADY)

        ok = spin_until(lambda: imu_pub.get_subscription_count() > 0
                        and cmd_pub.get_subscription_count() > 0
                        and seen["odom"] and seen["wheels"], WAIT_S)
        emit({"event": "ready", "ok": ok, "seen": {k: len(v) for k, v in seen.items()}})
        results["ok"] = ok
        if not ok:
            return
        # 1. At rest with the gyro at 0 for a second at least (the bias is learnt as 0).
        results["rest_before"] = spin_until(at_rest, WAIT_S, at_least=1.0)
        before = headings()
        # 2. Straight ahead, the gyro turning: for drive_s at least, until the base drives.
        state["gyro"], state["cmd"] = yaw_rate, SPEED
        turn0 = state["turn_sent"]
        results["moving"] = spin_until(lambda: steady("wheels", SPEED, 0.02), WAIT_S,
                                       at_least=drive_s)
        n = len(seen["odom"])
        spin_until(lambda: len(seen["odom"]) >= n + STEADY, WAIT_S)
        results["odom_yaw_rate_driving"] = [o.twist.twist.angular.z
                                            for o in seen["odom"][n:n + STEADY]]
        results["wheels_yaw_rate_driving"] = [o.twist.twist.angular.z
                                              for o in seen["wheels"][-STEADY:]]
        # 3. Stop (a zero command, as a teleop sends), the gyro at 0 again; at rest.
        state["gyro"], state["cmd"] = 0.0, 0.0
        results["gyro_turn_sent"] = state["turn_sent"] - turn0
        results["rest_after"] = spin_until(at_rest, WAIT_S, at_least=0.5)
        counts = (len(seen["odom"]), len(seen["wheels"]))
        spin_until(lambda: fresh(counts), WAIT_S)
        after = headings()
        results["before"], results["after"] = before, after
        results["fused_turn"] = wrap(after["fused"] - before["fused"])
        results["wheels_turn"] = wrap(after["wheels"] - before["wheels"])
        results["distance_x"] = (seen["wheels"][-1].pose.pose.position.x
                                 - seen["wheels"][0].pose.pose.position.x)
        results["imu_sent"], results["cmd_sent"] = state["imu_sent"], state["cmd_sent"]
    finally:
        emit({"event": "done", "results": results})
        node.destroy_node()
        rclpy.shutdown()


if __name__ == "__main__":
    main()
