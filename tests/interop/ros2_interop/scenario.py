"""What a ROS 2 peer does to ``omnican ros2 --sim``; run by a real rclpy node
(rclpy_check.py) and by a Cyclone DDS peer of omnican's own (cyclone_check.py). It only
acts and records; the tests judge. Standard library only: it runs in the ROS 2 venv.

Protocol with the test on stdout, one JSON object per line:

    {"event": "ready", "ok": bool}     discovery done, first odom and true pose seen
    {"event": "inject"}                the test now injects a fault into node 2 through
                                       omnican's stdin; this side waits to see it
    {"event": "done", "results": {...}}

Each sample is taken once the state it samples is there (the base driving steadily, at
rest, faulted, recovered), waited for with generous deadlines, never after a fixed
window of real time: a loaded machine (two busy processes beside it) stretches how
long a state takes to come, not what it is.
"""

import json
import math
import time

CMD = (0.3, 0.1, 0.6)  # vx, vy, wz while driving
RATE_HZ = 20.0  # cmd_vel rate
NODE_TOPIC = "/omnican"  # the node's ~/ topics
STEADY = 10  # odom samples in a row (0.2 s at 50 Hz) that show one state: it is steady
MOVING_TOL = 0.04  # m/s, rad/s: driving steadily at CMD (the judge allows 0.05)
REST_TOL = 1e-4  # at rest (the judge allows 1e-3)
WAIT_S = 60.0  # the longest any state may take to come, on a loaded machine


def emit(obj):
    print(json.dumps(obj), flush=True)


def yaw(q):
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def level(status):
    """DiagnosticStatus.level: an int from Cyclone, a 1-byte bytes object from rclpy."""
    lv = status.level
    return lv[0] if isinstance(lv, (bytes, bytearray)) else int(lv)


def twist3(odom):
    t = odom.twist.twist
    return [t.linear.x, t.linear.y, t.angular.z]


class Peer:
    """What an adapter provides: ``seen`` (lists of (monotonic time, message) under
    "odom", "joints", "diag", "truth"), ``spin_once(timeout)``, ``send_cmd(vx, vy, wz)``,
    ``send_recover()``, ``matched()`` (cmd_vel and recover have a reader) and
    ``graph()`` (topic -> type names, or None)."""

    seen: dict


