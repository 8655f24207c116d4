"""What the drives know, across processes: ``omnican sim`` in one process (faults typed
into its console), the base in this one or in ``omnican drive`` (a third), over the
simulator's loopback hub: each detection's stop, and the health values it reads."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from omnican import Chassis, default_config
from omnican.errors import DriveError
from omnican.protocol.cia402 import State
from tests.process.test_faults_process import SimProcess, free_port
from tests.support.helpers import drive_for, wait_for

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def sim() -> Iterator[tuple[SimProcess, int]]:
    port = free_port()
    process = SimProcess(port)
    try:
        yield process, port
    finally:
        while SimProcess.started:
            SimProcess.started.pop().kill()


def remote(port: int) -> dict[str, str]:
    return {"interface": "remote", "channel": f"ws://127.0.0.1:{port}/"}


def keep_driving(base: Chassis, text: str, timeout: float, vx: float = 0.3) -> str:
    """Command vx until the base is held stopped for a reason containing ``text``."""
    end = time.monotonic() + timeout
    while time.monotonic() < end and text not in (base.status.stopped_reason or ""):
        base.set_velocity(vx, 0.0, 0.0)
        time.sleep(0.02)
    reason = base.status.stopped_reason or ""
    assert text in reason, base.status
    return reason


def test_each_detection_across_processes(sim: tuple[SimProcess, int]) -> None:
    process, port = sim
    cfg = default_config(bus=remote(port))
    with Chassis.open(cfg) as base:
        # The health values come over the hub from the other process's drives.
        drive_for(base, 1.0, vx=0.3)
        assert wait_for(lambda: all(w.voltage_v is not None for w in base.wheels), 2.0)
        w = base.wheels[1]
        assert w.voltage_v == pytest.approx(24.0, abs=0.3) and w.temperature_c is not None
        on_ground = abs(w.current_a or 0.0)
        assert on_ground > 0.3  # it drives

        # Off the ground: no stop (its drive keeps its speed), a fraction of the current,
        # and a warning that names it.
        assert process.command("lift 2").strip() == "node 2: off the ground"
        drive_for(base, 1.0, vx=0.3)
        assert abs(base.wheels[1].current_a or 0.0) < 0.5 * on_ground
        end = time.monotonic() + 10.0
        while time.monotonic() < end and not any(
                w.startswith("wheel 1 (node 2) off the ground") for w in base.status.warnings):
            drive_for(base, 0.1, vx=0.3)
        assert any(w.startswith("wheel 1 (node 2) off the ground") for w in
                   base.status.warnings), base.status.warnings
        assert base.status.stopped_reason is None
        process.command("land 2")

        assert process.command("jam 2").strip() == "node 2: jammed"
        reason = keep_driving(base, "wheel 1 (node 2) not following its target", 5.0)
        assert "stalled, slipping or off the ground" in reason
        process.command("free 2")
        base.recover()

        process.command("estop on")
        keep_driving(base, "e-stop pressed", 5.0)
        with pytest.raises(DriveError, match="recover refused: e-stop pressed"):
            base.recover()
        process.command("estop off")
        assert wait_for(lambda: not base.status.estop, 3.0)
        base.recover()

        process.command("battery 19")
        keep_driving(base, "battery low", 5.0)
        with pytest.raises(DriveError, match="recover refused: battery"):
            base.recover()
        process.command("battery 24")
        assert wait_for(lambda: base.status.battery == "ok", 3.0)
        base.recover()

        process.command("ferror 3 2500")
        keep_driving(base, "wheel 2 (node 3) not following its target: its drive reports a "
                           "following error", 5.0)
        process.command("ferror 3 off")
        base.recover()

        base.stop()
        time.sleep(0.3)
        process.command("push 1 0.2")  # the base stands; wheel 0 turns
        keep_driving(base, "with a zero target", 5.0, vx=0.0)
        process.command("free 1")
        base.recover()
        drive_for(base, 0.5, vx=0.3)
        assert base.status.stopped_reason is None and base.twist.vx > 0.2


def test_drive_json_names_a_jammed_wheel_and_lists_the_wheels(sim: tuple[SimProcess, int]
                                                              ) -> None:
    process, port = sim
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    drive = subprocess.Popen(
        [sys.executable, "-m", "omnican", "drive", "-i", "remote", "-c",
         f"ws://127.0.0.1:{port}/", "--vx", "0.3", "--duration", "8", "--json"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        assert wait_for(lambda: process.true_x() > 0.05, 20.0, step=0.1)  # up and driving
        process.command("jam 3")
        out, err = drive.communicate(timeout=30)
    finally:
        if drive.poll() is None:
            drive.kill()
            drive.communicate(timeout=5)
    assert drive.returncode == 1, err
    result = json.loads(out)
    assert result["error"].startswith("base stopped: wheel 2 (node 3) not following its target")
    assert [w["node_id"] for w in result["wheels"]] == [1, 2, 3]
    assert all(w["voltage_v"] is not None for w in result["wheels"])
    assert "Traceback" not in err


def test_a_stopped_base_disables_a_pushed_wheel_across_processes(
        sim: tuple[SimProcess, int]) -> None:
    """Issue 30.1 as it was found: ``reboot 3`` latches a stop, then ``push 1 0.2`` in the
    simulator's console. The base (this process) disables wheel 0's drive and names it."""
    process, port = sim
    cfg = default_config(bus=remote(port))
    with Chassis.open(cfg) as base:
        drive_for(base, 0.5, vx=0.3)
        base.stop()
        process.command("reboot 3")
        assert wait_for(lambda: base.status.stopped_reason == "node 3 rebooted", 5.0)
        assert wait_for(lambda: base.wheels[2].state is State.SWITCH_ON_DISABLED, 10.0)
        assert base.wheels[0].state is State.OPERATION_ENABLED
        process.command("push 1 0.2")
        assert wait_for(lambda: base.wheels[0].state is State.SWITCH_ON_DISABLED, 15.0)
        reason = base.status.stopped_reason or ""
        assert reason.startswith("node 3 rebooted; wheel 0 (node 1) turns at") or \
            reason.startswith("node 3 rebooted; wheel 0 (node 1) drive energised at"), reason
        assert reason.endswith("its drive disabled")
        assert base.wheels[1].state is State.OPERATION_ENABLED
        process.command("free 1")
        base.recover()
        drive_for(base, 0.5, vx=0.3)
        assert base.status.stopped_reason is None and base.twist.vx > 0.2


@pytest.mark.parametrize("meanwhile", ["", "fault 2 0x8130", "reboot 3", "estop on"])
def test_a_cutoff_reached_during_recover_refuses_it_across_processes(
        sim: tuple[SimProcess, int], meanwhile: str) -> None:
    """Issue 30.2 as it was found: the drives' heartbeat EMCYs stopped the base; recover()
    passed its first check, and before the loop cleared the stop the battery fell below
    its cutoff (``battery 19``, typed into the simulator's console) and another stop
    reason came. recover() is refused, and the base does not run."""
    process, port = sim
    cfg = default_config(bus=remote(port))
    with Chassis.open(cfg) as base:
        drive_for(base, 0.5, vx=0.3)
        process.command("fault 1 0x8130")
        keep_driving(base, "node 1 fault", 5.0)
        monitor = base._supervisor.checks
        check = monitor.recover_refused
        window: list[str | None] = []

        def refused() -> str | None:
            answer = check()
            if not window:  # recover()'s first check has answered: now, before the loop
                window.append(answer)
                process.command("battery 19")
                if meanwhile:
                    process.command(meanwhile)
                assert wait_for(lambda: monitor.battery is not None and monitor.battery.cut,
                                10.0)
            return answer

        monitor.recover_refused = refused  # type: ignore[method-assign]
        with pytest.raises(DriveError, match=r"recover refused: (battery 19.0 V: below the "
                                             r"cutoff|e-stop pressed)"):
            base.recover()
        assert window == [None]  # the first check let it through
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            base.set_velocity(0.3, 0.0, 0.0)
            st = base.status
            assert not st.enabled and st.stopped_reason is not None, st
            time.sleep(0.02)
        assert base.status.battery == "cutoff"
