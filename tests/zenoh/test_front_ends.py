"""--zenoh on drive, sim, ros2 and teleop as a user runs them: each a process of its own,
a client of a router on loopback; another session receives what it publishes, and
drives or stops it through the one arbiter."""

from __future__ import annotations

import contextlib
import itertools
import os
import sys
import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest

from omnican.zenoh import rmw
from tests.interop.ros2_interop.harness import Proc
from tests.zenoh.conftest import client, wait_real

TIMEOUT_S = 120.0  # real seconds, generous: a process starting on a loaded machine
ODOM = "nav_msgs/msg/Odometry"


def omnican(*argv: str) -> Proc:
    return Proc([sys.executable, "-m", "omnican", *argv], env=dict(os.environ))


def key(domain: int, topic: str, type_name: str) -> str:
    return rmw.data_key(domain, topic, type_name, rmw.type_hash(type_name))


@pytest.fixture
def session(router: str) -> Iterator[Any]:
    s = client(router)
    try:
        yield s
    finally:
        s.close()


def received(session: Any, key_expr: str) -> tuple[threading.Event, Any]:
    got = threading.Event()
    return got, session.declare_subscriber(key_expr, lambda sample: got.set())


@contextlib.contextmanager
def publishing(session: Any, topic: str, vx: float, gid: bytes) -> Iterator[None]:
    """A cmd_vel publisher (its attachment's GID ``gid``) sending ``vx`` every 50 ms
    while the block runs."""
    from omnican.telemetry import cdr

    pub = session.declare_publisher(key(0, topic, "geometry_msgs/msg/Twist"))
    twist = cdr.encode("geometry_msgs/msg/Twist", {"linear": {"x": vx, "y": 0.0, "z": 0.0},
                                                   "angular": {"x": 0.0, "y": 0.0, "z": 0.0}})
    stop = threading.Event()

    def send() -> None:
        for seq in itertools.count(1):
            if stop.wait(0.05):
                return
            pub.put(twist, attachment=rmw.Attachment(seq, time.time_ns(), gid).encode())

    sender = threading.Thread(target=send, daemon=True)
    sender.start()
    try:
        yield
    finally:
        stop.set()
        sender.join()
        pub.undeclare()


def test_drive_sim_zenoh_publishes_odom(router: str, session: Any) -> None:
    got, sub = received(session, key(0, "/robot1/odom", ODOM))
    proc = omnican("drive", "--sim", "--vx", "0.1", "--duration", "3", "--zenoh",
                   "--zenoh-mode", "client", "--zenoh-connect", router, "--namespace", "/robot1")
    try:
        code, out = proc.finish(timeout=TIMEOUT_S)
        assert code == 0, out
        assert got.is_set(), out
        assert "omnican: Zenoh node /robot1/omnican on domain 0 (" in out
        assert "in /robot1/cmd_vel; out /robot1/odom, /robot1/tf" in out
    finally:
        sub.undeclare()
        proc.kill()


def test_drive_without_a_motion_takes_cmd_vel_from_zenoh(router: str, session: Any) -> None:
    proc = omnican("drive", "--sim", "--duration", "6", "--zenoh", "--zenoh-mode", "client",
                   "--zenoh-connect", router)
    try:
        assert proc.read_until(lambda text: text.startswith("omnican: Zenoh node"), TIMEOUT_S)
        with publishing(session, "/cmd_vel", 0.1, bytes(range(16))):
            code, out = proc.finish(timeout=TIMEOUT_S)
        assert code == 0, out
        assert "took commands from Zenoh for 6.00 s" in out
        pose = next(text for text in out.splitlines() if text.startswith("pose x="))
        assert float(pose.split()[1].removeprefix("x=")) > 0.01, out
    finally:
        proc.kill()


def test_a_stop_from_the_network_ends_a_scripted_drive(router: str, session: Any) -> None:
    """~/stop (the fleet stop's path) stops a base that drives a motion: the motion ends
    with exit 1 naming who stopped it; a cmd_vel publisher meanwhile is refused."""
    from omnican.telemetry import cdr
    from omnican.zenoh.services import SOURCE, service_key

    moving = threading.Event()

    def odom(sample: Any) -> None:
        msg = cdr.decode(ODOM, sample.payload.to_bytes())
        if msg["twist"]["twist"]["linear"]["x"] > 0.05:
            moving.set()

    sub = session.declare_subscriber(key(0, "/odom", ODOM), odom)
    proc = omnican("drive", "--sim", "--vx", "0.1", "--duration", "600", "--zenoh",
                   "--zenoh-mode", "client", "--zenoh-connect", router)
    try:
        assert moving.wait(TIMEOUT_S), proc.lines
        other = bytes(range(50, 66))
        with publishing(session, "/cmd_vel", -0.3, other):
            refused = proc.read_until(lambda text: "the scripted motion is driving" in text,
                                      TIMEOUT_S)
        assert refused is not None and f"cmd_vel from Zenoh cmd_vel publisher {other.hex()} " \
            "ignored: the scripted motion is driving" in refused, proc.lines
        node = rmw.RosNode(0, "0", 0, "omnican", namespace="/")
        gid = bytes(range(16))
        replies = session.get(service_key(node, "stop"), payload=b"\x00\x01\x00\x00\x00",
                              attachment=rmw.Attachment(1, 0, gid).encode(),
                              timeout=TIMEOUT_S)
        answers = [r for r in replies if r.ok is not None]
        assert len(answers) == 1
        code, out = proc.finish(timeout=TIMEOUT_S)
        assert code == 1, out
        assert f"omnican: error: base stopped: stopped by {SOURCE} {gid.hex()}" in out, out
    finally:
        sub.undeclare()
        proc.kill()


