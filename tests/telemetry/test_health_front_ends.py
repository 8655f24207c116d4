"""What the drives know, where the user looks: the teleop dashboard, ``omnican drive
--json``, and the simulator's console that injects it."""

from __future__ import annotations

import contextlib
import io
import json
from collections.abc import Iterator

import can
import pytest
from rich.console import Console

from omnican import Chassis
from omnican.cli import main
from omnican.cli.dashboard import dashboard
from omnican.cli.terminal import RecentEvents
from omnican.clock import SimClock
from omnican.command.teleop import TeleopModel
from omnican.core.kinematics import Twist
from omnican.io.lockstep import LockstepBus
from omnican.protocol import can_state as cs
from omnican.sim import SimulatedBase
from omnican.sim.console import command
from tests.support.helpers import drive_for, lockstep_rig, sim_config

Rig = tuple[SimClock, SimulatedBase, Chassis]


@pytest.fixture
def rig(channel: str) -> Iterator[Rig]:
    with lockstep_rig(channel) as r:
        yield r


def screen(base: Chassis, width: int = 80) -> list[str]:
    keys = TeleopModel.for_config(base.cfg, 0.3, 1.0, 0.6)
    console = Console(width=width, record=True, color_system=None, file=io.StringIO())
    console.print(dashboard(base, keys, Twist(), "omnican teleop", RecentEvents(), "", width, 24))
    return console.export_text().splitlines()


def test_the_dashboard_shows_current_voltage_and_temperature_in_80_columns(rig: Rig) -> None:
    _clock, _sim, base = rig
    drive_for(base, 1.0, vx=0.3)
    lines = screen(base)
    assert max(len(line) for line in lines) <= 80
    text = "\n".join(lines)
    assert "wheels (target, actual m/s; travel m; motor current A; DC link V; °C)" in text
    header = next(line for line in lines if "wheel" in line and "state" in line)
    assert header.split()[-4:] == ["A", "V", "°C", "│"]
    row = next(line for line in lines if line.startswith("│ 1 "))
    w = base.wheels[1]
    assert f"{w.current_a:+.2f}" in row and f"{w.voltage_v:.1f}" in row
    assert f"{w.temperature_c:.1f}" in row
    assert "battery 23.9 V" in lines[0] + lines[1]


def test_the_dashboard_shows_the_controller_state_and_what_a_stop_needs(rig: Rig,
                                                                         channel: str) -> None:
    clock, sim, base = rig
    kernel = LockstepBus(channel, clock)
    try:
        kernel.send(can.Message(arbitration_id=cs.ERR_CRTL | cs.ERR_CNT, is_error_frame=True,
                                data=bytes([0, cs.CRTL_RX_WARNING, 0, 0, 0, 0, 12, 99])))
        clock.sleep(0.3)  # the status has it at the next health period
        assert any("CAN error-warning (tx 12, rx 99)" in line for line in screen(base, 120))
    finally:
        kernel.shutdown()
    sim.estop(True)
    clock.sleep(0.3)
    text = " ".join(line.strip() for line in screen(base))
    assert "STOPPED: e-stop pressed (node 1 Digital inputs (0x60FD:00) bit 16) - release it, " \
           "then press r" in text


def test_drive_json_lists_each_wheels_drive() -> None:
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main(["drive", "--sim", "--fast", "--vx", "0.3", "--duration", "0.5",
                     "--json"]) == 0
    wheels = json.loads(out.getvalue())["wheels"]
    assert [w["node_id"] for w in wheels] == [1, 2, 3]
    for w in wheels:
        assert set(w) == {"node_id", "axis", "state", "current_a", "voltage_v", "temperature_c"}
        assert w["state"] == "OPERATION ENABLED" and w["axis"] == 0
        assert w["voltage_v"] == pytest.approx(24.0, abs=0.2)
        assert w["temperature_c"] == pytest.approx(25.0, abs=0.5)
        assert isinstance(w["current_a"], float)


@pytest.mark.parametrize(("line", "reply"), [
    ("jam 2", "node 2: jammed"), ("free 2", "node 2: turns freely"),
    ("lift 3", "node 3: off the ground"), ("land 3", "node 3: on the ground"),
    ("push 1 0.2", "node 1: pushed at 0.2 m/s"), ("ferror 1 1234", "node 1: following error 1234"),
    ("ferror 1 off", "node 1: no following error"), ("battery 21.5", "battery 21.5 V"),
    ("estop on", "e-stop pressed"), ("estop off", "e-stop released"),
    ("jam 2.1", "error: node 2 has 1 axis(es), no axis 1"), ("jam", "error: jam needs a node id"),
    ("push 1", "error: push takes a node id and a value"), ("battery low", "error: not a number"),
    ("estop maybe", "error: estop takes on or off"), ("lift 9", "error: no simulated node 9"),
])
def test_the_console_injects_what_the_drives_know(channel: str, line: str, reply: str) -> None:
    with SimulatedBase.from_config(sim_config(channel)) as sim:
        assert (command(sim, line) or "").startswith(reply)
        if line == "jam 2":
            assert sim.drives[1].axes[0].jammed
        if line == "lift 3":
            assert not sim.drives[2].axes[0].grounded
        if line == "battery 21.5":
            assert sim.drives[0].health.supply_v == 21.5
        if line == "estop on":
            assert all(d.health.estop_pressed for d in sim.drives)
