"""What the drives know, end to end in lock-step against the simulator: the health values
each wheel shows, and each detection's stop: a wheel not following its target (jammed,
pushed, a following error), the e-stop, a low battery, a bus-off controller."""

from __future__ import annotations

import logging
import math
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import can
import pytest

from omnican import Chassis, ChassisConfig, load_config
from omnican.chassis.state import Snapshot, StatusChecks
from omnican.clock import SimClock
from omnican.errors import DriveError
from omnican.io.lockstep import LockstepBus
from omnican.plan.health_fields import health_values
from omnican.protocol import can_state as cs
from omnican.protocol.cia402 import State
from omnican.sim import SimulatedBase
from tests.support.helpers import drive_for, lockstep_rig, sim_config, still, wait_for
from tests.support.shared_bus import bus_args, shared_bus

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
Rig = tuple[SimClock, SimulatedBase, Chassis]


@pytest.fixture
def rig(channel: str) -> Iterator[Rig]:
    with lockstep_rig(channel) as r:
        yield r


def stopped_for(base: Chassis, text: str, seconds: float, **velocity: float) -> str:
    """Command ``velocity`` until the base is held stopped for a reason containing
    ``text`` (at most ``seconds``); that reason."""
    clock = base.clock
    end = clock.now() + seconds
    while text not in (base.status.stopped_reason or "") and clock.now() < end:
        base.set_velocity(velocity.get("vx", 0.0), velocity.get("vy", 0.0),
                          velocity.get("wz", 0.0))
        clock.sleep(0.02)
    reason = base.status.stopped_reason
    assert reason is not None and text in reason, base.status
    return reason


def test_each_wheel_shows_its_current_torque_voltage_and_temperature(rig: Rig) -> None:
    clock, sim, base = rig
    clock.sleep(0.3)
    idle = base.wheels
    assert all(w.current_a == 0.0 and w.voltage_v == pytest.approx(24.0) for w in idle)
    assert all(w.temperature_c == pytest.approx(25.0) and w.error_register == 0 for w in idle)
    assert base.status.battery_v == pytest.approx(24.0) and not base.status.estop
    # Accelerating hard (wheel 0 stands still going straight ahead: wheels 1 and 2 move).
    peak = [0.0, 0.0, 0.0]
    for _ in range(20):
        base.set_velocity(0.5, 0.0, 0.0)
        clock.sleep(0.02)
        for w in base.wheels:
            peak[w.index] = max(peak[w.index], abs(w.current_a or 0.0))
    drive_for(base, 1.0, vx=0.5)
    cruise = base.wheels
    for i in (1, 2):
        assert abs(cruise[i].current_a or 0.0) > 0.3  # friction and the ground's load
        assert peak[i] > abs(cruise[i].current_a or 0.0) + 0.3  # and the base's inertia
        # 6077h and 6078h: per mille of the rated 5 A, the same current.
        assert cruise[i].torque_pct == pytest.approx(100 * (cruise[i].current_a or 0) / 5.0,
                                                     abs=0.11)
        assert cruise[i].voltage_v is not None and cruise[i].voltage_v < 24.0  # it sags
        truth = sim.drives[i].current_a()
        assert cruise[i].current_a == pytest.approx(truth, abs=0.01)
    assert base.status.battery_v is not None and 23.5 < base.status.battery_v < 24.0
    assert base.status.stopped_reason is None


def test_a_jammed_wheel_stops_the_base_and_names_itself(rig: Rig) -> None:
    clock, sim, base = rig
    drive_for(base, 0.8, vx=0.3)
    sim.drives[2].jam()
    t0 = clock.now()
    reason = stopped_for(base, "wheel 2 (node 3) not following its target for 0.5 s", 2.0,
                         vx=0.3)
    assert "stalled, slipping or off the ground" in reason
    assert 0.5 <= clock.now() - t0 < 0.8  # the time it must last, and a check or two
    assert wait_for(lambda: still(sim), 2.0, clock=clock)
    sim.drives[2].free()
    base.recover()
    drive_for(base, 0.5, vx=0.3)
    assert base.status.stopped_reason is None and base.twist.vx > 0.2


