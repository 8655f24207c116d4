"""Every stop ends in bounded time, whatever the decelerations say (issue 30 item 6).

A config refuses a stop deceleration below the floor (tests/config/test_config.py); these
tests give the base one in code, far below it, and show that each way a base stops (a
stop command, the watchdog, a latched stop, closing) still ends within
``limits.MAX_STOP_S``: in lock-step, and against ``omnican sim`` in another process."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path

import pytest

from omnican import Chassis, default_config
from omnican.clock import SimClock
from omnican.core.limits import MAX_STOP_S
from omnican.protocol.cia402 import State
from omnican.sim import SimulatedBase
from tests.process.test_faults_process import SimProcess
from tests.process.test_health_process import sim as sim_process  # noqa: F401 (the fixture, reused)
from tests.support.helpers import drive_for, one_error_line, sim_config, still, wait_for

ROOT = Path(__file__).resolve().parents[2]
TINY = {"stop_decel": 1e-9, "stop_angular_decel": 1e-9}  # an endless stop, as given


@pytest.fixture
def tiny_rig(channel: str) -> Iterator[tuple[SimClock, SimulatedBase, Chassis]]:
    """The demo base in lock-step, its stop decelerations set in code to 1e-9."""
    cfg = sim_config(channel, **TINY)
    clock = SimClock()
    with SimulatedBase.from_config(cfg, clock=clock) as sim, \
            Chassis.open(cfg, clock=clock) as base:
        yield clock, sim, base


def _at_speed(base: Chassis, sim: SimulatedBase) -> None:
    drive_for(base, 1.5, vx=0.6, wz=1.5)
    t = sim.true_twist
    assert t.vx == pytest.approx(0.6, abs=0.05) and t.wz == pytest.approx(1.5, abs=0.1)


STOPS: dict[str, Callable[[Chassis, SimulatedBase], None]] = {
    "stop command": lambda base, sim: base.stop(),
    "watchdog": lambda base, sim: None,  # the operator goes silent
    "latched stop": lambda base, sim: sim.drives[0].inject_fault(0x2310),
}


@pytest.mark.parametrize("how", list(STOPS))
def test_each_stop_ends_within_the_bound_whatever_the_deceleration(
        tiny_rig: tuple[SimClock, SimulatedBase, Chassis], how: str) -> None:
    """At 1e-9 m/s^2 the base once rolled on for ever (0.3 m/s after 3 s at 1e-3): now
    every stop path ends within MAX_STOP_S (plus the watchdog's timeout where it is the
    one to notice), and the base stays still."""
    clock, sim, base = tiny_rig
    _at_speed(base, sim)
    start = clock.now()
    STOPS[how](base, sim)
    watchdog = base.cfg.chassis.cmd_timeout_s if how == "watchdog" else 0.0
    assert wait_for(lambda: still(sim), watchdog + MAX_STOP_S + 0.3, clock=clock), \
        (how, sim.true_twist, clock.now() - start)
    x = sim.true_pose.x
    clock.sleep(1.0)
    assert sim.true_pose.x == pytest.approx(x, abs=1e-3)


def test_closing_a_moving_base_ends_within_the_bound_and_disables_every_drive(
        tiny_rig: tuple[SimClock, SimulatedBase, Chassis]) -> None:
    """close() (Ctrl-C and SIGTERM end here) waited speed / stop_decel + 0.5 s: 13
    minutes until SIGKILL at 1e-9. It waits for the bounded ramp, then disables."""
    clock, sim, base = tiny_rig
    _at_speed(base, sim)
    start = clock.now()
    base.close()
    assert clock.now() - start <= MAX_STOP_S + 1.0
    assert still(sim)
    assert all(d.state() is not State.OPERATION_ENABLED for d in sim.drives)


# ---------------------------------------------------------------- across processes


def test_a_config_with_a_tiny_deceleration_is_refused_before_anything_moves(
        tmp_path: Path) -> None:
    """``omnican drive`` with stop_decel 1e-9 never exited and ignored SIGTERM: now it
    is refused, one line, exit 2, before a bus is opened."""
    toml = tmp_path / "robot.toml"
    toml.write_text('[chassis]\nlayout = "b21"\nbase_radius = 0.19\nstop_decel = 0.001\n\n'
                    + "".join(f"[[wheel]]\nnode_id = {n}\ngear_ratio = 16\nencoder_cpr = 4096\n"
                              "wheel_radius = 0.05\n\n" for n in (1, 2, 3)))
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.run([sys.executable, "-m", "omnican", "drive", "--sim", "--config",
                           str(toml), "--vx", "0.3", "--duration", "0.2"],
                          capture_output=True, text=True, timeout=120, env=env, check=False)
    assert proc.returncode == 2, proc
    line = one_error_line(proc.stderr)
    assert "chassis.stop_decel: 0.001 would stop the base from its top speed" in line
    assert "every stop must end within 2 s: at least 0.667 m/s^2" in line
    assert proc.stdout == ""


def test_a_base_stops_in_bounded_time_against_another_process(
        sim_process: tuple[SimProcess, int]) -> None:  # noqa: F811 (the fixture)
    """The base in this process, given 1e-9 decelerations in code, drives the drives of
    ``omnican sim`` in another: the stop, the watchdog's stop and closing each leave the
    simulator's true pose still (it rolled on at 0.3 m/s before)."""
    process, port = sim_process
    cfg = default_config(bus={"interface": "remote", "channel": f"ws://127.0.0.1:{port}/"})
    cfg = replace(cfg, chassis=replace(cfg.chassis, **TINY))

    def settled() -> bool:  # the simulator's truth, read over its console
        x = process.true_x()
        time.sleep(0.3)
        return math.isclose(process.true_x(), x, abs_tol=1e-3)

    with Chassis.open(cfg) as base:
        for stop in (base.stop, lambda: None):  # a stop command; the operator goes silent
            drive_for(base, 1.0, vx=0.3)
            assert base.twist.vx > 0.2
            stop()
            assert wait_for(settled, 15.0, step=0.05), base.status
        drive_for(base, 1.0, vx=0.3)
    # Closed: still, however loaded the machine (a frame or two may be on its way).
    assert wait_for(settled, 15.0, step=0.05)
    assert all(w.state is not State.OPERATION_ENABLED for w in base.wheels)
