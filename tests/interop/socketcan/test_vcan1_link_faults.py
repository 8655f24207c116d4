"""The interface under the base fails while it drives: taken down and up again
(``ip link set vcan1 down`` / ``up``), and a transmit queue that fills (a rate-limited
queue on vcan1: sends fail with ENOBUFS, "No buffer space available", as on a
saturated bus). The host must report it, the drives must stop on their own, and the
base must come back in the same process, with nothing printing a traceback.

These run on vcan1 with a simulator of their own, so the shared one on vcan0 is not
disturbed; the interface is put back whatever happens (fixture ``disrupted_toml``).

Why a token-bucket queue and not ``ip link set vcan1 txqueuelen 1``: a vcan interface
has no queue of its own (qdisc noqueue) and hands every frame on at once, so its
txqueuelen changes nothing (two processes sending flat out through txqueuelen 1: no
ENOBUFS in 13,000 frames; with a pfifo_fast of length 1, 10 in 18,000). A queue that
drains slower than it is filled behaves like a real controller's on a saturated bus:
once it is full, every send fails with ENOBUFS until it drains."""

from __future__ import annotations

import re
import time
from collections.abc import Iterator
from pathlib import Path

import can
import pytest

from tests.interop.socketcan.support import (
    HostProcess,
    SimProcess,
    assert_odometry_reaches_truth,
    no_traceback,
    settled,
    sh,
    wait_until,
)

pytestmark = pytest.mark.socketcan

CHANNEL = "vcan1"
SOON_S = 30.0
QUEUE_FULL = re.compile(r"transmit queue full|No buffer space", re.IGNORECASE)


@pytest.fixture
def rig(disrupted_toml: Path, tmp_path: Path) -> Iterator[tuple[SimProcess, HostProcess]]:
    sim = SimProcess(disrupted_toml, CHANNEL, tmp_path / "sim.stderr")
    try:
        host = HostProcess(disrupted_toml, tmp_path / "host.stderr")
        try:
            yield sim, host
            assert host.close() == 0, host.stderr()[-3000:]
            no_traceback(host.stderr(), "the host")
        finally:
            host.kill()
        assert sim.close() == 0, sim.stderr()[-3000:]
        no_traceback(sim.stderr(), "omnican sim")
    finally:
        sim.kill()


def status(host: HostProcess) -> dict[str, object]:
    st: dict[str, object] = host.status()["status"]
    return st


def bus_up(host: HostProcess) -> object:
    """ChassisStatus.bus_up (None if this omnican has no such field)."""
    return status(host).get("bus_up")


def recover_and_drive(sim: SimProcess, host: HostProcess) -> None:
    host.request("hold")  # a new command after recover(), not the one from before the stop
    reply = host.request("recover")
    assert reply["ok"], reply
    start, odo0 = settled(host, sim)
    host.request("drive 0.2 0 0")
    assert wait_until(sim.moving, SOON_S)
    host.request("hold")
    assert wait_until(sim.still, SOON_S)
    assert_odometry_reaches_truth(host, sim, odo0, start, "after the bus came back")


def boot_ups(watch: can.BusABC, nodes: set[int], timeout: float) -> set[int]:
    """Nodes whose boot-up frame (0x700 + id, 00h) arrives within ``timeout``."""
    seen: set[int] = set()
    end = time.monotonic() + timeout
    while seen != nodes and time.monotonic() < end:
        try:
            msg = watch.recv(timeout=0.5)
        except can.CanOperationError:  # "network is down", once, from before the link came up
            continue
        if msg is not None and msg.arbitration_id - 0x700 in nodes and bytes(msg.data) == b"\0":
            seen.add(msg.arbitration_id - 0x700)
    return seen


