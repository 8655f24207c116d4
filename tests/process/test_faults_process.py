"""Fault paths across processes: a second signal during the stop, and the simulator
process (the other end of the bus) killed and restarted under a connected host."""

from __future__ import annotations

import json
import os
import re
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import ClassVar

import pytest

from omnican import Chassis, DriveError, default_config, load_config
from omnican.protocol.cia402 import State
from omnican.record.replay import load as load_recording
from omnican.sim import SimulatedBase
from tests.support.helpers import drive_for, still, wait_for
from tests.support.terminal import Pty

HOST = Path(__file__).resolve().parents[1] / "support" / "host_process.py"
ROOT = Path(__file__).resolve().parents[2]




# ---------------------------------------------------------------- a second signal


@pytest.mark.parametrize(("first", "second", "delay_s"), [
    (signal.SIGINT, signal.SIGINT, 0.01),
    (signal.SIGINT, signal.SIGINT, 0.1),
    (signal.SIGTERM, signal.SIGTERM, 0.05),  # what `timeout` does: the child, then its group
    (signal.SIGINT, signal.SIGTERM, 0.03),
])
def test_a_second_signal_does_not_cut_the_stop_short(
        served: tuple[SimulatedBase, Path], tmp_path: Path, first: signal.Signals,
        second: signal.Signals, delay_s: float) -> None:
    sim, toml = served
    record = tmp_path / "run.log"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, str(HOST), str(toml), str(record)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == "ready"
        assert wait_for(lambda: sim.true_twist.vx > 0.2, 3.0)
        proc.send_signal(first)
        time.sleep(delay_s)
        proc.send_signal(second)
        _, err = proc.communicate(timeout=15)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate(timeout=5)
    assert proc.returncode == (130 if first == signal.SIGINT else 128 + first), err
    assert "Traceback" not in err
    # The stop ran to its end: drives disabled by the host (the recording shows it, and
    # they were taken out of OPERATIONAL), the last target sent to every wheel was zero.
    assert all(d.state() is State.SWITCH_ON_DISABLED for d in sim.drives)
    assert all(d.nmt_state == "PRE-OPERATIONAL" for d in sim.drives)
    assert still(sim)
    rep = load_recording(record, load_config(toml))
    assert all(len(t) and t[-1] == 0.0 for t in rep.target_speed)
    assert all(track.changes[-1].state is State.SWITCH_ON_DISABLED for track in rep.stages)


# ---------------------------------------------------------------- simulator killed


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class SimProcess:
    """``omnican sim`` serving a loopback hub on ``port``, in a process of its own
    (``args``: more of its arguments, e.g. a config)."""

    started: ClassVar[list[SimProcess]] = []  # killed after each test whatever happened

    def __init__(self, port: int, *args: str) -> None:
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "omnican", "sim", "--serve", f"127.0.0.1:{port}", *args],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            env=env)
        SimProcess.started.append(self)
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        if "serving simulated nodes" not in line:
            self.kill()
            pytest.fail(f"omnican sim did not start: {line!r}")
        while line and not line.startswith("type a command"):  # the rest of the banner
            line = self.proc.stdout.readline()

    def command(self, line: str) -> str:
        """A console command; returns its reply line."""
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()
        return self.proc.stdout.readline()

    def true_x(self) -> float:
        match = re.search(r"x=(\S+)", self.command("pose"))
        return float(match[1]) if match else 0.0

    def kill(self) -> None:
        if self.proc.returncode is not None and self.proc.stdout is None:
            return  # already killed and reaped
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.communicate(timeout=5)
        self.proc.stdout = self.proc.stderr = self.proc.stdin = None


@pytest.fixture
def port() -> Iterator[int]:
    yield free_port()
    while SimProcess.started:  # no simulator outlives its test
        SimProcess.started.pop().kill()


