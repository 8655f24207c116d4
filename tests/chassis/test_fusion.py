"""A base with an IMU attached (ControlCycle.imu): the fused heading holds where a slipping
wheel takes the wheels' astray, the wheels' odometry stays beside it, a slip warns (and
stops the base if configured), a silent IMU warns and falls back to the wheels (and stops
it only if configured); a base without an IMU publishes no fused odometry."""

from __future__ import annotations

import math
import random
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import replace

from omnican import Chassis
from omnican.clock import SimClock
from omnican.config import FusionSettings, parse_config
from omnican.core.imu import ImuInbox, ImuSample
from omnican.sim import SimulatedBase
from omnican.sim.slip import SimSlip, set_slip
from omnican.telemetry import Telemetry
from omnican.telemetry.messages import TelemetrySample
from omnican.telemetry.settings import TelemetrySettings
from tests.support.helpers import sim_config

BIAS = math.radians(0.5)


@contextmanager
def rig(channel: str, fusion: FusionSettings | None = None, imu: bool = True
        ) -> Iterator[tuple[SimClock, SimulatedBase, Chassis, dict[str, bool]]]:
    """The demo base in lock-step; with ``imu``, a gyro sample (the truth's yaw rate, a
    0.5 deg/s bias, noise) into the loop's inbox before each cycle while ``gyro["on"]``."""
    cfg = sim_config(channel)
    if fusion is not None:
        cfg = replace(cfg, fusion=fusion)
    clock = SimClock()
    gyro = {"on": True}
    with SimulatedBase.from_config(cfg, clock=clock) as sim, \
            Chassis.open(cfg, clock=clock) as base:
        if imu:
            inbox = base._loop.imu = ImuInbox()
            cycle = base._runner.cycle
            rng = random.Random(7)

            def with_gyro(now: float) -> None:
                if gyro["on"]:
                    inbox.put(ImuSample(now, sim.true_twist.wz + BIAS + rng.gauss(0.0, 0.005)))
                cycle(now)

            base._runner.cycle = with_gyro
        deadline = clock.now() + 10.0
        while not base.status.enabled and clock.now() < deadline:
            clock.sleep(0.01)
        assert base.status.enabled
        yield clock, sim, base, gyro


def hold(clock: SimClock, base: Chassis, vx: float, vy: float, wz: float, seconds: float) -> None:
    end = clock.now() + seconds
    while clock.now() < end:
        base.set_velocity(vx, vy, wz)
        clock.sleep(0.01)


def test_the_fused_heading_holds_through_slip_and_the_wheels_odometry_stays(
        channel: str) -> None:
    with rig(channel) as (clock, sim, base, _):
        set_slip(sim, SimSlip(ratios=(0.0, 0.1, 0.0)))
        hold(clock, base, 0.0, 0.0, 0.0, 2.0)  # the bias, learnt standing still
        for _ in range(4):
            hold(clock, base, 0.5, 0.0, 0.0, 2.0)
            hold(clock, base, 0.0, 0.0, 0.0, 0.7)
            hold(clock, base, 0.0, 0.0, 1.0, math.pi / 2)
            hold(clock, base, 0.0, 0.0, 0.0, 0.7)
        true = sim.true_pose.theta
        fused = base.fused_pose
        assert fused is not None
        assert abs(math.degrees(base.pose.theta - true)) > 20.0  # the wheels' own, astray
        assert abs(math.degrees(fused.theta - true)) < 2.0
        status = base.status
        fusion = base._loop.fusion
        assert fusion is not None and fusion.fusion.slip.started > 0
        assert status.stopped_reason is None  # a warning: not configured to stop
        # /odom is the fused odometry, /odom/wheels the wheels'
        snap = base._loop.snapshot
        settings = TelemetrySettings.from_config(base.cfg)
        sample = TelemetrySample(1, snap.pose, snap.twist, snap.command, snap.wheels,
                                 snap.status, fused=snap.fused)
        msgs = {m.topic: m.decoded() for m in Telemetry(settings, base.cfg.kinematics())
                .messages(sample)}
        yaw = msgs["/odom"]["pose"]["pose"]["orientation"]
        assert abs(math.remainder(math.atan2(yaw["z"], yaw["w"]) * 2 - fused.theta,
                                  math.tau)) < 1e-9
        assert msgs["/odometry/filtered"] == msgs["/odom"]
        wheels_yaw = msgs["/odom/wheels"]["pose"]["pose"]["orientation"]
        assert abs(math.remainder(math.atan2(wheels_yaw["z"], wheels_yaw["w"]) * 2
                                  - base.pose.theta, math.tau)) < 1e-9
        assert snap.fused is not None
        assert msgs["/odom"]["pose"]["covariance"][35] == snap.fused[3]


