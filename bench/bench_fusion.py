"""The gyro fused with the wheels, on the simulator: heading through slip, slip seen, cost.

All on a lock-step simulated base (one thread, a simulated clock: no waits, the same
figures on a loaded machine), the demo config at ``--rate`` (100 Hz default), the
limits of bench_chassis (2 m/s^2, 6 rad/s^2: the base's full acceleration):

* squares: ten 1 m squares (drive 1 m at 0.5 m/s, stop, turn 90 deg, stop: the base's
  heading turns with it; each stop 0.4 s standing still after braking), wheel 1's ground taking 90 % of its motion (10 % slip) and a
  gyro with a 0.5 deg/s bias and 0.005 rad/s noise per sample, one sample a cycle from
  the simulator's true yaw rate. Final heading error against the truth: the wheels'
  odometry alone and the fused, side by side;
* onset: the base drives straight at 0.5 m/s, and the slip begins at a known time
  (omnican.sim.slip.set_slip): how long until the first slip event, and its size;
* clean: the ten squares with no slip, as fast as the limits allow (1 m/s, 3 rad/s):
  slip events counted (should be none);
* compare: the ten slipping squares' filter inputs (what the loop handed the filter each
  cycle) replayed through first-order complementary filters (time constant 1, 10, 100 s,
  the bias learnt standing still alike) and through the Kalman filter again: the final
  heading error of each and its time per step, the measurement the choice rests on;
* cost: the fusion's own time per cycle (the cycle's IMU block, ControlCycle._fuse, timed
  around the call: wall time on the loop's one thread, so a preemption of the shared
  machine lands in the mean and the tail; the median is the figure) at 100 Hz and 1 kHz.

The gyro comes the user's way by default: examples/imu.toml's ``[imu]`` lines (a CAN
IMU, the bundled OpenIMU300RI DBC) and the simulator's gyro sending its frames on the
simulated bus (``[sim.gyro]``: the bias and noise above, 200 Hz or the loop's rate);
``--gyro bench`` puts one sample a cycle straight into the loop's inbox instead.

Run: ``python bench/bench_fusion.py`` (about a minute); ``--quick`` (two squares).
Prints one JSON object per line, then a table.
"""

from __future__ import annotations

import argparse
import json
import math
import random
import statistics
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from bench_chassis import config

from omnican import Chassis
from omnican.clock import SimClock
from omnican.config import ChassisConfig, SimGyro, SimTruth, load_config
from omnican.core.fusion import HeadingFusion
from omnican.core.imu import ImuInbox, ImuSample
from omnican.sim import SimulatedBase
from omnican.sim.slip import SimSlip, set_slip

BIAS = math.radians(0.5)
NOISE = 0.005
ROWS: list[dict[str, Any]] = []


def emit(**fields: Any) -> None:
    ROWS.append(fields)
    print(json.dumps(fields), flush=True)


#: The gyro's path: "dbc" (the default), the user's: examples/imu.toml's four [imu] lines
#: (a CAN IMU read through the bundled OpenIMU300RI DBC) and the simulator's gyro sending
#: on the simulated bus ([sim.gyro] with the bias and noise below, GYRO_HZ); "bench": one
#: sample a cycle put straight into the loop's inbox.
GYRO = "dbc"
GYRO_HZ = 200.0
IMU_EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "imu.toml"


def imu_config(rate_hz: float) -> ChassisConfig:
    """The demo base with examples/imu.toml's [imu] table and a simulated gyro of
    ``BIAS`` and ``NOISE`` (per sample) sending through its DBC message."""
    gyro = SimGyro(enabled=True, rate_hz=min(GYRO_HZ, rate_hz), bias_deg_s=math.degrees(BIAS),
                   drift_deg_s=0.0, noise_deg_s=math.degrees(NOISE), mount_yaw_deg=None,
                   noise_stream=1)
    return replace(config(rate_hz), imu=load_config(IMU_EXAMPLE).imu,
                   sim=SimTruth(gyro=gyro))


