"""The Chassis API in a host process of its own, against ``omnican sim`` in another, on
vcan0: motion and odometry against the simulator's ground truth, and every safety case
that involves two processes (a drive faults, goes silent or reboots; the host is killed;
the host stops commanding; the host is terminated)."""

from __future__ import annotations

import os
import signal
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.interop.socketcan.support import (
    NMT_OPERATIONAL,
    NMT_PRE_OPERATIONAL,
    START_S,
    HostProcess,
    SimProcess,
    assert_odometry_reaches_truth,
    next_frame,
    nmt_states,
    no_traceback,
    settled,
    wait_until,
)

pytestmark = pytest.mark.socketcan

# The drives' own timeout on the host's heartbeat is 2 s in the test config; the emulated
# CPU may stall for a while on top of that: "soon" is anything well within a minute.
SOON_S = 30.0


def enabled(host: HostProcess) -> bool:
    st = host.status()
    return bool(st["status"]["enabled"]) and all(
        w["state"] == "OPERATION ENABLED" for w in st["wheels"])


def stopped_for(host: HostProcess, words: str) -> bool:
    reason = host.status()["status"]["stopped_reason"] or ""
    return words in reason


def test_chassis_api_odometry_matches_ground_truth(sim: SimProcess, host: HostProcess) -> None:
    assert enabled(host)
    start, odo0 = settled(host, sim)
    host.request("drive 0.2 0.1 -0.4")
    assert wait_until(sim.moving, SOON_S), host.status()
    wait_until(lambda: host.pose().relative_to(odo0).x > 0.3, SOON_S)
    host.request("hold")
    assert wait_until(sim.still, SOON_S), host.status()
    truth = sim.pose().relative_to(start)
    assert truth.x > 0.3 and truth.theta < -0.3
    assert_odometry_reaches_truth(host, sim, odo0, start, "Chassis API")
    st = host.status()
    assert st["status"]["stopped_reason"] is None
    assert st["status"]["cycles"] > 0 and st["status"]["bus_error"] is None


def recover_and_drive(sim: SimProcess, host: HostProcess) -> None:
    """recover() brings the base back in the same process, and it drives again."""
    host.request("hold")  # a new command after recover(), not the one from before the stop
    reply = host.request("recover")
    assert reply["ok"], reply
    assert enabled(host)
    start, odo0 = settled(host, sim)
    host.request("drive 0.2 0 0")
    assert wait_until(sim.moving, SOON_S), host.status()
    host.request("hold")
    assert wait_until(sim.still, SOON_S), host.status()
    assert_odometry_reaches_truth(host, sim, odo0, start, "after recover()")


def test_a_drive_fault_stops_every_wheel(sim: SimProcess, host: HostProcess) -> None:
    host.request("drive 0.2 0 0.3")
    assert wait_until(sim.moving, SOON_S), host.status()
    assert sim.command("fault 2", "node 2: fault").endswith("0x2310")
    assert wait_until(lambda: stopped_for(host, "node 2 fault"), SOON_S)
    assert wait_until(sim.still, SOON_S)  # all three wheels, not just the faulty one
    st = host.status()
    assert "0x2310" in st["status"]["stopped_reason"]
    wheel2 = next(w for w in st["wheels"] if w["node_id"] == 2)
    assert wheel2["state"] == "FAULT" and "0x2310" in (wheel2["fault"] or "")
    assert sim.still(1.0)  # commands keep coming, the base stays stopped
    recover_and_drive(sim, host)


def test_a_lost_heartbeat_stops_every_wheel(sim: SimProcess, host: HostProcess) -> None:
    host.request("drive 0.2 0 0")
    assert wait_until(sim.moving, SOON_S), host.status()
    sim.command("heartbeat 3 off", "node 3: heartbeat off")
    assert wait_until(lambda: stopped_for(host, "node 3 heartbeat lost"), SOON_S)
    assert wait_until(sim.still, SOON_S), host.status()
    wheel3 = next(w for w in host.status()["wheels"] if w["node_id"] == 3)
    assert not wheel3["online"]
    sim.command("heartbeat 3 on", "node 3: heartbeat on")
    assert next_frame("vcan0", 0x703) is not None  # the drive is back: now recover() can
    recover_and_drive(sim, host)