def test_a_base_that_does_not_move_at_a_slow_command_is_stopped(rig: Rig) -> None:
    """(Issue 36, item 3) Every wheel jammed under a 0.1 m/s command: the wheels' targets
    (0.087 m/s) are under tracking_error (0.1 m/s), but a wheel at under half its target
    is not following: the stop names the wheel, its target and its speed."""
    _, sim, base = rig
    for drive in sim.drives:
        drive.jam()
    reason = stopped_for(base, "not following its target", 3.0, vx=0.1)
    assert reason == ("wheel 1 (node 2) not following its target for 0.5 s: stalled, "
                      "slipping or off the ground (target +0.09 m/s, measured +0.00 m/s, "
                      "under 50% of its target)")
    assert base.pose.x == 0.0


def test_a_wheel_turning_with_a_zero_target_is_stopped_and_its_drive_disabled(rig: Rig
                                                                               ) -> None:
    clock, sim, base = rig
    clock.sleep(0.5)  # enabled, standing
    sim.drives[1].push(0.2)
    reason = stopped_for(base, "wheel 1 (node 2) not following its target", 2.0)
    assert "turns at +0.20 m/s with a zero target (pushed, or a runaway drive)" in reason
    assert wait_for(lambda: sim.drives[1].state() is State.SWITCH_ON_DISABLED, 1.0, clock=clock)
    sim.drives[1].free()
    base.recover()
    assert base.status.enabled


def test_a_stopped_base_disables_and_names_a_wheel_that_turns(rig: Rig) -> None:
    """Issue 30.1: held stopped (a reboot latched it), wheel 0 is pushed. Its drive, still
    enabled, is disabled as soon as on a running base (the stop has settled), and the
    stop names it after the first reason."""
    clock, sim, base = rig
    clock.sleep(0.5)
    sim.drives[2].reboot()
    clock.sleep(2)
    assert base.status.stopped_reason == "node 3 rebooted"
    assert sim.drives[0].state() is State.OPERATION_ENABLED  # held at zero, energised
    sim.drives[0].push(0.2)
    t0 = clock.now()
    assert wait_for(lambda: sim.drives[0].state() is State.SWITCH_ON_DISABLED, 5.0, clock=clock)
    assert clock.now() - t0 < 1.0  # settled: as on a running base (0.5 s, and a check)
    reason = base.status.stopped_reason or ""
    assert reason.startswith("node 3 rebooted; wheel 0 (node 1) turns at +0.20 m/s while the "
                             "base is stopped"), reason
    assert reason.endswith("its drive disabled")
    assert sim.drives[1].state() is State.OPERATION_ENABLED  # the still one is left alone
    sim.drives[0].free()
    base.recover()
    drive_for(base, 0.5, vx=0.3)
    assert base.status.stopped_reason is None and base.twist.vx > 0.2


def test_a_stop_from_full_speed_names_no_wheel(rig: Rig) -> None:
    """The wheels of a base stopped at full speed (a drive rebooted: the others' targets
    drop to zero at once, their own ramps stop them) are not taken for runaways."""
    clock, sim, base = rig
    drive_for(base, 2.5, wz=9.0)  # every wheel at its limit
    assert min(abs(w.actual_speed) for w in base.wheels) > 0.9
    sim.drives[2].reboot()
    clock.sleep(4.0)
    assert base.status.stopped_reason == "node 3 rebooted"
    assert [sim.drives[i].state() for i in (0, 1)] == [State.OPERATION_ENABLED] * 2
    assert still(sim)


def test_a_following_error_the_drive_reports_stops_the_base(rig: Rig) -> None:
    _clock, sim, base = rig
    drive_for(base, 0.5, vx=0.2)
    sim.drives[0].inject_following_error(4321)
    reason = stopped_for(base, "wheel 0 (node 1) not following its target", 1.0, vx=0.2)
    assert "its drive reports a following error (statusword bit 13" in reason
    sim.drives[0].clear_following_error()
    base.recover()
    assert base.status.enabled


