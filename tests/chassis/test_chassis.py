"""Chassis against the simulated base: motion, odometry, and every safety scenario.

Scenarios run in lock-step on a simulated clock (deterministic, faster than real
time); a few run in real time too, on the control loop's own thread, as a robot runs."""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import can
import pytest

from omnican import Chassis, ChassisConfig, Pose2D
from omnican.clock import REAL_TIME, SimClock
from omnican.errors import DriveError
from omnican.io.lockstep import LockstepBus
from omnican.protocol.cia402 import State
from omnican.record.recording import FileRecording
from omnican.sim import SimulatedBase
from tests.support.helpers import drive_for, sim_config, still, vendor_config, wait_for


@pytest.fixture
def rig(channel: str) -> Iterator[tuple[SimulatedBase, Chassis]]:
    """Simulated drives and a base in lock-step on one simulated clock."""
    cfg = sim_config(channel)
    clock = SimClock()
    with SimulatedBase.from_config(cfg, clock=clock) as sim, \
            Chassis.open(cfg, clock=clock) as base:
        yield sim, base


@pytest.fixture
def realtime_rig(channel: str) -> Iterator[tuple[SimulatedBase, Chassis]]:
    cfg = sim_config(channel)
    with SimulatedBase.from_config(cfg) as sim, Chassis.open(cfg) as base:
        yield sim, base


def lockstep(cfg: ChassisConfig, **sim_options: Any) -> tuple[SimClock, Any, Any]:
    """(clock, simulated base, chassis opener) on one simulated clock."""
    clock = SimClock()
    return (clock, SimulatedBase.from_config(cfg, clock=clock, **sim_options),
            lambda: Chassis.open(cfg, clock=clock))


@pytest.mark.parametrize("rig_name", ["rig", "realtime_rig"])
def test_drives_and_odometry_follows_truth(request: pytest.FixtureRequest,
                                           rig_name: str) -> None:
    sim, base = request.getfixturevalue(rig_name)
    assert base.status.enabled
    assert all(w.state is State.OPERATION_ENABLED for w in base.wheels)
    drive_for(base, 0.8, vx=0.3, wz=0.4)
    base.stop()
    assert wait_for(lambda: still(sim), 2.0, clock=sim.clock)
    sim.clock.sleep(0.05)
    truth, pose = sim.true_pose, base.pose
    assert truth.x > 0.1
    assert pose.distance_to(truth) < 0.005
    assert pose.theta == pytest.approx(truth.theta, abs=0.005)
    assert base.status.loop_hz == pytest.approx(100, rel=0.2)


def test_watchdog_stops_without_commands(rig: tuple[SimulatedBase, Chassis]) -> None:
    sim, base = rig
    base.set_velocity(0.4, 0.0, 0.0)  # once, then silence
    assert wait_for(lambda: sim.true_twist.vx > 0.2, 1.0, clock=sim.clock)
    assert wait_for(lambda: still(sim), 0.5 + 0.4 / 2.0 + 0.5, clock=sim.clock)
    assert base.status.command_age_s > 0.5
    assert base.status.enabled and base.status.stopped_reason is None  # not latched
    drive_for(base, 0.3, vx=0.2)
    assert sim.true_twist.vx > 0.1  # a new command moves again


def test_halt_holds_the_base_stopped_until_recover(rig: tuple[SimulatedBase, Chassis]) -> None:
    sim, base = rig
    drive_for(base, 0.4, vx=0.3)
    assert base.stopped_reason is None
    base.halt("stopped over Zenoh by the fleet")
    assert wait_for(lambda: still(sim), 0.3 / 2.0 + 0.5, clock=sim.clock)
    assert base.status.stopped_reason == "stopped over Zenoh by the fleet"
    assert base.stopped_reason == base.status.stopped_reason  # the same, without the rest
    drive_for(base, 0.3, vx=0.3)  # a command after the halt moves nothing
    assert still(sim)
    base.halt("a second halt")  # the first reason stays
    sim.clock.sleep(0.05)
    assert base.status.stopped_reason == "stopped over Zenoh by the fleet"
    base.recover()
    assert base.status.stopped_reason is None and base.stopped_reason is None
    drive_for(base, 0.3, vx=0.3)
    assert sim.true_twist.vx > 0.1


