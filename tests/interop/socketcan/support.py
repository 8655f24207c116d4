"""Processes and interfaces for the SocketCAN tests: ``omnican sim`` on a vcan interface,
a host program driving the base through the Chassis API, and the interface itself
(down/up, a transmit queue that fills).

Everything runs in separate processes talking over a real kernel CAN interface, as on
a robot. The guest these tests usually run in (tools/socketcan-tests) emulates its CPU,
about 14x slower than the host: waits are generous and every check is about what
happened, never about how fast."""

from __future__ import annotations

import json
import math
import os
import re
import select
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

from omnican.core.odometry import Pose2D
from tests.support.helpers import wait_for

ROOT = Path(__file__).resolve().parents[3]
HOST = Path(__file__).with_name("host.py")

# Python under emulation imports omnican in ~10 s; opening the base adds SDO round trips.
START_S = 120.0
REPLY_S = 60.0
STILL_MM = 1.0  # the truth moved less than this (mm) over a still window: the base stands

RUNNER_HINT = "run tools/socketcan-tests, which boots a Linux guest with SocketCAN"


def vcan_problem(channel: str) -> str | None:
    """Why ``channel`` cannot carry these tests here, or None when it can."""
    if not sys.platform.startswith("linux"):
        return f"SocketCAN needs Linux: {RUNNER_HINT}"
    sysfs = Path("/sys/class/net") / channel
    if not sysfs.exists():
        return f"no {channel} here: {RUNNER_HINT}"
    try:
        kind = int((sysfs / "type").read_text())
        flags = int((sysfs / "flags").read_text(), 16)
    except (OSError, ValueError) as exc:
        return f"cannot read {sysfs}: {exc}"
    if kind != 280:  # ARPHRD_CAN
        return f"{channel} is not a CAN interface"
    if not flags & 0x1:  # IFF_UP
        return f"{channel} is down (ip link set {channel} up)"
    return None


def admin_problem() -> str | None:
    """Why the interface cannot be taken down or given a qdisc here, or None."""
    if os.geteuid() != 0:
        return f"needs root to change the interface: {RUNNER_HINT}"
    if shutil.which("ip") is None or shutil.which("tc") is None:
        return "needs iproute2 (ip, tc) to change the interface"
    return None


def sh(*argv: str) -> None:
    """Run an administrative command (ip, tc); fail loudly if it fails."""
    done = subprocess.run(argv, capture_output=True, text=True, timeout=60, check=False)
    if done.returncode != 0:
        raise AssertionError(f"{' '.join(argv)} failed ({done.returncode}): {done.stderr}")


def write_config(path: Path, channel: str) -> Path:
    """The demo base (three bundled drives, nodes 1-3) on ``channel``, slow enough for
    an emulated CPU: 50 Hz, a 2 s heartbeat timeout both ways, 2 s SDO timeouts."""
    wheels = "".join(f"[[wheel]]\nnode_id = {n}\ngear_ratio = 16\nencoder_cpr = 4096\n"
                     "wheel_radius = 0.05\n\n" for n in (1, 2, 3))
    path.write_text(
        f'[bus]\ninterface = "socketcan"\nchannel = "{channel}"\n\n'
        '[chassis]\nlayout = "b21"\nbase_radius = 0.19\nrate_hz = 50\ncmd_timeout_s = 1.0\n'
        "heartbeat_ms = 200\nheartbeat_timeout_factor = 10\nsdo_timeout_s = 2.0\n"
        "boot_timeout_s = 5.0\nenable_timeout_s = 5.0\n\n" + wheels)
    return path


def env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1"}


class Lines:
    """Lines from a child's stdout, with a timeout (select on the pipe; no thread)."""

    def __init__(self, stream: IO[bytes], what: str) -> None:
        self.fd = stream.fileno()
        self.what = what
        self.buffer = b""

    def next(self, timeout: float) -> str | None:
        """The next line, or None at end of file. Raises AssertionError on timeout."""
        end = time.monotonic() + timeout
        while b"\n" not in self.buffer:
            left = end - time.monotonic()
            if left <= 0:
                raise AssertionError(f"{self.what}: no line within {timeout:g} s "
                                     f"(so far {self.buffer[-500:]!r})")
            ready, _, _ = select.select([self.fd], [], [], left)
            if not ready:
                continue
            chunk = os.read(self.fd, 65536)
            if not chunk:
                if self.buffer:
                    line, self.buffer = self.buffer, b""
                    return line.decode()
                return None
            self.buffer += chunk
        line, self.buffer = self.buffer.split(b"\n", 1)
        return line.decode()