class Rig:
    """A lock-step simulated base with a gyro (see :data:`GYRO`); the fusion's step is
    timed."""

    def __init__(self, rate_hz: float, bias: float = BIAS, seed: int = 1) -> None:
        cfg = imu_config(rate_hz) if GYRO == "dbc" else config(rate_hz)
        self.clock = SimClock()
        self.sim = SimulatedBase.from_config(cfg, clock=self.clock)
        self.base = Chassis.open(cfg, clock=self.clock)
        self.loop = self.base._loop
        if GYRO == "dbc":
            assert self.loop.imu is not None, "the [imu] table attached no inbox"
            self.inbox = self.loop.imu
        else:
            self.loop.imu = self.inbox = ImuInbox()
        self.rng = random.Random(seed)
        self.bias = bias
        self.fuse_s: list[float] = []
        cycle = self.base._runner.cycle
        fuse = self.loop._fuse
        sim, inbox, rng = self.sim, self.inbox, self.rng

        def timed_fuse(now: float, imu: ImuInbox) -> None:
            t0 = time.perf_counter()
            fuse(now, imu)
            self.fuse_s.append(time.perf_counter() - t0)

        def with_gyro(now: float) -> None:
            wz = sim.true_twist.wz
            inbox.put(ImuSample(now, wz + self.bias + rng.gauss(0.0, NOISE)))
            cycle(now)

        self.loop._fuse = timed_fuse  # type: ignore[method-assign]
        if GYRO == "bench":
            self.base._runner.cycle = with_gyro

    def __enter__(self) -> Rig:
        self.wait_enabled()
        return self

    def __exit__(self, *exc: object) -> None:
        self.base.close()
        self.sim.close()

    def wait_enabled(self) -> None:
        deadline = self.clock.now() + 10.0
        while not self.base.status.enabled and self.clock.now() < deadline:
            self.clock.sleep(0.01)
        if not self.base.status.enabled:
            raise SystemExit("the simulated base did not enable")

    def hold(self, vx: float, vy: float, wz: float, seconds: float) -> None:
        end = self.clock.now() + seconds
        while self.clock.now() < end:
            self.base.set_velocity(vx, vy, wz)
            self.clock.sleep(0.01)

    def square(self, speed: float, turn_rate: float) -> None:
        """A 1 m square; each stop: the time to brake at the limits, then 0.4 s still."""
        limits = self.base.cfg.chassis
        for _ in range(4):
            self.hold(speed, 0.0, 0.0, 1.0 / speed)
            self.hold(0.0, 0.0, 0.0, 0.4 + speed / limits.max_accel)
            self.hold(0.0, 0.0, turn_rate, (math.pi / 2) / turn_rate)
            self.hold(0.0, 0.0, 0.0, 0.4 + turn_rate / limits.max_angular_accel)

    def heading_errors_deg(self) -> tuple[float, float]:
        snap = self.loop.snapshot
        true = self.sim.true_pose.theta
        assert snap.fused is not None
        return (math.degrees(snap.xyt[2] - true), math.degrees(snap.fused[2] - true))

    @property
    def slip(self) -> Any:
        fusion = self.loop.fusion
        assert fusion is not None
        return fusion.fusion.slip


def squares(rate_hz: float, n: int) -> None:
    with Rig(rate_hz) as rig:
        set_slip(rig.sim, SimSlip(ratios=(0.0, 0.1, 0.0)))
        rig.hold(0.0, 0.0, 0.0, 2.0)  # standing still: the bias is learnt
        for _ in range(n):
            rig.square(0.5, 1.0)
        wheels, fused = rig.heading_errors_deg()
        fusion = rig.loop.fusion
        assert fusion is not None
        emit(bench="squares", rate_hz=rate_hz, squares=n, slip="10% wheel 1",
             gyro_bias_deg_s=0.5, wheels_heading_err_deg=round(wheels, 2),
             fused_heading_err_deg=round(fused, 2),
             fused_sigma_deg=round(math.degrees(math.sqrt(fusion.values[3])), 2),
             bias_learnt_deg_s=round(math.degrees(fusion.values[4]), 3),
             slip_events=rig.slip.started)