def test_fault_stops_all_wheels_until_recover(rig: tuple[SimulatedBase, Chassis]) -> None:
    sim, base = rig
    drive_for(base, 0.4, vy=0.3)
    sim.drives[0].inject_fault(0x2310)
    assert wait_for(lambda: base.status.stopped_reason is not None, 1.0, clock=sim.clock)
    assert base.status.stopped_reason == "node 1 fault: 0x2310 continuous over-current"
    assert base.wheels[0].fault == "0x2310 continuous over-current"
    assert wait_for(lambda: base.wheels[0].state is State.FAULT, 1.0,
                    clock=sim.clock)  # after the reaction
    assert wait_for(lambda: still(sim), 1.5, clock=sim.clock)
    drive_for(base, 0.3, vy=0.3)  # commands are ignored while stopped
    assert still(sim)
    base.recover()
    assert base.status.enabled and base.wheels[0].state is State.OPERATION_ENABLED
    assert base.wheels[0].fault is None
    sim.clock.sleep(0.1)
    assert still(sim)  # no motion until a new command
    drive_for(base, 0.3, vy=0.3)
    assert sim.true_twist.vy > 0.1



def test_at_1_khz_a_fault_zeroes_every_target_in_the_cycle_that_sees_it(channel: str) -> None:
    """Above 250 Hz the fault latch is checked every few cycles, not every cycle; the
    stop itself must not wait for it: the cycle whose statusword shows the drive out
    of OPERATION ENABLED already sends 0 to every wheel."""
    clock, sim, open_base = lockstep(sim_config(channel, rate_hz=1000.0))
    with sim, open_base() as base:
        drive_for(base, 0.2, vx=0.3, wz=0.5)
        assert all(abs(w.target_speed) > 0.05 for w in base.wheels)
        sim.drives[0].inject_fault(0x2310)
        seen_at = latched_at = None
        for _ in range(50):
            clock.sleep(0.001)  # one cycle
            wheels, status = base.wheels, base.status
            if wheels[0].state is not State.OPERATION_ENABLED:
                assert [w.target_speed for w in wheels] == [0.0, 0.0, 0.0]
                seen_at = seen_at if seen_at is not None else status.cycles
            if status.stopped_reason is not None and latched_at is None:
                latched_at = status.cycles
                assert status.stopped_reason == "node 1 fault: 0x2310 continuous over-current"
        assert seen_at is not None and latched_at is not None
        assert 0 <= latched_at - seen_at < 4  # checked every 4th cycle at 1 kHz
        assert [w.target_speed for w in base.wheels] == [0.0, 0.0, 0.0]

def test_heartbeat_loss_stops_all(rig: tuple[SimulatedBase, Chassis]) -> None:
    sim, base = rig
    drive_for(base, 0.3, vx=0.3)
    sim.drives[1].stop_heartbeat()
    assert wait_for(lambda: base.status.stopped_reason == "node 2 heartbeat lost", 1.0, clock=sim.clock)
    assert not base.wheels[1].online
    assert wait_for(lambda: still(sim), 1.5, clock=sim.clock)
    with pytest.raises(DriveError, match="not enabled"):
        base.recover(timeout_s=0.3)  # the node is still silent
    sim.drives[1].start_heartbeat()
    base.recover()
    assert base.status.enabled


def test_frozen_node_is_a_lost_heartbeat(rig: tuple[SimulatedBase, Chassis]) -> None:
    sim, base = rig
    drive_for(base, 0.2, vx=0.2)
    sim.drives[2].freeze()
    assert wait_for(lambda: base.status.stopped_reason == "node 3 heartbeat lost", 1.0, clock=sim.clock)
    sim.drives[2].thaw()