def test_simulator_killed_and_restarted_under_a_connected_base(port: int) -> None:
    cfg = default_config(bus={"interface": "remote", "channel": f"ws://127.0.0.1:{port}/"})
    sim = SimProcess(port)
    try:
        with Chassis.open(cfg) as base:
            drive_for(base, 0.4, vx=0.3)
            assert base.twist.vx > 0.2
            sim.kill()
            assert wait_for(lambda: not base.status.bus_up, 1.0)
            st = base.status
            assert (st.stopped_reason or "").startswith("CAN bus down")
            assert st.bus_error
            assert base.twist.vx == 0.0 and all(w.actual_speed == 0.0 for w in base.wheels)
            assert all(w.stale for w in base.wheels)
            sim = SimProcess(port)  # the other end comes back
            assert wait_for(lambda: base.status.bus_up, 5.0)
            # Re-configured drives, started again. Beside busy processes a drive's boot-up
            # can reach the host late and stop the base once more ("node 1 rebooted"):
            # a program then recovers again, as an operator presses r again.
            for _ in range(3):
                try:
                    base.recover()
                    break
                except DriveError:
                    continue
            assert base.status.enabled
            x0 = base.pose.x
            drive_for(base, 0.5, vx=0.3)
            assert base.twist.vx > 0.2 and base.pose.x > x0 + 0.08
    finally:
        sim.kill()


def test_teleop_survives_the_simulator_being_killed_and_restarted(port: int) -> None:
    sim = SimProcess(port)
    term = Pty("teleop", "-i", "remote", "-c", f"ws://127.0.0.1:{port}/")
    try:
        term.wait_for("RUNNING")
        end = time.monotonic() + 0.6
        while time.monotonic() < end:
            term.keys("i")
            term.read(0.05)
        sim.kill()
        term.wait_for("CAN bus down")
        sim = SimProcess(port)
        term.wait_for("configuring every drive again", timeout=10)
        # What an operator does: r, and r again if a recover says it failed (beside busy
        # processes a stalled simulator once missed the host's heartbeat in its first).
        for _ in range(3):
            term.keys("r")
            term.screen = ""
            shown = term.wait_for_any(("RUNNING", "recover failed"), timeout=15)
            if shown == "RUNNING":
                break
        else:
            raise AssertionError("three recovers failed: " + term.screen[-2000:])
        end = time.monotonic() + 0.8
        while time.monotonic() < end:
            term.keys("i")
            term.read(0.05)
        term.keys("\x1b")
        assert term.exit_code() == 0
        out = term.read(0.5)
        assert "Traceback" not in out and "Exception ignored" not in out, out[-2000:]
        match = re.search(r"pose x=(\S+) y=\S+ theta=\S+", out)
        assert match is not None and float(match[1]) > 0.1
    finally:
        term.close()
        sim.kill()


# ---------------------------------------------------------------- drive --json on failure


def test_drive_json_reports_a_failure_as_json(port: int) -> None:
    """A script reading ``omnican drive --json`` gets JSON when the run fails too: here
    a fault injected in the simulator process while the base drives."""
    sim = SimProcess(port)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    try:
        drive = subprocess.Popen(
            [sys.executable, "-m", "omnican", "drive", "-i", "remote", "-c",
             f"ws://127.0.0.1:{port}/", "--vx", "0.2", "--duration", "5", "--json"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        assert wait_for(lambda: sim.true_x() > 0.02, 15.0, step=0.1)  # up and driving
        sim.command("fault 2")
        out, err = drive.communicate(timeout=20)
    finally:
        sim.kill()
    assert drive.returncode == 1, err
    result = json.loads(out)
    assert result["error"].startswith("base stopped: node 2 fault")
    assert result["pose"]["x"] > 0.0
    assert "Traceback" not in err


def test_drive_json_reports_no_drive_on_the_bus_as_json(channel: str) -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.run(
        [sys.executable, "-m", "omnican", "drive", "-i", "virtual", "-c", channel, "--vx", "0.1",
         "--json"], check=False, capture_output=True, text=True, env=env, timeout=30)
    assert proc.returncode == 1
    result = json.loads(proc.stdout)
    assert "no drive answered" in result["error"] and result["pose"] is None