def test_a_drive_reboot_stops_every_wheel_and_is_reconfigured(sim: SimProcess,
                                                              host: HostProcess) -> None:
    start, odo0 = settled(host, sim)
    host.request("drive 0.2 0 0")
    assert wait_until(sim.moving, SOON_S), host.status()
    sim.command("reboot 1", "node 1: rebooted")
    assert wait_until(lambda: stopped_for(host, "node 1 rebooted"), SOON_S)
    assert wait_until(sim.still, SOON_S), host.status()
    # omnican configures the rebooted drive again by itself; then recover() starts it.
    assert wait_until(lambda: all(w["online"] for w in host.status()["wheels"]), SOON_S)
    # The odometry continued across the reboot (its counter restarted at zero).
    assert_odometry_reaches_truth(host, sim, odo0, start, "across the reboot")
    recover_and_drive(sim, host)


def test_command_timeout_stops_a_live_host(sim: SimProcess, host: HostProcess) -> None:
    host.request("drive 0.2 0 0")
    assert wait_until(sim.moving, SOON_S), host.status()
    host.request("hold")  # the host lives on, but sends no more commands
    assert wait_until(sim.still, SOON_S), host.status()
    st = host.status()["status"]
    assert st["command_age_s"] > 1.0  # cmd_timeout_s of the test config
    assert st["stopped_reason"] is None and st["enabled"]  # a pause, not a failure
    host.request("drive 0.2 0 0")  # the next command moves again, no recover() needed
    assert wait_until(sim.moving, SOON_S), host.status()
    host.request("hold")
    assert wait_until(sim.still, SOON_S), host.status()


@pytest.fixture
def driving_host(sim: SimProcess, toml: Path, tmp_path: Path,
                 no_host: None) -> Iterator[HostProcess]:
    """A host of its own, driving the base, for a test that ends it by a signal."""
    h = HostProcess(toml, tmp_path / "host.stderr")
    try:
        h.request("drive 0.2 0 0.3")
        assert wait_until(sim.moving, SOON_S), h.status()
        yield h
    finally:
        h.kill()


def test_killed_host_drives_stop_on_their_own(sim: SimProcess, driving_host: HostProcess,
                                              toml: Path, tmp_path: Path) -> None:
    os.kill(driving_host.proc.pid, signal.SIGKILL)
    assert driving_host.proc.wait(timeout=30) == -signal.SIGKILL
    # Nobody disables them: each drive's consumer of the host's heartbeat stops it.
    assert wait_until(sim.still, SOON_S)
    assert sim.still(2.0)
    # Still OPERATIONAL: no host shut them down, their own watchdog did.
    assert nmt_states("vcan0") == dict.fromkeys((1, 2, 3), NMT_OPERATIONAL)
    # And the drives come up again for the next host, without a restart of anything.
    after = HostProcess(toml, tmp_path / "host2.stderr")
    try:
        assert enabled(after)
        assert after.close() == 0
    finally:
        after.kill()


def test_terminated_host_disables_every_drive(sim: SimProcess,
                                              driving_host: HostProcess) -> None:
    driving_host.proc.send_signal(signal.SIGTERM)
    assert driving_host.proc.wait(timeout=START_S) == 128 + signal.SIGTERM
    no_traceback(driving_host.stderr(), "the host")
    assert sim.still(1.0)
    # The host shut them down in order: disabled and back in PRE-OPERATIONAL.
    assert nmt_states("vcan0") == dict.fromkeys((1, 2, 3), NMT_PRE_OPERATIONAL)