def test_reboot_reconfigures_without_motion_or_odometry_jump(
        rig: tuple[SimulatedBase, Chassis]) -> None:
    sim, base = rig
    clock = sim.clock
    drive_for(base, 0.5, vx=0.3)
    base.stop()
    assert wait_for(lambda: still(sim), 1.0, clock=clock)
    clock.sleep(0.05)
    before = base.pose
    sim.drives[2].reboot()
    assert wait_for(lambda: base.status.stopped_reason == "node 3 rebooted", 1.0, clock=clock)
    assert wait_for(lambda: base.wheels[2].online and base.wheels[2].state is not State.UNKNOWN,
                    3.0, clock=clock)  # re-configured automatically
    assert sim.drives[2].nmt_state == "OPERATIONAL"
    drive_for(base, 0.3, vx=0.3)
    assert still(sim)  # no motion before recover()
    base.recover()
    clock.sleep(0.1)
    assert still(sim)  # nor right after it
    assert base.pose.distance_to(before) < 1e-3  # no odometry jump from the counter reset
    drive_for(base, 0.4, vx=0.3)
    base.stop()
    assert wait_for(lambda: still(sim), 1.0, clock=clock)
    clock.sleep(0.05)
    assert base.pose.x - before.x == pytest.approx(sim.true_pose.x - before.x, abs=0.01)


@pytest.mark.parametrize("realtime", [False, True])
def test_leaving_the_block_disables_every_drive(channel: str, realtime: bool) -> None:
    cfg = sim_config(channel)
    clock = REAL_TIME if realtime else SimClock()
    with SimulatedBase.from_config(cfg, clock=clock) as sim:
        with Chassis.open(cfg, clock=clock) as base:
            drive_for(base, 0.3, vx=0.4)
        assert [d.state() for d in sim.drives] == [State.SWITCH_ON_DISABLED] * 3
        assert still(sim)
        assert [d.nmt_state for d in sim.drives] == ["PRE-OPERATIONAL"] * 3


def test_exception_in_block_disables_every_drive(channel: str) -> None:
    _clock, simulated, opener = lockstep(sim_config(channel))
    with simulated as sim:
        with pytest.raises(KeyboardInterrupt), opener() as base:
            drive_for(base, 0.2, vx=0.4)
            raise KeyboardInterrupt
        assert [d.state() for d in sim.drives] == [State.SWITCH_ON_DISABLED] * 3


def test_nan_and_inf_are_rejected(rig: tuple[SimulatedBase, Chassis]) -> None:
    sim, base = rig
    for bad in ((math.nan, 0, 0), (0, math.inf, 0), (0, 0, -math.inf)):
        with pytest.raises(ValueError, match="finite"):
            base.set_velocity(*bad)
    sim.clock.sleep(0.1)
    assert still(sim) and base.status.enabled


def test_foreign_traffic_is_ignored(rig: tuple[SimulatedBase, Chassis], channel: str) -> None:
    sim, base = rig
    clock = sim.clock
    other = LockstepBus(channel, clock)
    try:
        for i in range(200):
            other.send(can.Message(arbitration_id=0x123 + i % 7, data=bytes([i % 256] * 8),
                                   is_extended_id=False))
            other.send(can.Message(arbitration_id=0x1ABCDEF, data=b"\xff", is_extended_id=True))
            other.send(can.Message(arbitration_id=0x281, data=b"\x01", is_extended_id=False))
            base.set_velocity(0.2, 0.0, 0.0)
            clock.sleep(0.002)
    finally:
        other.shutdown()
    assert base.status.enabled and base.status.stopped_reason is None
    base.stop()
    assert wait_for(lambda: still(sim), 1.0, clock=clock)
    clock.sleep(0.05)
    assert base.pose.distance_to(sim.true_pose) < 0.005


def test_reset_pose(rig: tuple[SimulatedBase, Chassis]) -> None:
    _, base = rig
    base.reset_pose(Pose2D(1.0, 2.0, 0.5))
    assert base.pose == Pose2D(1.0, 2.0, 0.5)


def test_limits_change_live_from_the_next_cycle(rig: tuple[SimulatedBase, Chassis]) -> None:
    """set_limits: a lower max_speed caps the motion from the next cycle on (the truth
    says so, not the limiter), a higher one lets it go faster again, and the base keeps
    running throughout."""
    sim, base = rig
    drive_for(base, 1.0, vx=0.4)
    assert sim.true_twist.vx == pytest.approx(0.4, abs=0.02)
    settings = base.set_limits(max_speed=0.15, max_accel=0.8)
    assert (settings.max_speed, settings.max_accel) == (0.15, 0.8)
    assert base.cfg.chassis is settings
    drive_for(base, 0.6, vx=0.4)
    assert sim.true_twist.vx == pytest.approx(0.15, abs=0.01)
    assert base.command.vx == pytest.approx(0.15)
    base.set_limits(max_speed=math.inf)
    drive_for(base, 0.6, vx=0.4)
    assert sim.true_twist.vx == pytest.approx(0.4, abs=0.02)
    assert base.status.enabled and base.status.stopped_reason is None