def test_a_lasting_slip_stops_the_base_when_configured(channel: str) -> None:
    with rig(channel, FusionSettings(stop_on_slip=True, slip_warn_s=0.3)) as (
            clock, sim, base, _):
        hold(clock, base, 0.0, 0.0, 0.0, 1.0)
        hold(clock, base, 0.5, 0.0, 0.0, 0.5)
        assert base.status.stopped_reason is None
        set_slip(sim, SimSlip(ratios=(0.0, 0.2, 0.0)))
        end = clock.now() + 3.0
        while base.status.stopped_reason is None and clock.now() < end:
            base.set_velocity(0.5, 0.0, 0.0)
            clock.sleep(0.01)
        assert "slipping" in (base.status.stopped_reason or "")


def test_a_silent_imu_warns_and_falls_back_without_stopping(channel: str) -> None:
    with rig(channel) as (clock, _, base, gyro):
        hold(clock, base, 0.0, 0.0, 0.0, 1.0)
        gyro["on"] = False
        hold(clock, base, 0.0, 0.0, 0.5, 1.0)
        status = base.status
        assert any("IMU silent" in w for w in status.warnings)
        assert status.stopped_reason is None and status.enabled
        snap = base._loop.snapshot
        assert snap.fused is not None and snap.fused[7] is False
        # From the fall back on, the fused heading moves with the wheels'.
        before = snap.fused[2] - snap.xyt[2]
        hold(clock, base, 0.0, 0.0, 0.5, 1.0)
        snap = base._loop.snapshot
        assert snap.fused is not None
        assert abs((snap.fused[2] - snap.xyt[2]) - before) < 1e-9
        gyro["on"] = True
        hold(clock, base, 0.0, 0.0, 0.0, 0.5)
        assert not any("IMU silent" in w for w in base.status.warnings)


def test_a_silent_imu_stops_the_base_when_configured(channel: str) -> None:
    with rig(channel, FusionSettings(stop_on_imu_stale=True)) as (
            clock, _, base, gyro):
        hold(clock, base, 0.0, 0.0, 0.0, 1.0)
        assert base.status.stopped_reason is None
        gyro["on"] = False
        hold(clock, base, 0.0, 0.0, 0.0, 0.5)
        assert "IMU went silent" in (base.status.stopped_reason or "")


def test_without_an_imu_nothing_is_fused(channel: str) -> None:
    with rig(channel, imu=False) as (clock, _, base, _):
        hold(clock, base, 0.2, 0.0, 0.3, 0.5)
        assert base.fused_pose is None and base._loop.fusion is None
        assert base._loop.snapshot.fused is None


def test_the_fusion_table_is_read_and_checked() -> None:
    import pytest

    from omnican.errors import ConfigError

    text = {"chassis": {"layout": "b21", "base_radius": 0.19},
            "wheel": [{"node_id": i, "velocity_scale": 1000.0, "position_scale": 10000.0}
                      for i in (1, 2, 3)],
            "fusion": {"stop_on_slip": True, "slip_warn_s": 1.5}}
    cfg = parse_config(text, check_eds=False)
    assert cfg.fusion.stop_on_slip and cfg.fusion.slip_warn_s == 1.5
    assert not cfg.fusion.stop_on_imu_stale
    with pytest.raises(ConfigError, match=r"fusion\.slip_warn_s"):
        parse_config({**text, "fusion": {"slip_warn_s": -1.0}}, check_eds=False)
    with pytest.raises(ConfigError, match=r"fusion\.stop_on_slp"):
        parse_config({**text, "fusion": {"stop_on_slp": True}}, check_eds=False)
