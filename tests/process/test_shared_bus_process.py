"""The shared bus across processes: the simulated drives in this process behind a
loopback hub, omnican in another, and this process as the other devices on the bus
(another master, a battery management system with 29-bit ids, a cloned drive)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import can
import canopen
import pytest

from omnican.protocol.cia301 import NMT_COB_ID, NmtCommand
from omnican.protocol.cia402 import State
from omnican.sim import SimulatedBase, SimulatedDrive
from tests.support.helpers import one_error_line, still, wait_for

HOST = Path(__file__).resolve().parents[1] / "support" / "host_process.py"
ROOT = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}


@pytest.fixture
def other(channel: str) -> Iterator[can.BusABC]:
    """Another device on the drives' side of the hub."""
    with can.Bus(interface="virtual", channel=channel) as bus:
        yield bus


def omnican(*args: str, timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "omnican", *args], capture_output=True,
                          text=True, timeout=timeout, env=ENV, check=False)


@pytest.fixture
def host(served: tuple[SimulatedBase, Path]) -> Iterator[subprocess.Popen[str]]:
    """A program that keeps commanding 0.3 m/s forward until it is signalled."""
    _, toml = served
    proc = subprocess.Popen([sys.executable, str(HOST), str(toml)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=ENV)
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == "ready", proc.stderr and proc.stderr.read()
        yield proc
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.communicate(timeout=10)


def test_another_masters_nmt_stop_and_start_move_nothing(
        served: tuple[SimulatedBase, Path], host: subprocess.Popen[str],
        other: can.BusABC) -> None:
    sim, _ = served
    assert wait_for(lambda: sim.true_twist.vx > 0.2, 5.0)
    other.send(can.Message(arbitration_id=NMT_COB_ID, data=[NmtCommand.STOP, 0],
                           is_extended_id=False))
    assert wait_for(lambda: still(sim), 3.0)
    time.sleep(0.5)
    other.send(can.Message(arbitration_id=NMT_COB_ID, data=[NmtCommand.START, 0],
                           is_extended_id=False))
    start = sim.true_pose
    time.sleep(1.5)  # the host still commands 0.3 m/s all this while
    assert sim.true_pose.distance_to(start) < 0.002
    assert all(d.state() is not State.OPERATION_ENABLED for d in sim.drives)
    host.send_signal(signal.SIGINT)
    _, err = host.communicate(timeout=15)
    assert host.returncode == 130, err
    assert "another master sent NMT stop to all nodes" in err
    assert all(d.state() is State.SWITCH_ON_DISABLED for d in sim.drives)


def test_29_bit_frames_from_another_device_change_nothing(
        served: tuple[SimulatedBase, Path], other: can.BusABC) -> None:
    sim, toml = served
    # A BMS whose 29-bit ids equal node 1's TPDOs, node 2's EMCY and node 3's boot-up.
    frames = [can.Message(arbitration_id=i, data=d, is_extended_id=True)
              for i, d in ((0x181, b"\x08\x00\x00\x10\x23"), (0x281, b"\xff\xff\xff\x7f"),
                           (0x082, b"\x10\x23\x01\x00\x00\x00\x00\x00"), (0x703, b"\x00"))]
    tasks = [other.send_periodic(f, 0.005) for f in frames]
    try:
        result = omnican("drive", "--config", str(toml), "--vx", "0.2", "--duration", "2",
                         "--json")
    finally:
        for task in tasks:
            task.stop()
    assert result.returncode == 0, result.stderr
    out = json.loads(result.stdout)
    assert wait_for(lambda: still(sim), 2.0)
    assert out["pose"]["x"] == pytest.approx(sim.true_pose.x, abs=0.01)
    assert out["pose"]["x"] > 0.2


def test_a_failed_open_leaves_every_drive_disabled(served: tuple[SimulatedBase, Path]) -> None:
    sim, toml = served
    # The point is what a failed open leaves: a stall of either process beside busy ones
    # must not cost a drive the host's heartbeat first (seen once at the default factor).
    toml.write_text(toml.read_text().replace('layout = "b21"',
                                             'layout = "b21"\nheartbeat_timeout_factor = 10.0'))
    sim.drives[2].hold_switched_on()  # node 3 will not enable
    result = omnican("drive", "--config", str(toml), "--vx", "0.2", "--duration", "1")
    assert result.returncode == 1
    line = one_error_line(result.stderr)
    assert "node 3" in line and "SWITCHED ON" in line, line
    assert [d.state() for d in sim.drives[:2]] == [State.SWITCH_ON_DISABLED] * 2
    assert still(sim)


def test_two_devices_on_one_node_id_are_refused(served: tuple[SimulatedBase, Path],
                                                 channel: str) -> None:
    sim, toml = served
    net = canopen.Network()
    net.connect(interface="virtual", channel=channel)
    twin = SimulatedDrive(net, 2)  # a cloned drive
    try:
        result = omnican("drive", "--config", str(toml), "--vx", "0.2", "--duration", "1")
    finally:
        twin.close()
        net.disconnect()
    assert result.returncode == 1
    line = one_error_line(result.stderr)
    assert "two devices answer as node 2" in line, line
    assert all(d.state() is not State.OPERATION_ENABLED for d in sim.drives)
