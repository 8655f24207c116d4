"""Process-level safety: the host killed (SIGKILL) or terminated (SIGTERM, Ctrl-C),
and the bus going down. The simulated drives run in this process; the host runs in
a child process that reaches them through a loopback hub."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest

from omnican import Chassis
from omnican.protocol.cia402 import State
from omnican.sim import SimulatedBase
from tests.support.flaky_bus import FlakyBus, register
from tests.support.helpers import drive_for, sim_config, still, wait_for

HOST = Path(__file__).resolve().parents[1] / "support" / "host_process.py"
ROOT = Path(__file__).resolve().parents[2]




def start_host(toml: Path) -> subprocess.Popen[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, str(HOST), str(toml)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env)
    assert proc.stdout is not None
    line = proc.stdout.readline()
    if line.strip() != "ready":
        proc.kill()
        _, err = proc.communicate(timeout=10)
        pytest.fail(f"host did not start: {line!r} {err}")
    return proc


def test_sigkill_host_drives_stop_on_their_own(served: tuple[SimulatedBase, Path]) -> None:
    sim, toml = served
    proc = start_host(toml)
    try:
        assert wait_for(lambda: sim.true_twist.vx > 0.2, 3.0)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=5)
        # Nobody disables them: each drive's heartbeat consumer (3 x 100 ms) quick-stops it.
        assert wait_for(lambda: still(sim), 0.3 + 0.3 / 4.0 + 1.0)
        assert wait_for(lambda: all(d.state() is State.SWITCH_ON_DISABLED for d in sim.drives),
                        1.0)
        assert all(d.nmt_state == "OPERATIONAL" for d in sim.drives)  # not a host shutdown
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.communicate(timeout=5)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_sigterm_and_ctrl_c_disable_every_drive(served: tuple[SimulatedBase, Path],
                                                sig: signal.Signals) -> None:
    sim, toml = served
    proc = start_host(toml)
    try:
        assert wait_for(lambda: sim.true_twist.vx > 0.2, 3.0)
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == (128 + sig if sig == signal.SIGTERM else 130)
    assert "Traceback" not in err
    assert all(d.state() is State.SWITCH_ON_DISABLED for d in sim.drives)
    assert all(d.nmt_state == "PRE-OPERATIONAL" for d in sim.drives)  # a clean host shutdown
    assert still(sim)


def test_bus_down_is_reported_and_reconnected(channel: str) -> None:
    iface = register()
    cfg = sim_config(channel)
    host_cfg = replace(cfg, bus={"interface": iface, "channel": channel})
    with SimulatedBase.from_config(cfg) as sim, Chassis.open(host_cfg) as base:
        drive_for(base, 0.3, vx=0.3)
        opened = FlakyBus.opened
        FlakyBus.failing = True
        try:
            assert wait_for(lambda: (base.status.stopped_reason or "").startswith("CAN bus down"),
                            1.0)
            assert "interface is down" in (base.status.bus_error or "")
            # The drives lost the host's heartbeat and stopped by themselves.
            assert wait_for(lambda: still(sim), 1.5)
            assert wait_for(lambda: FlakyBus.opened > opened, 2.0)  # tried to reopen the bus
        finally:
            FlakyBus.failing = False
        assert wait_for(lambda: base.status.bus_up and base.status.bus_error is None, 3.0)
        assert wait_for(lambda: all(w.online for w in base.wheels), 3.0)  # configured again
        base.recover()
        drive_for(base, 0.3, vx=0.3)
        assert sim.true_twist.vx > 0.2
