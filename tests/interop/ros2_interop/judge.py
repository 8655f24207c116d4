"""Running ``omnican ros2 --sim`` against a scenario peer, and judging what the peer saw
(shared by the rclpy interop test and the Cyclone-only loopback test)."""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest

from omnican import Twist, default_config
from tests.interop.ros2_interop.harness import HERE, NetNs, Proc, clean_env
from tests.interop.ros2_interop.scenario import CMD


@dataclass
class Run:
    results: dict[str, Any]
    omnican_code: int
    omnican_out: str
    peer_out: str
    extra: dict[str, Any]


def run_scenario(netns: NetNs, domain: int, peer_argv: Sequence[str], peer_env: dict[str, str],
                 tf_reader: bool = False, stderr: Any = None) -> Run:
    """Start ``omnican ros2 --sim`` and the peer in the namespace; inject the fault when the
    peer asks; stop omnican with Ctrl-C at the end."""
    omnican = Proc(netns.wrap([sys.executable, "-m", "omnican", "ros2", "--sim",
                               "--config", str(HERE / "robot.toml"),
                               "--domain-id", str(domain)]),
                   env=clean_env(PYTHONUNBUFFERED="1"))
    procs = [omnican]
    extra: dict[str, Any] = {}
    try:
        assert omnican.read_until(lambda ln: ln.startswith("Ctrl-C to stop"), 60), \
            "omnican ros2 did not start:\n" + "\n".join(omnican.lines)
        tf = None
        if tf_reader:
            tf = Proc(netns.wrap([sys.executable, str(HERE / "cyclone_check.py"), "tf",
                                  str(domain)]), env=clean_env())
            procs.append(tf)
        peer = Proc(netns.wrap(list(peer_argv)), env=peer_env, stderr=stderr)
        procs.append(peer)
        ready = peer.read_json("ready", 60)
        assert ready is not None, "peer did not start:\n" + "\n".join(peer.lines)
        assert ready["ok"], "peer did not discover omnican:\n" + "\n".join(peer.lines)
        # The peer waits for each state it samples (up to a minute each on a loaded
        # machine): these deadlines only bound a peer that hangs.
        assert peer.read_json("inject", 300), "\n".join(peer.lines)
        omnican.send("fault 2")
        done = peer.read_json("done", 300)
        assert done is not None, "\n".join(peer.lines)
        tf_line = peer.read_json("tf", 10) if not tf_reader else None
        if tf is not None:
            tf.send("stop")
            tf_line = tf.read_json("done", 20)
        extra["tf"] = tf_line
        omnican.interrupt()  # Ctrl-C: clean shutdown, drives disabled
        code, out = omnican.finish()
        return Run(done["results"], code, out, "\n".join(peer.lines), extra)
    finally:
        for p in reversed(procs):
            p.kill()


def _cov(flat: Sequence[float]) -> np.ndarray:
    return np.array(flat, dtype=float).reshape(6, 6)


def final_pose_printed(out: str) -> list[float]:
    line = next(ln for ln in out.splitlines() if ln.startswith("pose x="))
    return [float(w.split("=")[1]) for w in line.split()[1:4]]


def judge(run: Run) -> None:
    """What a ROS 2 nav stack relies on, checked on what the peer saw."""
    try:
        _judge(run)
    except AssertionError as exc:
        raise AssertionError(f"{exc}\n\npeer saw {run.results}\n\nomnican said:\n"
                             f"{run.omnican_out}") from None