def test_interface_down_and_up_while_driving(rig: tuple[SimProcess, HostProcess]) -> None:
    sim, host = rig
    host.request("drive 0.2 0 0")
    assert wait_until(sim.moving, SOON_S)
    host.request("watch")
    sh("ip", "link", "set", CHANNEL, "down")

    # The base says so, and keeps running its loop (it is not stuck in a send).
    assert wait_until(lambda: bus_up(host) is False, SOON_S), status(host)
    st = status(host)
    assert str(st["stopped_reason"]).startswith("CAN bus down"), st
    assert st["bus_error"], st  # and why (its wording changes as the bus is reopened)
    # Nothing the host sends gets through: the drives' own host-heartbeat consumers
    # stopped the wheels.
    assert wait_until(sim.still, SOON_S)
    seen = host.request("seen")
    assert seen["last_cycles"] > seen["first_cycles"], seen

    # Listen for the drives' boot-ups from before the link comes back.
    with can.Bus(interface="socketcan", channel=CHANNEL,
                 can_filters=[{"can_id": 0x700, "can_mask": 0x780}]) as watch:
        sh("ip", "link", "set", CHANNEL, "up")
        # omnican reopens the bus and configures every drive again (NMT reset
        # communication: each drive answers with its boot-up).
        assert boot_ups(watch, {1, 2, 3}, 2 * SOON_S) == {1, 2, 3}
    assert wait_until(lambda: bus_up(host) is True and status(host)["bus_error"] is None,
                      SOON_S), status(host)
    assert sim.still(1.0)  # no motion before recover() and a new command
    recover_and_drive(sim, host)


def test_transmit_queue_full_drops_frames_and_recovers(
        rig: tuple[SimProcess, HostProcess]) -> None:
    sim, host = rig
    host.request("drive 0.2 0 0")
    assert wait_until(sim.moving, SOON_S)
    before = host.status()
    host.request("watch")
    # A queue of ~10 frames drained at ~80 frames/s, for ~400 frames/s offered: it fills,
    # and the kernel refuses further frames with ENOBUFS, as on a saturated bus.
    sh("tc", "qdisc", "replace", "dev", CHANNEL, "root", "tbf", "rate", "10kbit", "burst", "200",
       "limit", "160")
    assert wait_until(lambda: any(QUEUE_FULL.search(e or "") for e in
                                  host.request("seen")["bus_errors"]), SOON_S)
    during = host.status()
    assert host.proc.poll() is None
    assert during["status"]["cycles"] > before["status"]["cycles"]  # the loop never blocked
    assert isinstance(during["dropped_frames"], int), "the bus counts no dropped frames"
    assert during["dropped_frames"] > (before["dropped_frames"] or 0)
    sh("tc", "qdisc", "del", "dev", CHANNEL, "root")

    # Back to normal: the errors clear, and no more frames are dropped.
    assert wait_until(lambda: status(host)["bus_error"] is None, SOON_S), status(host)
    quiet = host.status()
    time.sleep(2.0)
    after = host.status()
    assert after["dropped_frames"] == quiet["dropped_frames"]
    assert after["status"]["cycles"] > quiet["status"]["cycles"]
    # Dropped, never queued for later: at most every frame of every cycle meanwhile.
    cycles = after["status"]["cycles"] - before["status"]["cycles"]
    assert after["dropped_frames"] - (before["dropped_frames"] or 0) <= 8 * cycles
    recover_and_drive(sim, host)

    # Quitting while the queue is full (Ctrl-C on a saturated bus) ends cleanly too: the
    # frames of the shutdown that the bus refuses are dropped like any other.
    host.request("drive 0.2 0 0")
    host.request("watch")
    sh("tc", "qdisc", "replace", "dev", CHANNEL, "root", "tbf", "rate", "10kbit", "burst", "200",
       "limit", "160")
    assert wait_until(lambda: any(QUEUE_FULL.search(e or "") for e in
                                  host.request("seen")["bus_errors"]), SOON_S)
    assert host.close() == 0, host.stderr()[-3000:]
    no_traceback(host.stderr(), "the host")