class Child:
    """A child process with stdin/stdout pipes and stderr in a file."""

    def __init__(self, argv: list[str], log: Path, what: str) -> None:
        self.what = what
        self.log = log
        with log.open("wb") as err:
            self.proc = subprocess.Popen(argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                         stderr=err, env=env(), cwd=ROOT)
        assert self.proc.stdout is not None
        self.lines = Lines(self.proc.stdout, what)

    def say(self, text: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(text.encode() + b"\n")
        self.proc.stdin.flush()

    def stderr(self) -> str:
        return self.log.read_text(errors="replace")

    def read_until(self, pred: Callable[[str], bool], timeout: float) -> str:
        end = time.monotonic() + timeout
        while True:
            line = self.lines.next(max(0.0, end - time.monotonic()))
            if line is None:
                raise AssertionError(f"{self.what} ended (status {self.proc.wait()}); "
                                     f"stderr:\n{self.stderr()[-3000:]}")
            if pred(line):
                return line

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(timeout=30)
        for stream in (self.proc.stdin, self.proc.stdout):
            if stream is not None:
                try:
                    stream.close()
                except OSError:  # a pipe whose reader is gone
                    pass


_POSE = re.compile(r"true pose x=(\S+) y=(\S+) theta=(\S+)")


class SimProcess(Child):
    """``omnican sim -i socketcan -c CHANNEL`` with its stdin commands."""

    def __init__(self, toml: Path, channel: str, log: Path) -> None:
        super().__init__([sys.executable, "-m", "omnican", "sim", "--config", str(toml),
                          "-i", "socketcan", "-c", channel], log, f"omnican sim on {channel}")
        first = self.read_until(lambda line: bool(line.strip()), START_S)
        assert first.startswith("serving simulated nodes 1 (omnican_wheel.eds), 2"), first
        assert f"channel={channel}" in first, first

    def command(self, text: str, reply_prefix: str) -> str:
        self.say(text)
        return self.read_until(lambda line: line.startswith(reply_prefix), REPLY_S)

    def pose(self) -> Pose2D:
        line = self.command("pose", "true pose ")
        m = _POSE.fullmatch(line.strip())
        assert m is not None, line
        return Pose2D(float(m[1]), float(m[2]), float(m[3]))

    def still(self, window_s: float = 0.5) -> bool:
        """The simulated base stands still: its true pose does not change over a window."""
        p0 = self.pose()
        time.sleep(window_s)
        return moved_mm(p0, self.pose()) < STILL_MM

    def moving(self, window_s: float = 0.5) -> bool:
        p0 = self.pose()
        time.sleep(window_s)
        return moved_mm(p0, self.pose()) > 5 * STILL_MM

    def healthy(self) -> bool:
        return self.proc.poll() is None

    def close(self) -> int:
        """Quit the simulator; returns its exit status."""
        try:
            if self.proc.poll() is None:
                self.say("quit")
                self.read_until(lambda line: line == "simulator stopped", REPLY_S)
            return self.proc.wait(timeout=REPLY_S)
        finally:
            self.kill()


def moved_mm(p0: Pose2D, p1: Pose2D) -> float:
    """How far the base moved between two poses (mm; a turn counts at the wheel radius)."""
    return 1000.0 * max(math.hypot(p1.x - p0.x, p1.y - p0.y), abs(p1.theta - p0.theta) * 0.19)


class HostProcess(Child):
    """tests/interop/socketcan/host.py: the Chassis API in a process of its own."""

    def __init__(self, toml: Path, log: Path, *extra: str) -> None:
        super().__init__([sys.executable, str(HOST), str(toml), *extra], log, "host")
        line = self.read_until(lambda line: line.startswith("{"), START_S)
        reply = json.loads(line)
        if not reply.get("ready"):
            raise AssertionError(f"host did not start: {reply}; stderr:\n{self.stderr()[-3000:]}")
        self.ready = reply

    def request(self, text: str) -> dict[str, Any]:
        self.say(text)
        reply: dict[str, Any] = json.loads(self.read_until(lambda line: line.startswith("{"),
                                                           REPLY_S))
        return reply

    def status(self) -> dict[str, Any]:
        return self.request("status")

    def pose(self) -> Pose2D:
        p = self.status()["pose"]
        return Pose2D(p["x"], p["y"], p["theta"])

    def close(self) -> int:
        """Leave the ``with`` block (stop, disable, release the bus); the exit status."""
        try:
            if self.proc.poll() is None:
                self.say("quit")
            return self.proc.wait(timeout=START_S)
        finally:
            self.kill()


def wait_until(pred: Callable[[], bool], timeout: float) -> bool:
    """``pred`` within ``timeout``, asked every 0.2 s (each ask may be a round trip)."""
    return wait_for(pred, timeout, step=0.2)


def pose_problem(odometry: Pose2D, truth: Pose2D) -> str | None:
    """Odometry against ground truth: within a centimetre plus 3 % of the path and
    0.03 rad, or what is wrong."""
    path = math.hypot(truth.x, truth.y)
    if (math.hypot(odometry.x - truth.x, odometry.y - truth.y) < 0.01 + 0.03 * path
            and abs(odometry.theta - truth.theta) < 0.03):
        return None
    return f"odometry {odometry} vs truth {truth}"


def assert_pose_close(odometry: Pose2D, truth: Pose2D, what: str) -> None:
    problem = pose_problem(odometry, truth)
    assert problem is None, f"{what}: {problem}"


def settled(host: HostProcess, sim: SimProcess, timeout: float = 30.0) -> tuple[Pose2D, Pose2D]:
    """(true pose, odometry) once both stand still: a start for relative comparisons."""

    def calm() -> bool:
        before = host.pose()
        return sim.still(0.5) and moved_mm(before, host.pose()) < STILL_MM

    assert wait_until(calm, timeout), f"never settled: {host.status()}"
    return sim.pose(), host.pose()


def assert_odometry_reaches_truth(host: HostProcess, sim: SimProcess, odo0: Pose2D,
                                  start: Pose2D, what: str, timeout: float = 30.0) -> None:
    """With the base standing still, the host's odometry (relative to ``odo0``) reaches
    the true displacement since ``start``: its last samples may still be on their way
    under emulation, but it must get there, and stay there."""
    truth = sim.pose().relative_to(start)
    last: dict[str, Any] = {}

    def reached() -> bool:
        last.update(host.status())
        p = last["pose"]
        return pose_problem(Pose2D(p["x"], p["y"], p["theta"]).relative_to(odo0), truth) is None

    if not wait_until(reached, timeout):
        p = last["pose"]
        raise AssertionError(
            f"{what}: {pose_problem(Pose2D(p['x'], p['y'], p['theta']).relative_to(odo0), truth)}"
            f" after {timeout:g} s still; last SYNC {last.get('sync_epoch')}, samples filed "
            f"under {last.get('sample_epochs')}, wheels "
            f"{[(w['node_id'], w['state'], w['online'], w.get('stale')) for w in last['wheels']]}")


def no_traceback(text: str, what: str) -> None:
    assert "Traceback" not in text, f"{what} printed a traceback:\n{text[-4000:]}"


def next_frame(channel: str, cob_id: int, timeout: float = REPLY_S) -> bytes | None:
    """The data of the next frame with ``cob_id`` on ``channel`` (None if none comes)."""
    import can

    with can.Bus(interface="socketcan", channel=channel,
                 can_filters=[{"can_id": cob_id, "can_mask": 0x7FF}]) as bus:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            msg = bus.recv(timeout=max(0.0, end - time.monotonic()))
            if msg is not None and msg.arbitration_id == cob_id:
                return bytes(msg.data)
    return None


NMT_OPERATIONAL, NMT_PRE_OPERATIONAL = 0x05, 0x7F


def nmt_states(channel: str) -> dict[int, int | None]:
    """Each drive's NMT state from its next heartbeat (None: no heartbeat)."""
    out: dict[int, int | None] = {}
    for node in (1, 2, 3):
        data = next_frame(channel, 0x700 + node, 10.0)
        out[node] = data[0] & 0x7F if data else None
    return out
