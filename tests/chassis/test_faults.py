"""Fault paths inside one process: a bus that goes down (sends, receives, a full
transmit queue) and comes back, stale measurements, and the races between the
Notifier, the control loop and the configuration workers."""

from __future__ import annotations

import errno
import sys
import threading
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import can
import pytest

from omnican import Chassis
from omnican.clock import SimClock
from omnican.io.bus import CanBus
from omnican.protocol.cia402 import State
from omnican.record.recording import FileRecording
from omnican.sim import SimulatedBase
from tests.support.flaky_bus import FlakyBus, register
from tests.support.helpers import drive_for, sim_config, still, wait_for


@pytest.fixture
def flaky(channel: str) -> Iterator[tuple[SimulatedBase, Chassis]]:
    """A base whose bus (the host's side only) can be made to fail."""
    iface = register()
    FlakyBus.reset()
    cfg = sim_config(channel)
    host_cfg = replace(cfg, bus={"interface": iface, "channel": channel})
    try:
        with SimulatedBase.from_config(cfg) as sim, Chassis.open(host_cfg) as base:
            yield sim, base
    finally:
        FlakyBus.reset()


def bus_down(base: Chassis) -> bool:
    return not base.status.bus_up and (base.status.stopped_reason or "").startswith(
        "CAN bus down")


# ---------------------------------------------------------------- bus down and back


def test_reception_resumes_after_the_bus_is_reopened(
        flaky: tuple[SimulatedBase, Chassis]) -> None:
    sim, base = flaky
    drive_for(base, 0.3, vx=0.3)
    FlakyBus.failing = True
    assert wait_for(lambda: bus_down(base), 1.0)
    assert "interface is down" in (base.status.bus_error or "")
    assert wait_for(lambda: still(sim), 1.5)  # the drives' own heartbeat consumers
    opened = FlakyBus.opened
    assert wait_for(lambda: FlakyBus.opened > opened, 2.5)  # it tried to reopen the bus
    FlakyBus.failing = False
    assert wait_for(lambda: base.status.bus_up, 3.0)
    base.recover()
    x0 = base.pose.x
    drive_for(base, 0.5, vx=0.3)
    # What the host *receives* moves again: the odometry and the measured twist.
    assert base.twist.vx > 0.2
    assert base.pose.x > x0 + 0.08
    assert not any(w.stale for w in base.wheels)


def test_receive_failure_is_the_bus_down(flaky: tuple[SimulatedBase, Chassis]) -> None:
    _sim, base = flaky
    drive_for(base, 0.3, vx=0.3)
    FlakyBus.rx_failing = True
    assert wait_for(lambda: bus_down(base), 1.0)
    assert "receive failed" in (base.status.stopped_reason or "")
    FlakyBus.rx_failing = False
    assert wait_for(lambda: base.status.bus_up, 3.0)
    base.recover()
    drive_for(base, 0.3, vx=0.3)
    assert base.twist.vx > 0.2


def test_transmit_queue_full_is_reported_and_recovered(
        flaky: tuple[SimulatedBase, Chassis]) -> None:
    sim, base = flaky
    drive_for(base, 0.3, vx=0.3)
    FlakyBus.failing_errno = errno.ENOBUFS
    FlakyBus.failing = True
    assert wait_for(lambda: bus_down(base), 1.0)
    assert "transmit queue full" in (base.status.stopped_reason or "")
    dropped = base.bus.dropped_frames
    assert dropped > 0
    assert wait_for(lambda: still(sim), 1.5)
    FlakyBus.failing = False
    assert wait_for(lambda: base.status.bus_up, 3.0)
    base.recover()
    drive_for(base, 0.3, vx=0.3)
    assert sim.true_twist.vx > 0.2


def test_reopening_the_bus_never_blocks_the_control_loop(
        flaky: tuple[SimulatedBase, Chassis]) -> None:
    _sim, base = flaky
    FlakyBus.open_delay_s = 1.5
    FlakyBus.failing = True
    assert wait_for(FlakyBus.opening.is_set, 3.0)  # a reopening is under way, and slow
    cycles = base.status.cycles
    assert wait_for(lambda: base.status.cycles > cycles + 20, 1.0)
    assert FlakyBus.opening.is_set()  # the loop ran on while the reopening still waited
    # The old bus is closed meanwhile; what the status says is still why it went down.
    assert "interface is down" in (base.status.bus_error or "")
    FlakyBus.failing = False
    assert wait_for(lambda: base.status.bus_up, 4.0)


# ---------------------------------------------------------------- stale values


def test_speeds_of_a_silent_drive_are_not_shown_as_live(channel: str) -> None:
    cfg = sim_config(channel)
    clock = SimClock()
    with SimulatedBase.from_config(cfg, clock=clock) as sim, \
            Chassis.open(cfg, clock=clock) as base:
        drive_for(base, 0.5, vx=0.3)
        assert base.twist.vx > 0.25
        sim.drives[1].freeze()  # node 2 goes silent
        assert wait_for(lambda: base.wheels[1].stale, 1.0, clock=clock)
        assert base.wheels[1].actual_speed == 0.0
        assert base.twist.vx == 0.0  # unknown, not +0.300 as if it were live
        assert wait_for(lambda: base.status.stopped_reason == "node 2 heartbeat lost", 1.0,
                        clock=clock), base.status
        assert not base.wheels[1].online and base.wheels[1].actual_speed == 0.0
        sim.drives[1].thaw()
        # Back, it finds it missed the host's heartbeats while it hung, and stops.
        assert wait_for(lambda: sim.drives[1].state() is State.SWITCH_ON_DISABLED, 1.0,
                        clock=clock)
        base.recover()
        drive_for(base, 0.5, vx=0.3)
        assert not base.wheels[1].stale and base.twist.vx > 0.25, base.status


