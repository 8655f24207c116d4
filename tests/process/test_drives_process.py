"""Drives omnican did not write (issue 36, items 2-4), across processes: ``omnican sim``
in one process, its drives made to behave as such drives do from its console, and
``omnican drive`` in another."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.process.test_faults_process import SimProcess, free_port

ROOT = Path(__file__).resolve().parents[2]

WHEELS = "".join(f"[[wheel]]\nnode_id = {n}\ngear_ratio = 16\nencoder_cpr = 4096\n"
                 "wheel_radius = 0.05\n\n" for n in (1, 2, 3))


def robot_toml(tmp_path: Path, chassis: str = "") -> Path:
    toml = tmp_path / "robot.toml"
    toml.write_text(f'[chassis]\nlayout = "b21"\nbase_radius = 0.19\n{chassis}\n{WHEELS}')
    return toml


@pytest.fixture
def port() -> Iterator[int]:
    yield free_port()
    while SimProcess.started:  # no simulator outlives its test
        SimProcess.started.pop().kill()


def drive(port: int, toml: Path, *motion: str) -> subprocess.CompletedProcess[str]:
    """``omnican drive ... --json`` against the simulator on ``port``."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, "-m", "omnican", "drive", "--config", str(toml), "-i", "remote",
         "-c", f"ws://127.0.0.1:{port}/", *motion, "--json"],
        check=False, capture_output=True, text=True, env=env, timeout=90)


# ---------------------------------------------------------------- 2: a slower heartbeat


def test_a_slow_configuring_drive_with_a_periodic_heartbeat_starts(port: int,
                                                                   tmp_path: Path) -> None:
    """heartbeat_ms = 200 (lost after 0.7 s), node 1 answering each SDO 20 ms late (about
    1 s from its boot-up to 1017h) and starting its producer's timer when 1017h is
    written (lely's): the base starts and drives, its heartbeat watched from 1017h."""
    toml = robot_toml(tmp_path, "heartbeat_ms = 200")
    sim = SimProcess(port, "--config", str(toml))
    assert sim.command("heartbeat 1 periodic").strip() == "node 1: heartbeat periodic"
    assert sim.command("slowsdo 1 0.02").strip() == "node 1: SDO answers 0.02 s after the request"
    done = drive(port, toml, "--vx", "0.1", "--duration", "1")
    assert done.returncode == 0, done.stderr
    assert "heartbeat lost" not in done.stderr and "Traceback" not in done.stderr
    assert json.loads(done.stdout)["pose"]["x"] > 0.05


# ---------------------------------------------------------------- 3: a wheel that never turns


def test_a_base_whose_wheels_never_turn_fails_naming_a_wheel(port: int,
                                                              tmp_path: Path) -> None:
    """Every drive takes its targets and no wheel turns: under ``--vx 0.1`` each wheel's
    0.087 m/s error is within tracking_error, but none is at half its target: the run
    fails (exit 1) naming the wheel, its target and its speed."""
    toml = robot_toml(tmp_path)
    sim = SimProcess(port, "--config", str(toml))
    for node in (1, 2, 3):
        assert sim.command(f"jam {node}").strip() == f"node {node}: jammed"
    done = drive(port, toml, "--vx", "0.1", "--duration", "3")
    assert done.returncode == 1, (done.stdout, done.stderr)
    assert "Traceback" not in done.stderr
    result = json.loads(done.stdout)
    # For tracking_time_s (0.5 s) and up to a check more (10 Hz, in real time).
    assert re.fullmatch(
        r"base stopped: wheel 1 \(node 2\) not following its target for 0\.[56] s: stalled, "
        r"slipping or off the ground \(target \+0\.09 m/s, measured \+0\.00 m/s, under 50% "
        r"of its target\)", result["error"]), result["error"]
    assert result["pose"]["x"] == 0.0
    assert sim.true_x() == 0.0


# ---------------------------------------------------------------- 4: the controlword every cycle


def test_drives_acting_on_a_controlword_as_it_arrives_move(port: int, tmp_path: Path) -> None:
    """Each drive acts on a controlword only as one arrives (ros2_canopen's fake CiA 402
    slave): written every cycle, the controlword that reaches it in OPERATION ENABLED
    starts its motors, and the base drives."""
    toml = robot_toml(tmp_path)
    sim = SimProcess(port, "--config", str(toml))
    for node in (1, 2, 3):
        assert (sim.command(f"cwarrival {node} on").strip() ==
                f"node {node}: acts on a controlword only as one arrives")
    done = drive(port, toml, "--vx", "0.2", "--duration", "1.5")
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["pose"]["x"] > 0.15
    assert sim.true_x() > 0.15


def test_the_controlword_on_change_for_a_drive_that_dislikes_the_repeat(
        port: int, tmp_path: Path) -> None:
    """cyclic_controlword = false: the controlword on an RPDO of its own, when it changes
    (check-config says so), and the base drives as before. (That a drive acting on
    arrival then never moves is shown in lock-step: in real time a statusword late by
    more than 100 ms gets the enable command sent again, which may start it.)"""
    toml = robot_toml(tmp_path, "cyclic_controlword = false")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    checked = subprocess.run([sys.executable, "-m", "omnican", "check-config", str(toml)],
                             check=False, capture_output=True, text=True, env=env, timeout=60)
    assert checked.returncode == 0, checked.stderr
    assert "RPDO1 0x201 on change, 2 bytes: Controlword (0x6040:00)" in checked.stdout
    assert "RPDO2 0x301 every SYNC, 4 bytes: Target velocity (0x60FF:00)" in checked.stdout
    SimProcess(port, "--config", str(toml))
    done = drive(port, toml, "--vx", "0.2", "--duration", "1")
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["pose"]["x"] > 0.1