class Recorded(HeadingFusion):
    """The loop's filter, keeping what each step was given (to replay it through others)."""

    __slots__ = ("steps",)

    def step(self, now: float, samples: Any, wheel_step: Any, still: bool) -> None:
        self.steps.append((now, list(samples), wheel_step, still))
        super().step(now, samples, wheel_step, still)


class Complementary:
    """The alternative: a first-order complementary filter, the gyro high-passed and the
    wheels' heading low-passed with time constant ``tau_s``, the bias the mean gyro
    reading standing still (the same zero-velocity information as the Kalman filter's)."""

    def __init__(self, tau_s: float) -> None:
        self.tau_s = tau_s
        self.theta = self.wheels = self.b = 0.0
        self.t: float | None = None
        self.rate = 0.0

    def step(self, now: float, samples: Any, wheel_step: Any, still: bool) -> None:
        if samples:
            self.rate = sum(s.yaw_rate for s in samples) / len(samples)
            if still:
                self.b += 0.02 * (self.rate - self.b)
        dt = now - self.t if self.t is not None else 0.0
        self.t = now
        if wheel_step is not None:
            self.wheels += wheel_step[2]
        gyro = 0.0 if still else self.rate - self.b
        self.theta += gyro * dt + min(1.0, dt / self.tau_s) * (self.wheels - self.theta)


def compare(rate_hz: float, n: int) -> None:
    """The ten slipping squares' inputs, replayed through complementary filters."""
    with Rig(rate_hz) as rig:
        set_slip(rig.sim, SimSlip(ratios=(0.0, 0.1, 0.0)))
        rig.hold(0.0, 0.0, 0.0, 0.05)
        fused = rig.loop.fusion
        assert fused is not None
        old = fused.fusion
        rec = Recorded(rig.loop.kinematics.rows, rig.loop.kinematics.forward_rows[2],
                       old.params, fused.odometry.xyt)
        rec.steps = []
        fused.fusion = rec
        start = rig.sim.true_pose.theta - rec.theta
        rig.hold(0.0, 0.0, 0.0, 2.0)
        for _ in range(n):
            rig.square(0.5, 1.0)
        true = rig.sim.true_pose.theta - start
        steps = rec.steps
    for tau in (1.0, 10.0, 100.0):
        cf = Complementary(tau)
        t0 = time.perf_counter()
        for args in steps:
            cf.step(*args)
        us = (time.perf_counter() - t0) / len(steps) * 1e6
        emit(bench="compare", rate_hz=rate_hz, filter=f"complementary tau {tau:g} s",
             heading_err_deg=round(math.degrees(cf.theta - true), 2),
             us_per_step=round(us, 2))
    kf = HeadingFusion(rec._rows, rec._wz_of, rec.params)
    t0 = time.perf_counter()
    for args in steps:
        kf.step(*args)
    us = (time.perf_counter() - t0) / len(steps) * 1e6
    emit(bench="compare", rate_hz=rate_hz, filter="kalman (omnican.core.fusion)",
         heading_err_deg=round(math.degrees(kf.theta - true), 2), us_per_step=round(us, 2))


def onset(rate_hz: float) -> None:
    with Rig(rate_hz) as rig:
        rig.hold(0.0, 0.0, 0.0, 2.0)
        rig.hold(0.5, 0.0, 0.0, 1.0)
        before = rig.slip.started
        t_slip = rig.clock.now()
        set_slip(rig.sim, SimSlip(ratios=(0.0, 0.1, 0.0)))
        rig.hold(0.5, 0.0, 0.0, 1.0)
        events = list(rig.slip.events)[-(rig.slip.started - before):] \
            if rig.slip.started > before else []
        first = events[0] if events else None
        emit(bench="onset", rate_hz=rate_hz, slip="10% wheel 1 from t0",
             false_before=before,
             began_after_ms=None if first is None else round((first.t - t_slip) * 1e3, 1),
             flagged_after_ms=None if first is None else round(
                 (first.t + rig.slip.confirm_s - t_slip) * 1e3, 1),
             size_rad_s=None if first is None else round(first.size, 4))


