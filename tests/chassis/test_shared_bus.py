"""A bus that is not ours alone: lost frames, other masters, other devices (29-bit ids),
two devices on one node id, an EMCY storm. All in simulated time (lock-step), with the
host and the drives on two channels joined by a bridge that can lose frames."""

from __future__ import annotations

import itertools
import logging
from collections.abc import Iterator
from typing import Any

import canopen
import pytest

from omnican import Chassis, DriveError
from omnican.clock import SimClock
from omnican.io.lockstep import LockstepBus, listeners_receiver
from omnican.protocol.cia301 import EMCY_BASE, NMT_COB_ID, NmtCommand
from omnican.protocol.cia402 import State
from omnican.sim import SimulatedBase, SimulatedDrive
from omnican.sim.scheduler import SimScheduler
from tests.support.helpers import drive_for, sim_config, still, wait_for
from tests.support.shared_bus import (
    LossyLink,
    Sender,
    bus_args,
    drop_next,
    heartbeats_of,
    shared_bus,
)

HOST_HEARTBEAT = 0x700 + 127


def settle(base: Chassis, sim: SimulatedBase) -> None:
    base.stop()
    assert wait_for(lambda: still(sim), 2.0, clock=sim.clock)
    sim.clock.sleep(0.05)


@pytest.fixture
def rig(channel: str) -> Iterator[tuple[SimClock, LossyLink, Sender, SimulatedBase, Chassis]]:
    cfg = sim_config(channel)
    with shared_bus(channel) as (clock, bridge, sender, drives), \
            SimulatedBase.from_config(cfg, bus=bus_args(drives), clock=clock) as sim, \
            Chassis.open(cfg, clock=clock) as base:
        yield clock, bridge, sender, sim, base


# ---------------------------------------------------------------- 1: lost frames


@pytest.mark.parametrize("loss", [0.01, 0.05])
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_startup_and_driving_survive_lost_frames(channel: str, loss: float, seed: int) -> None:
    cfg = sim_config(channel)
    with shared_bus(channel, loss=loss, seed=seed) as (clock, bridge, _, drives), \
            SimulatedBase.from_config(cfg, bus=bus_args(drives), clock=clock) as sim, \
            Chassis.open(cfg, clock=clock) as base:
        assert bridge.stats.lost > 0  # frames were lost while the drives were configured
        drive_for(base, 1.5, vx=0.3, wz=0.3)
        settle(base, sim)
        assert base.status.stopped_reason is None, base.status
        assert sim.true_pose.x > 0.3
        assert base.pose.distance_to(sim.true_pose) < 0.01
    assert all(d.state() is State.SWITCH_ON_DISABLED for d in sim.drives)


def test_a_drive_that_stops_answering_sdo_is_named_with_what_was_being_done(
        channel: str) -> None:
    cfg = sim_config(channel)
    with shared_bus(channel) as (clock, bridge, _, drives), \
            SimulatedBase.from_config(cfg, bus=bus_args(drives), clock=clock) as sim:
        # Node 2 answers its boot-up, then no SDO ever again.
        bridge.rules.append(lambda m, way: way == "to_host" and m.arbitration_id == 0x582)
        with pytest.raises(DriveError) as err:
            Chassis.open(cfg, clock=clock)
        assert "node 2" in str(err.value)
        assert "no SDO answer" in str(err.value) and "attempts" in str(err.value)
        assert all(d.state() is not State.OPERATION_ENABLED for d in sim.drives)


def test_a_lost_boot_up_is_asked_for_again(channel: str) -> None:
    cfg = sim_config(channel)
    with shared_bus(channel) as (clock, bridge, _, drives):
        bridge.rules.append(drop_next(heartbeats_of(1), 1, "to_host", 0.0, clock))  # boot-up
        bridge.rules.append(drop_next(lambda m: m.arbitration_id == NMT_COB_ID, 1,
                                      "to_drives", 0.0, clock))  # and a reset command
        with SimulatedBase.from_config(cfg, bus=bus_args(drives), clock=clock, boot=False), \
                Chassis.open(cfg, clock=clock) as base:
            assert base.status.enabled
        assert bridge.stats.dropped == 2


# ---------------------------------------------------------------- 2: heartbeats