def test_a_wheel_off_the_ground_keeps_its_speed_on_less_current(rig: Rig) -> None:
    """Its drive follows the target as before (nothing to tell from the speeds); the
    current shows it (issue 30.3: a warning names the wheel, by default), and the base no
    longer goes where the odometry says."""
    _clock, sim, base = rig
    drive_for(base, 1.0, vx=0.4)
    on_ground = abs(base.wheels[1].current_a or 0.0)
    assert not any("off the ground" in w for w in base.status.warnings)
    sim.drives[1].lift()
    drive_for(base, 2.0, vx=0.4)
    lifted = abs(base.wheels[1].current_a or 0.0)
    assert base.status.stopped_reason is None
    assert lifted < 0.5 * on_ground and lifted > 0.0
    assert base.pose.distance_to(sim.true_pose) > 0.05
    lifted_warnings = [w for w in base.status.warnings if "off the ground" in w]
    assert len(lifted_warnings) == 1 and lifted_warnings[0].startswith(
        "wheel 1 (node 2) off the ground or without its roller: it turns on 43 % of its "
        "siblings' current ("), lifted_warnings
    sim.drives[1].land()
    drive_for(base, 0.5, vx=0.4)
    assert abs(base.wheels[1].current_a or 0.0) == pytest.approx(on_ground, rel=0.2)
    assert not any("off the ground" in w for w in base.status.warnings)


@pytest.mark.parametrize("wheel", [0, 1, 2])
def test_a_wheel_lifted_at_rest_stops_the_base_when_configured(channel: str,
                                                               wheel: int) -> None:
    """``chassis.lifted_wheel = "stop"``: lifted before the base sets off, each wheel is
    found within a square run and the stop names it."""
    cfg = sim_config(channel, lifted_wheel="stop")
    clock = SimClock()
    with SimulatedBase.from_config(cfg, clock=clock) as sim, \
            Chassis.open(cfg, clock=clock) as base:
        clock.sleep(0.3)
        sim.drives[wheel].lift()
        for vx, vy in ((0.4, 0.0), (0.0, 0.4), (-0.4, 0.0), (0.0, -0.4)):
            drive_for(base, 2.0, vx=vx, vy=vy)
            if base.status.stopped_reason is not None:
                break
        reason = base.status.stopped_reason or ""
        assert reason.startswith(f"wheel {wheel} (node {wheel + 1}) off the ground or without "
                                 "its roller: it turns on "), reason
        sim.drives[wheel].land()
        base.recover()
        for vx, vy in ((0.4, 0.0), (0.0, 0.4), (-0.4, 0.0), (0.0, -0.4)):
            drive_for(base, 2.0, vx=vx, vy=vy)
        assert base.status.stopped_reason is None


def test_the_estop_stops_the_base_and_recover_waits_for_its_release(rig: Rig) -> None:
    clock, sim, base = rig
    drive_for(base, 0.6, vx=0.3)
    sim.estop(True)
    reason = stopped_for(base, "e-stop pressed", 1.0, vx=0.3)
    assert reason == "e-stop pressed (node 1 Digital inputs (0x60FD:00) bit 16)"
    assert base.status.estop
    assert wait_for(lambda: still(sim), 2.0, clock=clock)
    with pytest.raises(DriveError, match=r"recover refused: e-stop pressed .*release it first"):
        base.recover()
    assert base.status.stopped_reason == reason
    sim.estop(False)
    clock.sleep(0.3)
    assert not base.status.estop
    base.recover()
    drive_for(base, 0.5, vx=0.3)
    assert base.twist.vx > 0.2


def test_a_low_battery_warns_then_stops_the_base_with_hysteresis(rig: Rig) -> None:
    clock, sim, base = rig
    sim.set_battery(21.5)
    drive_for(base, 1.5, vx=0.2)
    st = base.status
    assert st.stopped_reason is None
    assert any(w.startswith("battery low: 21.") for w in st.warnings), st.warnings
    sim.set_battery(19.0)
    reason = stopped_for(base, "battery", 2.0, vx=0.2)
    assert "below the cutoff 20 V (power.cutoff_v) for 1 s" in reason
    for volts in (19.5, 20.3):  # below the cutoff, then within its hysteresis
        sim.set_battery(volts)
        clock.sleep(0.3)
        with pytest.raises(DriveError, match="recover refused: battery"):
            base.recover()
    sim.set_battery(21.0)
    clock.sleep(0.3)
    base.recover()
    assert base.status.enabled