def _judge(run: Run) -> None:
    r = run.results
    # Each state the peer samples came (it waits for it; scenario.py).
    assert r["moving_steady"], "never drove steadily at the command"
    assert r["came_to_rest"], "never came to rest once the commands stopped"
    assert r["moving_after_recover"], "never drove steadily again after the recover"
    assert r["rest_at_end"], "never came to rest at the end"
    # Driven by cmd_vel, the measured twist follows the command. It is the encoders' speed
    # over 0.1 s, whose timing jitters when the machine is loaded (seen: 0.32 for 0.3).
    assert r["moving_twist"] == pytest.approx(list(CMD), abs=0.05)
    # Commands stopped: the chassis watchdog stopped the base.
    assert r["stopped_twist"] == pytest.approx([0.0, 0.0, 0.0], abs=1e-3)
    # Odometry agrees with the simulator's ground truth (no slip or noise simulated).
    ox, oy, oth = r["odom_pose"]
    tx, ty, tth = r["true_pose"]
    assert math.hypot(ox, oy) > 0.5, "the base did not move"
    assert math.hypot(ox - tx, oy - ty) < 0.01
    assert abs(oth - tth) < 0.01
    assert float(np.linalg.norm(r["quaternion"])) == pytest.approx(1.0)
    assert r["frames"] == ["odom", "base_link", "odom"]
    assert abs(r["stamp_age_s"]) < 5.0
    # Covariances: symmetric, positive semi-definite, grown with the drive; z, roll and
    # pitch unobserved.
    for flat in (r["pose_cov"], r["moving_twist_cov"]):
        c = _cov(flat)
        assert np.allclose(c, c.T)
        assert np.linalg.eigvalsh(c).min() >= -1e-12
        assert c[0, 0] > 0 and c[1, 1] > 0 and c[5, 5] > 0
        assert c[2, 2] == c[3, 3] == c[4, 4] == 1e6

    # Joint states: one joint per wheel, rad/s = rim speed / wheel radius.
    cfg = default_config()
    radius = cfg.wheels[0].wheel_radius
    assert radius is not None
    expected = cfg.kinematics().to_wheel_speeds(Twist(*CMD)) / radius
    joints = r["moving_joints"]
    assert joints["name"] == ["wheel_0_joint", "wheel_1_joint", "wheel_2_joint"]
    # Each wheel's speed jitters more than the twist (which averages three): 0.06 m/s at
    # the rim, 1.2 rad/s here (seen: 0.036 m/s off on a loaded machine).
    assert joints["velocity"] == pytest.approx([float(v) for v in expected], abs=1.2)
    assert r["stopped_joints"]["velocity"] == pytest.approx([0.0] * 3, abs=0.02)
    assert any(abs(p) > 1.0 for p in r["stopped_joints"]["position"])

    # Diagnostics: all OK while driving; the injected fault shows with its EMCY text, the
    # base stays stopped while latched, recover over ROS clears it and it drives again.
    assert r["diag_ok"] and all(s[1] == 0 for s in r["diag_ok"]), r["diag_ok"]
    assert r["fault_seen"], r["diag_fault"]
    wheel = next(s for s in r["diag_fault"] if s[3] == "canopen node 2")
    assert "0x2310" in wheel[2] and "over-current" in wheel[2]
    chassis = next(s for s in r["diag_fault"] if s[0].endswith(": chassis"))
    assert chassis[1] == 2 and "node 2 fault" in chassis[2]
    assert r["latched_twist"] == pytest.approx([0.0, 0.0, 0.0], abs=1e-3)
    assert r["recovered"], r["diag_recovered"]
    assert r["after_recover_twist"][0] > 0.1

    # tf: odom -> base_link where the odometry says the base is.
    tf = run.extra["tf"]
    assert tf and tf["count"] > 0, run.peer_out
    assert tf["frames"] == ["odom", "base_link"]
    assert tf["transforms_per_message"] == [1]
    fx, fy, _ = r["final_pose"]
    assert tf["last_xy"] == pytest.approx([fx, fy], abs=0.01)

    # Ctrl-C: a clean exit, drives disabled, the same final pose.
    assert run.omnican_code == 0, run.omnican_out
    assert "drives disabled" in run.omnican_out
    assert "Traceback" not in run.omnican_out
    assert final_pose_printed(run.omnican_out)[:2] == pytest.approx([fx, fy], abs=0.01)