def test_host_heartbeat_keeps_its_period_whatever_the_loop_rate(channel: str) -> None:
    # At 30 Hz a heartbeat sent "at the first cycle after its period" comes every 133 ms.
    cfg = sim_config(channel, rate_hz=30.0)
    with shared_bus(channel) as (clock, _, sender, drives), \
            SimulatedBase.from_config(cfg, bus=bus_args(drives), clock=clock), \
            Chassis.open(cfg, clock=clock):
        sender.received.clear()
        clock.sleep(3.0)
        times = [m.timestamp for m in sender.received if m.arbitration_id == HOST_HEARTBEAT]
    assert 29 <= len(times) <= 31
    gaps = [b - a for a, b in itertools.pairwise(times)]
    assert max(gaps) <= 0.1 + 1 / 30 + 1e-6


@pytest.mark.parametrize(("lost", "trips"), [(2, False), (3, True)])
def test_drives_ride_out_fewer_lost_host_heartbeats_than_the_factor(
        rig: Any, lost: int, trips: bool) -> None:
    clock, bridge, _, sim, base = rig
    drive_for(base, 0.5, vx=0.2)
    bridge.rules.append(drop_next(lambda m: m.arbitration_id == HOST_HEARTBEAT, lost,
                                  "to_drives", clock.now(), clock))
    drive_for(base, 1.0, vx=0.2)
    assert bridge.stats.dropped == lost
    if trips:  # 400 ms of silence, more than 3.5 periods: every drive stops by itself
        assert base.status.stopped_reason is not None
        assert all(d.state() is not State.OPERATION_ENABLED for d in sim.drives)
    else:
        assert base.status.stopped_reason is None, base.status
        assert all(d.state() is State.OPERATION_ENABLED for d in sim.drives)
        assert sim.true_twist.vx > 0.15


@pytest.mark.parametrize(("lost", "trips"), [(2, False), (3, True)])
def test_the_host_rides_out_fewer_lost_drive_heartbeats_than_the_factor(
        rig: Any, lost: int, trips: bool) -> None:
    clock, bridge, _, _sim, base = rig
    drive_for(base, 0.3, vx=0.2)
    bridge.rules.append(drop_next(heartbeats_of(2), lost, "to_host", clock.now(), clock))
    drive_for(base, 1.0, vx=0.2)
    assert bridge.stats.dropped == lost
    if trips:
        assert base.status.stopped_reason == "node 2 heartbeat lost"
    else:
        assert base.status.stopped_reason is None, base.status


# ---------------------------------------------------------------- 3: 29-bit frames


def test_29_bit_frames_are_never_taken_for_canopen(rig: Any) -> None:
    _, _, sender, sim, base = rig
    # A BMS and a charger on 29-bit ids that equal our COB-IDs: TPDOs of every node, an
    # EMCY, a boot-up, an SDO answer, an NMT command.
    for can_id, data in ((0x181, b"\x08\x00\x00\x10\x23\x00\x00"), (0x281, b"\xff\xff\xff\x7f"),
                         (0x282, b"\x00\x00\x00\x80"), (0x283, b"\x12\x34\x56\x78"),
                         (0x082, b"\x10\x23\x01\x00\x00\x00\x00\x00"), (0x703, b"\x00"),
                         (0x581, b"\x80\x00\x00\x00\x00\x00\x00\x00"), (0x000, b"\x02\x00")):
        sender.every(0.003, can_id, data, extended=True)
    drive_for(base, 1.0, vx=0.3)
    settle(base, sim)
    assert base.status.stopped_reason is None, base.status
    assert base.pose.distance_to(sim.true_pose) < 0.005
    assert all(d.state() is State.OPERATION_ENABLED for d in sim.drives)
    assert all(w.fault is None for w in base.wheels)


def test_29_bit_frames_reach_no_simulated_drive(channel: str) -> None:
    cfg = sim_config(channel)
    clock = SimClock()
    with SimulatedBase.from_config(cfg, clock=clock) as sim:
        sender = Sender(clock, channel)
        try:
            sender.send(0x000, bytes([NmtCommand.START, 0]), extended=True)  # NMT start all
            sender.send(0x601, b"\x40\x00\x10\x00\x00\x00\x00\x00", extended=True)  # SDO read
            clock.sleep(0.1)
            assert all(d.nmt_state == "PRE-OPERATIONAL" for d in sim.drives)
            assert not [m for m in sender.received if m.arbitration_id == 0x581]
        finally:
            sender.close()


# ---------------------------------------------------------------- 4: another master