def error_frame(bus: LockstepBus, can_id: int, data: bytes = b"") -> None:
    bus.send(can.Message(arbitration_id=can_id, data=data.ljust(8, b"\0"), is_error_frame=True,
                         is_extended_id=False))


def test_the_controllers_state_and_bus_off(rig: Rig, channel: str) -> None:
    """Error frames (as SocketCAN delivers them; here on the lock-step channel): the state
    and counters in the status, bus-off a stop recover() waits out until the restart."""
    clock, _sim, base = rig
    kernel = LockstepBus(channel, clock)
    try:
        drive_for(base, 0.3, vx=0.2)
        assert base.status.can_state is None  # nothing said yet
        error_frame(kernel, cs.ERR_CRTL | cs.ERR_CNT,
                    bytes([0, cs.CRTL_TX_PASSIVE, 0, 0, 0, 0, 130, 5]))
        drive_for(base, 0.1, vx=0.2)
        st = base.status
        assert (st.can_state, st.can_tx_errors, st.can_rx_errors) == ("error-passive", 130, 5)
        assert st.stopped_reason is None  # error-passive still talks
        error_frame(kernel, cs.ERR_BUSOFF)
        reason = stopped_for(base, "CAN bus-off", 1.0, vx=0.2)
        assert "restart-ms brings it back" in reason
        with pytest.raises(DriveError, match="recover refused: the CAN controller is bus-off"):
            base.recover()
        error_frame(kernel, cs.ERR_RESTARTED)
        clock.sleep(0.1)
        assert base.status.can_state == "error-active"
        base.recover()
        drive_for(base, 0.3, vx=0.2)
        assert base.status.enabled and base.status.can_error_frames == 3
    finally:
        kernel.shutdown()


# ---------------------------------------------------------------- never on the ramp


# The simulator's drives follow their ramp with a 10 ms lag by default; 150 ms is a slow
# real drive's velocity loop, where the measurement lags the target the most.
@pytest.mark.parametrize(("rate", "loss", "seed", "tau_s", "accel"), [
    (100.0, 0.0, 0, 0.15, 1.0), (100.0, 0.05, 1, 0.15, 2.0), (100.0, 0.05, 2, 0.01, 2.0),
    (1000.0, 0.05, 3, 0.15, 2.0)])
def test_full_speed_starts_and_stops_never_latch_a_tracking_stop(
        channel: str, rate: float, loss: float, seed: int, tau_s: float, accel: float) -> None:
    """At the configured accelerations (and the steeper stop), with frames lost, on a
    drive with a slow velocity loop: starts to full speed, stops, reversals and spins
    never look like a wheel not following, nor like one off the ground. (At 5 % loss, three heartbeats of a node lost
    in a row now and then stop the base, as they should; the base is recovered then, and
    the run goes on.)"""
    cfg = sim_config(channel, rate_hz=rate, max_accel=accel, max_angular_accel=3 * accel,
                     lifted_wheel="stop")  # nor a wheel off the ground
    with shared_bus(channel, loss=loss, seed=seed) as (clock, _, _, drives), \
            SimulatedBase.from_config(cfg, bus=bus_args(drives), clock=clock,
                                      tau_s=tau_s) as sim, \
            Chassis.open(cfg, clock=clock) as base:
        for vx, vy, wz in ((5.0, 0.0, 0.0), (-5.0, 0.0, 0.0), (0.0, 5.0, 0.0),
                           (0.0, 0.0, 9.0), (3.0, -3.0, -9.0)):
            drive_for(base, 1.5, vx=vx, vy=vy, wz=wz)  # beyond the limits: at them
            if base.status.stopped_reason is None:
                assert max(abs(w.target_speed) for w in base.wheels) > 0.85  # at the limits
            base.stop()  # at the stop deceleration
            assert wait_for(lambda: still(sim), 3.0, clock=clock)
            reason = base.status.stopped_reason
            if reason is not None:
                assert "heartbeat lost" in reason and loss, base.status
                base.recover()