# ---------------------------------------------------------------- races


def test_subscription_changes_never_skip_a_callback(channel: str) -> None:
    """A handler unsubscribed on one thread while the Notifier runs the callbacks of the
    same COB-ID must not make it skip the next one."""
    with CanBus({"interface": "virtual", "channel": channel}) as bus:
        net = bus.network
        called: list[str] = []

        def first(can_id: int, data: bytearray, ts: float) -> None:
            called.append("first")
            net.unsubscribe(0x181, first)  # what a re-configuration does, mid-notify

        def second(can_id: int, data: bytearray, ts: float) -> None:
            called.append("second")

        net.subscribe(0x181, first)
        net.subscribe(0x181, second)
        net.notify(0x181, bytearray(2), 0.0)
        assert called == ["first", "second"]
        net.notify(0x181, bytearray(2), 0.0)
        assert called == ["first", "second", "second"]


def test_traffic_counts_are_exact_from_two_threads(channel: str) -> None:
    """Frames sent by the loop and frames received on the Notifier are counted on two
    threads into the same totals: none may be lost."""
    with CanBus({"interface": "virtual", "channel": channel}) as bus:
        traffic = bus.traffic
        base_frames, base_bits = traffic.frames, traffic.bits
        n = 50_000
        msg = can.Message(arbitration_id=0x181, data=bytes(8))
        old = sys.getswitchinterval()
        sys.setswitchinterval(1e-6)  # switch threads as often as possible
        try:
            rx = threading.Thread(target=lambda: [traffic.on_message_received(msg)
                                                  for _ in range(n)])
            rx.start()
            for _ in range(n):
                bus._sent(0x201, bytes(8))
            rx.join()
        finally:
            sys.setswitchinterval(old)
        assert traffic.frames - base_frames == 2 * n
        assert traffic.bits - base_bits == 2 * n * 135


def test_a_reboot_during_reconfiguration_is_not_lost(
        flaky: tuple[SimulatedBase, Chassis]) -> None:
    """Node 1 reboots; while omnican configures it again, it reboots once more (after
    the boot-up omnican waited for). That second reboot undid part of the configuration:
    omnican must notice and configure the node again, not lose the event."""
    sim, base = flaky
    node = base.nodes[0]
    drive = sim.drives[0]
    original = node._sdo_config._configure_ramps
    rebooted_again = threading.Event()

    def ramps_then_reboot(*args: Any) -> None:
        original(*args)
        if not rebooted_again.is_set():
            rebooted_again.set()
            drive.reboot()  # mode and ramps written so far are gone

    node._sdo_config._configure_ramps = ramps_then_reboot  # type: ignore[method-assign]
    drive.reboot()
    assert wait_for(rebooted_again.is_set, 3.0)
    assert wait_for(lambda: node.node_id not in base._supervisor.configuring and not node.rebooted, 5.0)
    base.recover()
    assert base.status.enabled
    mode = int.from_bytes(drive.read(0x6060), "little", signed=True)
    assert mode == int(node.mode)  # configured after the second boot too
    drive_for(base, 0.3, vx=0.3)
    assert sim.true_twist.vx > 0.2
    assert all(w.state is State.OPERATION_ENABLED for w in base.wheels)


def test_a_reboot_during_startup_configuration_is_not_lost(
        channel: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """Node 2 reboots in the middle of its first configuration: what was written before
    is gone, so it must be configured again before the base reports itself enabled."""
    from omnican.drive.sdo_config import SdoConfig

    cfg = sim_config(channel)
    original = SdoConfig._configure_ramps
    rebooted = threading.Event()
    with SimulatedBase.from_config(cfg) as sim:
        drive = sim.drives[1]

        def ramps_then_reboot(self: SdoConfig) -> None:
            original(self)
            if self.node.node_id == 2 and not rebooted.is_set():
                rebooted.set()
                drive.reboot()

        monkeypatch.setattr(SdoConfig, "_configure_ramps", ramps_then_reboot)
        with Chassis.open(cfg) as base:
            assert rebooted.is_set()
            node = base.nodes[1]
            assert not node.rebooted
            mode = int.from_bytes(drive.read(0x6060), "little", signed=True)
            assert mode == int(node.mode)
            accel = int.from_bytes(drive.read(0x6083), "little")
            assert accel != 0  # the profile acceleration written after the reboot
            drive_for(base, 0.3, vx=0.3)
            assert sim.true_twist.vx > 0.2


def test_a_stalled_disk_never_stalls_the_control_loop(channel: str, tmp_path: Path) -> None:
    """The recorder writes on a thread of its own: while its writes hang (a slow SD card),
    the loop keeps its cycles and nothing recorded is lost."""
    cfg = sim_config(channel)
    log = tmp_path / "run.log"
    with SimulatedBase.from_config(cfg), Chassis.open(cfg, record=FileRecording(log)) as base:
        recorder = base.bus.recorder
        assert recorder is not None
        writer = recorder._writer
        assert writer is not None
        stall = threading.Event()
        write = writer.on_message_received

        def slow(msg: can.Message) -> None:
            stall.wait(5.0)
            write(msg)

        writer.on_message_received = slow  # type: ignore[method-assign]
        cycles = base.status.cycles
        assert wait_for(lambda: base.status.cycles > cycles + 50, 3.0)  # the loop runs on
        assert not stall.is_set()
        stall.set()
        drive_for(base, 0.2, vx=0.1)
    frames = list(can.LogReader(str(log)))
    assert sum(1 for m in frames if m.arbitration_id == 0x80) >= 50  # every SYNC written