@pytest.mark.parametrize(("changes", "message"), [
    ({"max_accel": -1.0}, "live: chassis.max_accel: must be a positive number, got -1.0"),
    ({"max_speed": math.nan}, "live: chassis.max_speed: must be a number, got nan"),
    ({"max_accel": math.inf}, "live: chassis.max_accel: must be a positive number, got inf"),
    ({"stop_decel": True}, "live: chassis.stop_decel: must be a number, got True"),
    ({"max_angular_speed": "fast"}, "chassis.max_angular_speed: must be a number, got 'fast'"),
    ({"rate_hz": 50.0}, "live: chassis.rate_hz: cannot change while the base runs"),
    ({"max_sped": 1.0}, "live: chassis.max_sped: unknown key"),
    ({"max_wheel_speed": 1.5}, "chassis.max_wheel_speed: at most 1 m/s, the value the base "
                               "was opened with"),
    ({"max_accel": 1.5}, "chassis.max_accel: at most 1 m/s^2, the value the base was opened "
                         "with"),
    ({"stop_decel": 0.5}, "chassis.stop_decel: at least 2 m/s^2, the value the base was "
                          "opened with (a live value may only shorten a stop"),
    ({"stop_angular_decel": 1e-6}, "chassis.stop_angular_decel: must be 0.001-200, got 1e-06"),
    ({"max_speed": 1e9}, "live: chassis.max_speed: must be 0.001-100 or inf, got 1e+09"),
])
def test_a_refused_limit_says_why_and_changes_nothing(
        rig: tuple[SimulatedBase, Chassis], changes: dict[str, Any], message: str) -> None:
    sim, base = rig
    before = base.cfg.chassis
    with pytest.raises(ValueError) as info:
        base.set_limits(**{"max_angular_accel": 1.0, **changes})  # a good one beside: not applied
    assert message in str(info.value)
    assert base.cfg.chassis is before
    drive_for(base, 0.8, vx=0.3)
    assert sim.true_twist.vx == pytest.approx(0.3, abs=0.02)


@pytest.mark.parametrize("realtime", [False, True])
def test_recording(channel: str, tmp_path: Path, realtime: bool) -> None:
    cfg = sim_config(channel)
    log = tmp_path / "run.log"
    clock = REAL_TIME if realtime else SimClock()
    with SimulatedBase.from_config(cfg, clock=clock), \
            Chassis.open(cfg, record=FileRecording(log), clock=clock) as base:
        drive_for(base, 0.2, vx=0.2)
    frames = list(can.LogReader(str(log)))
    ids = {m.arbitration_id for m in frames}
    assert {0x80, 0x201, 0x281, 0x181, 0x77F, 0x701} <= ids  # SYNC, RPDO, TPDOs, heartbeats
    assert any(not m.is_rx for m in frames) and any(m.is_rx for m in frames)


def test_blf_recording_of_a_channel_named_with_big_digits(channel: str, tmp_path: Path) -> None:
    """BLF keeps a 16-bit channel number from the name's trailing digits; a name ending
    in 123456789 must neither break the recording nor stop reception."""
    cfg = sim_config(f"{channel}-123456789")
    log = tmp_path / "run.blf"
    with SimulatedBase.from_config(cfg) as sim, Chassis.open(cfg, record=FileRecording(log)) as base:
        drive_for(base, 0.3, vx=0.2)
        assert base.status.enabled and sim.true_twist.vx > 0.1
    frames = list(can.LogReader(str(log)))
    assert {0x80, 0x201, 0x281} <= {m.arbitration_id for m in frames}


@pytest.mark.parametrize("layout", ["zlac", "roboteq", "epos4"])
def test_vendor_layouts_drive_and_track_truth(channel: str, layout: str) -> None:
    clock, simulated, opener = lockstep(vendor_config(channel, layout))
    with simulated as sim, opener() as base:
        assert base.status.enabled
        if layout == "zlac":
            assert any("no heartbeat consumer" in w for w in base.status.warnings)
        drive_for(base, 0.6, vx=0.2, vy=-0.1, wz=0.3)
        base.stop()
        assert wait_for(lambda: still(sim), 2.0, clock=clock)
        clock.sleep(0.05)
        assert sim.true_pose.x > 0.05
        assert base.pose.distance_to(sim.true_pose) < 0.005
        assert base.pose.theta == pytest.approx(sim.true_pose.theta, abs=0.01)