def test_another_masters_nmt_stop_latches_and_its_start_moves_nothing(rig: Any) -> None:
    clock, _, other, sim, base = rig
    drive_for(base, 0.5, vx=0.2)
    other.send(NMT_COB_ID, bytes([NmtCommand.STOP, 0]))  # "stop all nodes"
    clock.sleep(0.05)
    reason = base.status.stopped_reason or ""
    assert "NMT" in reason and "stop" in reason.lower(), base.status
    assert not base.status.enabled
    other.send(NMT_COB_ID, bytes([NmtCommand.START, 0]))  # the other master starts them
    start = sim.true_pose
    drive_for(base, 1.0, vx=0.2)
    assert sim.true_pose.distance_to(start) < 0.002  # no motion without recover()
    assert base.status.stopped_reason == reason
    base.recover()
    drive_for(base, 0.5, vx=0.2)
    assert sim.true_twist.vx > 0.15 and base.status.enabled


@pytest.mark.parametrize("command", [NmtCommand.STOP, NmtCommand.ENTER_PRE_OPERATIONAL])
def test_a_drive_leaving_operational_latches_and_recover_starts_it(
        rig: Any, command: NmtCommand) -> None:
    clock, _, other, sim, base = rig
    drive_for(base, 0.3, vx=0.2)
    other.send(NMT_COB_ID, bytes([command, 2]))  # node 2 only
    clock.sleep(0.05)
    assert "node 2" in (base.status.stopped_reason or ""), base.status
    drive_for(base, 0.5, vx=0.2)
    assert still(sim)
    base.recover()
    assert sim.drives[1].nmt_state == "OPERATIONAL"
    drive_for(base, 0.5, vx=0.2)
    assert sim.true_twist.vx > 0.15


# ---------------------------------------------------------------- 5: a failed open


@pytest.mark.parametrize("how", ["stays switched on", "fault will not clear"])
def test_a_failed_open_disables_every_drive_it_enabled(channel: str, how: str) -> None:
    cfg = sim_config(channel)
    clock = SimClock()
    with SimulatedBase.from_config(cfg, clock=clock) as sim:
        if how == "stays switched on":
            sim.drives[2].hold_switched_on()
        else:
            sim.drives[2].inject_fault(0x4310, persistent=True)
        with pytest.raises(DriveError) as err:
            Chassis.open(cfg, clock=clock)
        assert "node 3" in str(err.value)
        clock.sleep(0.2)
        assert [d.state() for d in sim.drives[:2]] == [State.SWITCH_ON_DISABLED] * 2
        assert still(sim)


# ---------------------------------------------------------------- 6: two drives, one id


def twin_drive(clock: SimClock, channel: str, node_id: int) -> tuple[SimulatedDrive, Any]:
    """A second device answering as ``node_id`` on ``channel`` (a cloned drive)."""
    net = canopen.Network()
    lockstep = LockstepBus(channel, clock)
    lockstep.set_receiver(listeners_receiver(net.listeners))
    net.bus = lockstep
    scheduler = SimScheduler(0.002, clock=clock)
    drive = SimulatedDrive(net, node_id, scheduler=scheduler, clock=clock)
    scheduler.start()

    def close() -> None:
        drive.close()
        scheduler.close()
        lockstep.shutdown()

    return drive, close


def test_two_drives_on_one_node_id_are_refused_before_anything_moves(channel: str) -> None:
    cfg = sim_config(channel)
    clock = SimClock()
    with SimulatedBase.from_config(cfg, clock=clock) as sim:
        twin, close = twin_drive(clock, channel, 3)
        try:
            with pytest.raises(DriveError) as err:
                Chassis.open(cfg, clock=clock)
            assert "node 3" in str(err.value) and "two devices" in str(err.value)
            assert all(d.state() is not State.OPERATION_ENABLED for d in [*sim.drives, twin])
        finally:
            close()


# ---------------------------------------------------------------- 8: storms


def test_an_emcy_storm_is_summarised_not_logged_frame_by_frame(
        rig: Any, caplog: pytest.LogCaptureFixture) -> None:
    _, _, sender, _sim, base = rig
    caplog.set_level(logging.INFO, logger="omnican")
    sender.every(0.001, EMCY_BASE + 2, b"\x10\x42\x08\x00\x00\x00\x00\x00")  # 1000/s, 0x4210
    sender.every(0.001, EMCY_BASE + 3, b"\x10")  # broken EMCY frames, 1000/s
    drive_for(base, 12.0, vx=0.1)
    lines = [r.getMessage() for r in caplog.records if r.name.startswith("omnican")]
    about_2 = [m for m in lines if "node 2" in m and "EMCY" in m]
    about_3 = [m for m in lines if "0x083" in m]
    assert 1 <= len(about_2) <= 5, about_2
    assert 1 <= len(about_3) <= 5, about_3
    assert any("more" in m for m in about_2), about_2
    assert len(lines) < 40, lines[:40]
