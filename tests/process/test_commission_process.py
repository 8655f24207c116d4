"""Commissioning across processes (issue 38): ``omnican sim`` serving three drives without
node ids (FFh, one vendor and product) in one process, ``omnican commission`` in another
gives them the node ids the config names for their serials; the simulator's power cycle
brings them back with those ids, ``omnican scan`` finds nothing that disagrees, and
``omnican drive`` drives."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.process.test_faults_process import SimProcess, free_port

ROOT = Path(__file__).resolve().parents[2]

SERIALS = {1: 0x0C0FFEE3, 2: 0x0C0FFEE1, 3: 0x0C0FFEE2}


def robot_toml(tmp_path: Path) -> Path:
    wheels = "".join(f"[[wheel]]\nnode_id = {n}\nserial = {s}\ngear_ratio = 16\n"
                     "encoder_cpr = 4096\nwheel_radius = 0.05\n\n" for n, s in SERIALS.items())
    toml = tmp_path / "robot.toml"
    toml.write_text(f'[chassis]\nlayout = "b21"\nbase_radius = 0.19\n\n{wheels}')
    return toml


@pytest.fixture
def port() -> Iterator[int]:
    yield free_port()
    while SimProcess.started:  # no simulator outlives its test
        SimProcess.started.pop().kill()


def omnican(*argv: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-m", "omnican", *argv], check=False,
                          capture_output=True, text=True, env=env, timeout=120)


def test_unconfigured_drives_in_another_process_are_commissioned_and_then_drive(
        port: int, tmp_path: Path) -> None:
    toml = robot_toml(tmp_path)
    bus = ["-i", "remote", "-c", f"ws://127.0.0.1:{port}/"]
    sim = SimProcess(port, "--config", str(toml), "--unconfigured")
    # Nothing answers as a node before: a scan finds none of the config's.
    before = omnican("scan", "--config", str(toml), *bus)
    assert before.returncode == 1
    assert "0 node(s) found; 3 configured node(s) missing" in before.stdout

    done = omnican("commission", str(toml), *bus, "--lss-timeout", "0.3")
    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr
    rows = {line.split("│")[1].strip(): line.split("│")[4].strip()
            for line in done.stdout.splitlines() if line.count("│") == 7}
    assert rows == {f"0x{s:08X}": str(n) for n, s in SERIALS.items()}

    reply = sim.command("power")
    assert reply.strip() == ("power cycled: " + ", ".join(
        f"serial 0x{s:08X} node {n}" for n, s in sorted(SERIALS.items())))

    scan = omnican("scan", "--config", str(toml), *bus)
    assert scan.returncode == 0, scan.stdout + scan.stderr
    assert "3 node(s) found; 0 configured node(s) missing" in scan.stdout
    for serial in SERIALS.values():
        assert f"0x{serial:08X}" in scan.stdout

    drove = omnican("drive", "--config", str(toml), *bus, "--vx", "0.2", "--duration", "1",
                    "--json")
    assert drove.returncode == 0, drove.stderr
    assert json.loads(drove.stdout)["pose"]["x"] > 0.05