def test_drive_that_refuses_remapping_uses_its_mapping(channel: str) -> None:
    clock, simulated, opener = lockstep(vendor_config(channel, "epos4"), remappable=False)
    with simulated as sim, opener() as base:
        assert any("refuses remapping" in w for w in base.status.warnings)
        drive_for(base, 0.4, vx=0.2)
        base.stop()
        assert wait_for(lambda: still(sim), 2.0, clock=clock)
        clock.sleep(0.05)
        assert base.pose.distance_to(sim.true_pose) < 0.005


@pytest.mark.parametrize("mode", ["csv", "vl"])
def test_other_modes(channel: str, mode: str) -> None:
    from omnican.protocol.cia402 import Mode
    cfg = sim_config(channel)
    m = Mode.from_name(mode)
    if mode == "vl":  # 6042h is INTEGER16 (rpm): a coarser velocity unit
        wheels = tuple(replace(w, mode=m, velocity_scale=w.velocity_scale / 1000.0)
                       for w in cfg.wheels)
    else:
        wheels = tuple(replace(w, mode=m) for w in cfg.wheels)
    _clock, simulated, opener = lockstep(replace(cfg, wheels=wheels))
    with simulated as sim, opener() as base:
        assert {w.mode for w in base.wheels} == {int(m)}
        drive_for(base, 0.5, vx=0.25)
        assert sim.true_twist.vx == pytest.approx(0.25, rel=0.05)


def test_encoder_wrap_around_keeps_odometry(channel: str) -> None:
    cfg = sim_config(channel)
    counts_per_m = cfg.wheels[0].position_scale
    near = 2**31 - int(0.05 * counts_per_m)  # wraps after 5 cm of rim travel
    clock, simulated, opener = lockstep(cfg, initial_position=near)
    with simulated as sim, opener() as base:
        drive_for(base, 0.8, vx=0.4)
        base.stop()
        assert wait_for(lambda: still(sim), 2.0, clock=clock)
        clock.sleep(0.05)
        assert sim.true_pose.x > 0.2
        assert base.pose.distance_to(sim.true_pose) < 0.005


def test_missing_node_fails_with_a_clear_error(channel: str) -> None:
    cfg = sim_config(channel, boot_timeout_s=0.3)
    with SimulatedBase.from_config(cfg) as sim:
        sim.drives[1].freeze()
        with pytest.raises(DriveError, match=r"node 2: no boot-up within 0.3 s"):
            Chassis.open(cfg)


def test_drive_stuck_in_fault_at_startup_is_reset(channel: str) -> None:
    _clock, simulated, opener = lockstep(sim_config(channel))
    with simulated as sim:
        sim.drives[0].inject_fault(0x3210)
        with opener() as base:
            assert base.status.enabled


def test_lockstep_runs_are_identical(channel: str, tmp_path: Path) -> None:
    """The same scripted run on a simulated clock, twice, with seeded frame loss and
    encoder noise: the same odometry to the last bit, the same recording."""
    results = []
    for run in (1, 2):
        cfg = sim_config(channel)
        log = tmp_path / f"run{run}.log"
        clock = SimClock()
        with SimulatedBase.from_config(cfg, clock=clock, frame_loss=0.02, encoder_noise=2.0,
                                       seed=7) as sim, \
                Chassis.open(cfg, clock=clock, record=FileRecording(log)) as base:
            drive_for(base, 1.0, vx=0.3, wz=0.5)
            sim.drives[1].inject_fault(0x2310)
            clock.sleep(0.3)
            base.recover()
            drive_for(base, 0.5, vy=0.2)
            results.append((base.pose, sim.true_pose, base.status.stopped_reason))
        results.append(tuple(line.split(maxsplit=1)[1] for line in
                             log.read_text().splitlines()))  # frames without timestamps
    assert results[0] == results[2]
    assert results[1] == results[3]
