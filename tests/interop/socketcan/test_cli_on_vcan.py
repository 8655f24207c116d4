"""The omnican commands on a real kernel CAN interface, against ``omnican sim`` running
in another process on the same vcan0: drive (JSON, recording), teleop in a terminal,
scan and monitor."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import time
from pathlib import Path

import can
import pytest

from omnican.core.odometry import Pose2D
from tests.cli.test_cli import Pty
from tests.interop.socketcan.support import (
    START_S,
    HostProcess,
    SimProcess,
    assert_pose_close,
    env,
    no_traceback,
)

pytestmark = pytest.mark.socketcan


def omnican(*argv: str, timeout: float = 4 * START_S) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "omnican", *argv], capture_output=True,
                          text=True, env=env(), timeout=timeout, check=False)


@pytest.mark.usefixtures("no_host")
def test_drive_moves_the_base_and_records_the_bus(sim: SimProcess, toml: Path,
                                                  tmp_path: Path) -> None:
    start = sim.pose()
    log = tmp_path / "run.log"
    done = omnican("drive", "--config", str(toml), "-i", "socketcan", "-c", "vcan0",
                   "--vx", "0.2", "--wz", "0.3", "--duration", "2", "--json", "--record", str(log))
    assert done.returncode == 0, done.stderr
    no_traceback(done.stderr, "omnican drive")
    result = json.loads(done.stdout)
    odometry = Pose2D(**result["pose"])
    truth = sim.pose().relative_to(start)
    assert truth.x > 0.2 and truth.theta > 0.3  # it really drove, and turned
    assert_pose_close(odometry, truth, "omnican drive")

    # The recording holds both directions of the run, read back with python-can.
    frames = list(can.LogReader(str(log)))
    ids = {f.arbitration_id for f in frames}
    assert 0x080 in ids  # SYNC
    assert {0x701, 0x702, 0x703, 0x77F} <= ids  # the drives' heartbeats and the host's
    assert {0x181, 0x182, 0x183} & ids or {0x281, 0x282, 0x283} & ids  # samples from drives
    for node in (1, 2, 3):  # the host's targets: an RPDO (0x200-0x500 + node) to each drive
        assert any(f.arbitration_id in (0x200 + node, 0x300 + node, 0x400 + node, 0x500 + node)
                   for f in frames), f"no RPDO to node {node} recorded"


@pytest.mark.usefixtures("no_host")
def test_teleop_drives_from_the_keyboard(sim: SimProcess, toml: Path) -> None:
    start = sim.pose()
    term = Pty("--config", str(toml))
    try:
        term.wait_for("RUNNING", timeout=START_S)
        # Hold 'i' (forward), as key repeat would, until the base has covered ground (as
        # a user holds the key until it moves: the emulated guest beside CPU hogs may take
        # longer than any fixed hold to start; the moving base stops soon after release).
        deadline = time.monotonic() + 90.0
        covered, look = 0.0, time.monotonic() + 0.5
        while covered <= 0.12 and time.monotonic() < deadline:
            term.keys("i")
            term.read(0.05)
            if time.monotonic() >= look:
                covered, look = sim.pose().relative_to(start).x, time.monotonic() + 0.5
        assert covered > 0.12, f"the base covered {covered:.3f} m while 'i' was held 90 s"
        term.wait_for("last key 'i'", timeout=30)
        term.keys("\x1b")  # Esc quits
        assert term.exit_code(timeout=START_S) == 0, term.read(0.5)[-3000:]
        screen = term.read(0.5)
        no_traceback(screen, "omnican teleop")
        final = [line for line in screen.strip().splitlines() if line.strip()][-1]
        match = re.fullmatch(r"pose x=(\S+) y=(\S+) theta=(\S+)", final.strip())
        assert match is not None, final
        odometry = Pose2D(float(match[1]), float(match[2]), float(match[3]))
    finally:
        term.close()
    truth = sim.pose().relative_to(start)
    assert truth.x > 0.1
    assert_pose_close(odometry, truth, "omnican teleop")


@pytest.mark.usefixtures("no_host")
def test_scan_finds_the_simulated_nodes(sim: SimProcess, toml: Path) -> None:
    done = omnican("scan", "--config", str(toml), "--listen", "2", "--sdo-timeout", "1")
    assert done.returncode == 0, done.stdout + done.stderr
    no_traceback(done.stderr, "omnican scan")
    assert "3 node(s) found; 0 configured node(s) missing" in done.stdout
    for node in (1, 2, 3):
        row = next((line for line in done.stdout.splitlines()
                    if re.match(rf"\W*{node}\W", line)), None)
        assert row is not None, done.stdout
        assert "0x00020192" in row and "ok" in row, row  # CiA 402 device type, no complaint


def test_monitor_decodes_a_driving_base(sim: SimProcess, toml: Path,
                                       host: HostProcess) -> None:
    host.request("drive 0.1 0 0.4")
    try:
        done = omnican("monitor", "--config", str(toml), "-i", "socketcan", "-c", "vcan0",
                       "--duration", "6", "--interval", "3")
    finally:
        host.request("hold")
    assert done.returncode == 0, done.stderr
    no_traceback(done.stderr, "omnican monitor")
    summary = done.stdout.split("omnican monitor (summary")[-1]
    assert "on socketcan vcan0" in summary
    rows = {line.split()[0]: line for line in summary.splitlines() if line.startswith("0x")}
    for cob in ("0x080", "0x77F", "0x701", "0x702", "0x703"):
        assert cob in rows, summary
    assert "NmtState=operational" in rows["0x77F"]
    # Targets decoded through the config's database, and non-zero while it drives.
    targets = [line for line in rows.values() if "TargetVelocity=" in line]
    assert len(targets) >= 3, summary
    assert any(not re.search(r"TargetVelocity=0 ", line) for line in targets), summary
    assert "bus load:" in summary and "total:" in summary