def test_sim_zenoh_publishes_the_true_pose(router: str, session: Any) -> None:
    got, sub = received(session, key(0, "/robot1/sim/true_pose",
                                      "geometry_msgs/msg/PoseStamped"))
    proc = omnican("sim", "--serve", "127.0.0.1:0", "--zenoh", "--zenoh-mode", "client",
                   "--zenoh-connect", router, "--namespace", "/robot1")
    try:
        line = proc.read_until(lambda text: text.startswith("Zenoh node"), TIMEOUT_S)
        assert line is not None, proc.lines
        assert line.startswith("Zenoh node /robot1/omnican_sim on domain 0 (")
        assert line.endswith(": out /robot1/sim/true_pose 50 Hz")
        assert got.wait(TIMEOUT_S)
        tokens = {str(r.ok.key_expr) for r in
                  session.liveliness().get("@ros2_lv/**", timeout=10.0) if r.ok}
        assert any("/NN/%/%robot1/omnican_sim" in t for t in tokens), tokens
        proc.send("quit")
        code, out = proc.finish(timeout=TIMEOUT_S)
        assert code == 0 and "simulator stopped" in out, out
    finally:
        sub.undeclare()
        proc.kill()


def test_ros2_zenoh_puts_the_same_node_on_both() -> None:
    """One ROS graph serves both: ros2's --namespace and --domain-id place the Zenoh
    node too. DDS runs, so everything runs in a network namespace holding only loopback
    (skipped where none can be made): omnican ros2 listens for Zenoh there, and a peer
    in the same namespace hears its odometry on domain 96's key."""
    pytest.importorskip("cyclonedds")
    from tests.interop.ros2_interop.harness import NetNs, netns_unavailable

    why = netns_unavailable()
    if why:
        pytest.skip(why)
    endpoint = "tcp/127.0.0.1:7447"  # the namespace's own loopback: nothing else there
    peer = f"""
import threading
from omnican.zenoh import rmw
from tests.zenoh.conftest import client
s = client({endpoint!r})
got = threading.Event()
odom = "nav_msgs/msg/Odometry"
sub = s.declare_subscriber(rmw.data_key(96, "/robot2/odom", odom, rmw.type_hash(odom)),
                           lambda sample: got.set())
print("got" if got.wait(120) else "nothing", flush=True)
sub.undeclare()
s.close()
"""
    with NetNs() as ns:
        proc = Proc(ns.wrap([sys.executable, "-m", "omnican", "ros2", "--sim", "--localhost",
                             "--domain-id", "96", "--namespace", "/robot2", "--zenoh",
                             "--zenoh-listen", endpoint]), env=dict(os.environ))
        watcher = None
        try:
            assert proc.read_until(lambda text: "Ctrl-C to stop" in text, TIMEOUT_S), \
                proc.lines
            assert any(text.startswith("Zenoh node /robot2/omnican on domain 96 (")
                       for text in proc.lines), proc.lines
            assert any(text.startswith("ROS 2 node /robot2/omnican on DDS domain 96")
                       for text in proc.lines), proc.lines
            watcher = Proc(ns.wrap([sys.executable, "-c", peer]), env=dict(os.environ))
            assert watcher.read_until(lambda text: text in ("got", "nothing"),
                                      TIMEOUT_S) == "got", watcher.lines
            proc.send("quit")
            code, out = proc.finish(timeout=TIMEOUT_S)
            assert code == 0 and "drives disabled" in out, out
        finally:
            if watcher is not None:
                watcher.kill()
            proc.kill()


def test_teleop_shows_a_zenoh_publisher_driving(router: str, session: Any) -> None:
    """teleop --zenoh in a terminal: a cmd_vel publisher on Zenoh drives the base through
    the arbiter the keys share, and the dashboard says who drives."""
    from tests.support.terminal import Pty

    term = Pty("teleop", "--sim", "--zenoh", "--zenoh-mode", "client", "--zenoh-connect",
               router, "--namespace", "/robot3")
    gid = bytes(range(32, 48))
    try:
        term.wait_for_frame("Zenoh /robot3/omnican", timeout=TIMEOUT_S)
        with publishing(session, "/robot3/cmd_vel", 0.1, gid):
            term.wait_for_frame(f"Zenoh cmd_vel publisher {gid.hex()} is driving",
                                timeout=TIMEOUT_S)

        def let_go() -> bool:  # the arbiter's timeout after its last sample
            term.read(0.1)
            return "is driving" not in "\n".join(term.frame()) or term.proc.poll() is not None

        assert wait_real(let_go, TIMEOUT_S)
        term.keys("\x1b")  # Esc quits
        assert term.exit_code(TIMEOUT_S) == 0, term.read()
        assert "pose x=" in term.read()
    finally:
        term.close()