def run(peer):
    results = {}
    seen = peer.seen

    def spin_for(seconds, publish=None):
        end = time.monotonic() + seconds
        next_pub = time.monotonic()
        while time.monotonic() < end:
            if publish is not None and time.monotonic() >= next_pub:
                publish()
                next_pub += 1.0 / RATE_HZ
            peer.spin_once(0.01)

    def spin_until(pred, timeout, publish=None, at_least=0.0):
        """Spin (publishing at RATE_HZ with ``publish``) until ``pred()`` holds, for at
        least ``at_least`` s and at most ``timeout`` s; whether it held."""
        start = time.monotonic()
        next_pub = start
        while time.monotonic() - start < timeout:
            now = time.monotonic()
            if now - start >= at_least and pred():
                return True
            if publish is not None and now >= next_pub:
                publish()
                next_pub = max(next_pub + 1.0 / RATE_HZ, now)  # no burst after a stall
            peer.spin_once(0.01)
        return pred()

    def steady(target, tol):
        """The last STEADY odometry twists are all within ``tol`` of ``target``."""
        last = seen["odom"][-STEADY:]
        return len(last) == STEADY and all(
            abs(a - b) <= tol for _, odom in last for a, b in zip(twist3(odom), target, strict=True))

    def moving():
        return steady(CMD, MOVING_TOL)

    def at_rest():
        return steady((0.0, 0.0, 0.0), REST_TOL)

    def rest_since():
        """When the peer received the first of the odometry samples that show the rest."""
        return seen["odom"][-STEADY][0]

    def heard_since(key, t):
        return bool(seen[key]) and seen[key][-1][0] > t
    def drive():
        peer.send_cmd(*CMD)
        results["cmd_sent"] = results.get("cmd_sent", 0) + 1

    def statuses():
        return seen["diag"][-1][1].status if seen["diag"] else []

    def note(phase):
        """What the bridge says it received, for explaining a failure."""
        bridge = [s for s in statuses() if s.name.endswith(": ros2 bridge")]
        values = {kv.key: kv.value for kv in bridge[0].values} if bridge else {}
        results.setdefault("phases", []).append(
            [phase, results.get("cmd_sent", 0), values.get("cmd_vel_received"),
             len(seen["odom"]), len(seen["diag"])])

    try:
        ok = spin_until(lambda: bool(seen["odom"] and seen["truth"] and seen["diag"]
                                     and peer.matched()), 30.0)
        results["discovered"] = ok
        results["graph"] = peer.graph()
        emit({"event": "ready", "ok": ok, "seen": {k: len(v) for k, v in seen.items()},
              "matched": peer.matched()})
        if not ok:
            return results
        # Drive at 20 Hz (3 s at least, for the rates) until the base drives steadily;
        # sample that state.
        t0 = time.monotonic()
        n_odom0, n_joint0, n_diag0 = len(seen["odom"]), len(seen["joints"]), len(seen["diag"])
        results["moving_steady"] = spin_until(moving, WAIT_S, drive, at_least=3.0)
        steady_at = time.monotonic()
        spin_until(lambda: heard_since("joints", steady_at), WAIT_S, drive)
        elapsed = time.monotonic() - t0
        results["odom_rate_hz"] = (len(seen["odom"]) - n_odom0) / elapsed
        results["joint_states_rate_hz"] = (len(seen["joints"]) - n_joint0) / elapsed
        results["diagnostics_rate_hz"] = (len(seen["diag"]) - n_diag0) / elapsed
        odom = seen["odom"][-1][1]
        results["moving_twist"] = twist3(odom)
        results["moving_twist_cov"] = list(odom.twist.covariance)
        j = seen["joints"][-1][1]
        results["moving_joints"] = {"name": list(j.name), "position": list(j.position),
                                    "velocity": list(j.velocity)}
        if seen.get("battery"):  # the peers that subscribe (rclpy): decoded by ROS 2 itself
            b = seen["battery"][-1][1]
            results["battery"] = {"count": len(seen["battery"]), "voltage": b.voltage,
                                  "current": b.current, "present": b.present,
                                  "technology": b.power_supply_technology,
                                  "frame_id": b.header.frame_id, "location": b.location}
        note("driven")
        # Commands stop: the watchdog stops the base. Sampled at rest, with the truth and
        # the joints as they were published after it came to rest.
        results["came_to_rest"] = spin_until(at_rest, WAIT_S)
        rest = rest_since() if results["came_to_rest"] else time.monotonic()
        spin_until(lambda: heard_since("truth", rest) and heard_since("joints", rest), WAIT_S)
        odom, truth = seen["odom"][-1][1], seen["truth"][-1][1]
        p, tp = odom.pose.pose, truth.pose
        results["stopped_twist"] = twist3(odom)
        results["odom_pose"] = [p.position.x, p.position.y, yaw(p.orientation)]
        results["true_pose"] = [tp.position.x, tp.position.y, yaw(tp.orientation)]
        o = p.orientation
        results["quaternion"] = [o.x, o.y, o.z, o.w]
        results["pose_cov"] = list(odom.pose.covariance)
        results["frames"] = [odom.header.frame_id, odom.child_frame_id, truth.header.frame_id]
        stamp = odom.header.stamp.sec + odom.header.stamp.nanosec * 1e-9
        results["stamp_age_s"] = time.time() - stamp
        j = seen["joints"][-1][1]
        results["stopped_joints"] = {"position": list(j.position), "velocity": list(j.velocity)}
        results["diag_ok"] = [[s.name, level(s), s.message, s.hardware_id] for s in statuses()]

        note("stopped")
        # A drive fault shows in diagnostics with its EMCY text; the base stays stopped.
        emit({"event": "inject"})

        def faulted():
            return any(s.hardware_id == "canopen node 2" and level(s) == 2 for s in statuses())

        results["fault_seen"] = spin_until(faulted, WAIT_S)
        results["diag_fault"] = [[s.name, level(s), s.message, s.hardware_id]
                                 for s in statuses()]
        # Commanded while latched, it must not move: a window of commands (a negative
        # check: time it does not move in; a loaded machine cannot make it move).
        spin_for(1.0, drive)
        results["latched_twist"] = twist3(seen["odom"][-1][1])

        note("latched")
        # Recover over ROS, then drive again and stop.
        peer.send_recover()

        def chassis_ok():
            return any(s.name.endswith(": chassis") and level(s) == 0 for s in statuses())

        results["recovered"] = spin_until(chassis_ok, WAIT_S)
        results["diag_recovered"] = [[s.name, level(s), s.message] for s in statuses()]
        note("recovered")
        results["moving_after_recover"] = spin_until(moving, WAIT_S, drive)
        results["after_recover_twist"] = twist3(seen["odom"][-1][1])
        results["rest_at_end"] = spin_until(at_rest, WAIT_S)
        note("end")
        p = seen["odom"][-1][1].pose.pose
        results["final_pose"] = [p.position.x, p.position.y, yaw(p.orientation)]
        return results
    finally:
        emit({"event": "done", "results": results})