def clean(rate_hz: float, n: int) -> None:
    with Rig(rate_hz) as rig:
        rig.hold(0.0, 0.0, 0.0, 2.0)
        for _ in range(n):
            rig.square(1.0, 3.0)
        wheels, fused = rig.heading_errors_deg()
        emit(bench="clean", rate_hz=rate_hz, squares=n, speed_m_s=1.0, turn_rad_s=3.0,
             slip_events=rig.slip.started, wheels_heading_err_deg=round(wheels, 2),
             fused_heading_err_deg=round(fused, 2))


def cost(rate_hz: float, seconds: float) -> None:
    with Rig(rate_hz) as rig:
        rig.hold(0.0, 0.0, 0.0, 1.0)
        rig.fuse_s.clear()
        end = rig.clock.now() + seconds
        k = 0
        while rig.clock.now() < end:
            rig.base.set_velocity(0.3 * math.sin(k * 0.01), 0.1, 0.5)
            rig.clock.sleep(0.01)
            k += 1
        per = sorted(rig.fuse_s)
        emit(bench="cost", rate_hz=rate_hz, cycles=len(per),
             fusion_us_per_cycle_p50=round(statistics.median(per) * 1e6, 1),
             fusion_us_per_cycle_p99=round(per[int(0.99 * (len(per) - 1))] * 1e6, 1),
             fusion_us_per_cycle_mean=round(statistics.fmean(per) * 1e6, 1))


def table() -> None:
    print()
    for r in ROWS:
        if r["bench"] in ("squares", "clean"):
            print(f"{r['bench']:<8} {r['rate_hz']:>5.0f} Hz  {r['squares']} squares: heading error "
                  f"wheels {r['wheels_heading_err_deg']:+8.2f} deg, fused "
                  f"{r['fused_heading_err_deg']:+6.2f} deg, slip events {r['slip_events']}")
        elif r["bench"] == "onset":
            print(f"onset    {r['rate_hz']:>5.0f} Hz  slip flagged {r['flagged_after_ms']} ms "
                  f"after it began (size {r['size_rad_s']} rad/s), false before: "
                  f"{r['false_before']}")
        elif r["bench"] == "compare":
            print(f"compare  {r['rate_hz']:>5.0f} Hz  {r['filter']:<30} heading error "
                  f"{r['heading_err_deg']:+7.2f} deg, {r['us_per_step']} us a step")
        elif r["bench"] == "cost":
            print(f"cost     {r['rate_hz']:>5.0f} Hz  fusion {r['fusion_us_per_cycle_p50']} us per "
                  f"cycle (median; p99 {r['fusion_us_per_cycle_p99']}, mean "
                  f"{r['fusion_us_per_cycle_mean']})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="two squares, short cost runs")
    ap.add_argument("--rate", type=float, default=100.0, help="control rate of the squares")
    ap.add_argument("--gyro", choices=("dbc", "bench"), default="dbc",
                    help="dbc: the simulator's gyro on the bus, read through the [imu] "
                         "table's DBC (default); bench: one sample a cycle into the inbox")
    args = ap.parse_args()
    global GYRO
    GYRO = args.gyro
    n = 2 if args.quick else 10
    squares(args.rate, n)
    compare(args.rate, n)
    onset(args.rate)
    clean(args.rate, n)
    for rate in (100.0, 1000.0):
        cost(rate, 2.0 if args.quick else 5.0)
    table()


if __name__ == "__main__":
    main()