@pytest.mark.parametrize(("loss", "seed", "tau_s", "noise"), [
    (0.0, 0, 0.15, 0.0), (0.05, 4, 0.15, 20.0), (0.05, 2, 0.01, 50.0)])
def test_slow_motions_never_latch_a_tracking_stop(channel: str, loss: float, seed: int,
                                                  tau_s: float, noise: float) -> None:
    """A few cm/s and less, starts, stops, reversals and creeping turns, on a drive with a
    slow velocity loop, frames lost and a noisy encoder: every wheel follows its target
    (judged against its size too, from 5 mm/s), so nothing stops the base but a lost
    heartbeat now and then (at 5 % loss, as it should; then it is recovered)."""
    cfg = sim_config(channel)
    with shared_bus(channel, loss=loss, seed=seed) as (clock, _, _, drives), \
            SimulatedBase.from_config(cfg, bus=bus_args(drives), clock=clock, tau_s=tau_s,
                                      encoder_noise=noise) as sim, \
            Chassis.open(cfg, clock=clock) as base:
        for vx, vy, wz in ((0.02, 0.0, 0.0), (-0.02, 0.0, 0.0), (0.01, 0.01, 0.0),
                           (0.0, -0.006, 0.0), (0.0, 0.0, 0.05), (0.03, 0.0, -0.2),
                           (-0.03, 0.0, 0.2)):
            drive_for(base, 1.5, vx=vx, vy=vy, wz=wz)
            reason = base.status.stopped_reason
            if reason is not None:
                assert "heartbeat lost" in reason and loss, base.status
                base.recover()
        base.stop()
        assert wait_for(lambda: still(sim), 3.0, clock=clock)


# ---------------------------------------------------------------- vendor drives


def vendor_example(name: str, channel: str) -> ChassisConfig:
    cfg = load_config(EXAMPLES / f"{name}.toml")
    return replace(cfg, bus={"interface": "virtual", "channel": channel})


@pytest.mark.parametrize("name", ["zlac8015d", "epos4", "roboteq"])
def test_vendor_drives_report_their_health_as_their_example_config_reads_it(
        channel: str, name: str) -> None:
    """Each example reads its drive's own objects in its own units: by the health TPDOs
    where the EDS lets them be mapped, by SDO round robin where not."""
    cfg = vendor_example(name, channel)
    clock = SimClock()
    with SimulatedBase.from_config(cfg, clock=clock) as sim, \
            Chassis.open(cfg, clock=clock) as base:
        clock.sleep(0.5)
        for w in base.wheels:
            assert w.voltage_v == pytest.approx(24.0, abs=0.05), w
            assert w.temperature_c == pytest.approx(25.0, abs=1.0), w
            assert w.current_a == pytest.approx(0.0, abs=0.1), w
        drive_for(base, 1.0, vx=0.3, wz=0.5)
        moving = [w for w in base.wheels if abs(w.actual_speed) > 0.05]
        assert moving
        for w in moving:
            drive, axis = sim.wheel_drive(w.index)
            assert w.current_a == pytest.approx(drive.current_a(axis), abs=0.15), w
            assert abs(w.current_a or 0.0) > 0.3
        assert base.status.battery_v is not None and base.status.battery_v < 24.0
        assert base.status.stopped_reason is None


def test_vendor_settings_are_written_at_startup_and_after_a_reboot(channel: str) -> None:
    cfg = vendor_example("zlac8015d", channel)
    clock = SimClock()
    with SimulatedBase.from_config(cfg, clock=clock) as sim, \
            Chassis.open(cfg, clock=clock) as base:
        assert [int.from_bytes(d.read(0x2000), "little") for d in sim.drives] == [500, 500]
        sim.drives[1].reboot()  # its settings back at their defaults (0)
        assert int.from_bytes(sim.drives[1].read(0x2000), "little") == 0
        assert wait_for(lambda: int.from_bytes(sim.drives[1].read(0x2000), "little") == 500,
                        2.0, clock=clock)
        base.recover()
        assert base.status.enabled


def test_a_drive_that_keeps_its_own_mapping_reports_its_health_by_sdo(channel: str) -> None:
    cfg = sim_config(channel)
    clock = SimClock()
    with SimulatedBase.from_config(cfg, clock=clock, remappable=False) as sim, \
            Chassis.open(cfg, clock=clock) as base:
        assert any("refuses remapping" in w for w in base.warnings)
        drive_for(base, 1.0, vx=0.3)
        for w in base.wheels:
            assert w.voltage_v is not None and w.temperature_c is not None, w
        assert base.wheels[1].current_a == pytest.approx(sim.drives[1].current_a(), abs=0.05)


def test_a_silent_drive_shows_no_health_values(rig: Rig) -> None:
    clock, sim, base = rig
    clock.sleep(0.3)
    sim.drives[0].freeze()
    clock.sleep(1.2)  # values go stale after five health periods (1 s)
    w = base.wheels[0]
    assert (w.current_a, w.voltage_v, w.temperature_c) == (None, None, None)
    assert base.wheels[1].voltage_v is not None
    sim.drives[0].thaw()


def test_temperature_rises_with_current_while_stalled(rig: Rig) -> None:
    """The winding warms with the current it carries (the drive pushing at its limit)."""
    _clock, sim, base = rig
    sim.drives[1].jam()
    drive_for(base, 0.45, vx=0.3)  # stalled, at the current limit, until the stop
    assert math.isclose(sim.drives[1].current_a(), 0.0, abs_tol=10.0)
    t0 = base.wheels[1].temperature_c
    assert t0 is not None and t0 > 25.0


def test_a_rated_current_the_drive_will_not_give_is_one_warning_and_no_amps(
        channel: str, caplog: pytest.LogCaptureFixture) -> None:
    """6078h counts per mille of 6075h: a drive that refuses 6075h (here: its dictionary
    lacks it, whatever the EDS says) still runs, says why its current shows no amps, and
    the other drives' currents are shown."""
    cfg = sim_config(channel)
    clock = SimClock()
    with SimulatedBase.from_config(cfg, clock=clock) as sim:
        del sim.drives[0].dictionary[0x6075]
        with caplog.at_level(logging.WARNING, logger="omnican"), \
                Chassis.open(cfg, clock=clock) as base:
            drive_for(base, 0.5, vx=0.3)
            wheels = base.wheels
            assert base.status.stopped_reason is None
    warned = [r.getMessage() for r in caplog.records if "rated current" in r.getMessage()]
    assert len(warned) == 1 and warned[0].startswith(
        "node 1: reading the rated current (0x6075:00) failed"), warned
    assert wheels[0].current_a is None and wheels[0].voltage_v is not None
    assert wheels[1].current_a is not None and wheels[2].current_a is not None


def test_a_snapshot_carries_each_value_by_name(rig: Rig) -> None:
    """The cycle fills every field of its snapshot; the status and the wheels are made of
    them and of the chassis checks' record, name for name."""
    clock, _sim, base = rig
    drive_for(base, 0.5, vx=0.3)
    snap = base._loop.snapshot
    missing = [n for n in Snapshot.__slots__ if not n.startswith("_") and not hasattr(snap, n)]
    assert not missing
    status, health = snap.status, snap.checked
    assert (status.cycles, status.enabled, status.bus_up) == (snap.cycles, True, True)
    for name in StatusChecks._fields:
        expected = getattr(health.status, name)
        if name == "warnings":
            expected = snap.warnings + expected
        assert getattr(status, name) == expected, name
    assert status.battery_v == pytest.approx(24.0, abs=0.2)
    assert [health_values(w) for w in snap.wheels] == [health_values(h) for h in health.wheels]
    assert all(w.voltage_v is not None for w in snap.wheels)
    clock.sleep(0.01)
    assert base._loop.snapshot is not snap and snap.status is status  # made once, kept
