"""The gyro fused with the wheels (omnican.core.fusion): a gyro that agrees with the wheels
changes nothing, a constant bias is learnt standing still, the heading holds through wheel
slip, a silent IMU leaves the wheels' odometry exactly, the covariance grows moving and
shrinks at a zero-velocity update."""

from __future__ import annotations

import math
import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from omnican.core.fusion import FusedOdometry, FusionParams, HeadingFusion
from omnican.core.imu import ImuSample
from omnican.core.kinematics import OmniKinematics
from omnican.core.odometry import Odometry

KIN = OmniKinematics.from_layout("b21", 0.19)
FOUR = OmniKinematics([0.0, 90.0, 180.0, 270.0], 0.2)

# A motion: (vx, vy, wz, seconds) segments, each followed by a stop.
segment = st.tuples(st.floats(-0.8, 0.8), st.floats(-0.8, 0.8), st.floats(-2.0, 2.0),
                    st.floats(0.05, 1.0))


def fusion(kin: OmniKinematics = KIN, **params: float) -> HeadingFusion:
    return HeadingFusion(kin.rows, kin.forward_rows[2], FusionParams(**params))


def drive(f: HeadingFusion, odo: Odometry, plan: list[tuple[float, float, float, float]],
          slip: tuple[float, ...] = (0.0, 0.0, 0.0), bias: float = 0.0, noise: float = 0.0,
          dt: float = 0.01, rng: random.Random | None = None, still_s: float = 0.3,
          t0: float = 0.0, imu: bool = True) -> tuple[float, float]:
    """Drive ``plan`` (each segment then ``still_s`` standing still) through ``f`` and the
    wheels' ``odo``; the truth's wheels take (1 - slip) of each rim's motion. Returns the
    true heading and the time reached."""
    rng = rng or random.Random(0)
    t, truth = t0, 0.0
    kin = f_kin(odo)
    travel = [0.0] * odo.num_wheels
    if odo.seeded:  # carry on from the travel of the last call
        travel = list(odo._last)  # type: ignore[arg-type]
    else:
        odo.step(list(travel))
    for vx, vy, wz, seconds in plan:
        for moving, span in ((True, seconds), (False, still_s)):
            for _ in range(max(1, round(span / dt))):
                t += dt
                rims = kin.wheel_speeds_of(vx, vy, wz) if moving else [0.0] * len(travel)
                true_wz = kin.body_of([v * (1.0 - s) for v, s in zip(rims, slip, strict=True)])[2]
                truth += true_wz * dt
                travel = [a + v * dt for a, v in zip(travel, rims, strict=True)]
                step = odo.step(list(travel))
                samples = [ImuSample(t, true_wz + bias + (rng.gauss(0.0, noise) if noise else 0.0))
                           ] if imu else []
                f.step(t, samples, step, not moving or vx == vy == wz == 0.0)
    return truth, t


def f_kin(odo: Odometry) -> OmniKinematics:
    return KIN if odo.num_wheels == 3 else FOUR


@settings(max_examples=40, deadline=None)
@given(st.lists(segment, min_size=1, max_size=4))
def test_a_gyro_with_no_bias_and_no_slip_changes_nothing(plan: list[tuple[float, ...]]) -> None:
    f, odo = fusion(), Odometry(KIN)
    drive(f, odo, plan)  # type: ignore[arg-type]
    x, y, th = odo.xyt
    assert f.theta == pytest.approx(th, abs=1e-9)
    assert f.x == pytest.approx(x, abs=1e-9)
    assert f.y == pytest.approx(y, abs=1e-9)
    assert f.b == pytest.approx(0.0, abs=1e-12)
    assert f.slip.started == 0


@settings(max_examples=30, deadline=None)
@given(st.floats(-0.03, 0.03), st.integers(0, 1000))
def test_a_constant_bias_is_learnt_standing_still(bias: float, seed: int) -> None:
    f, odo = fusion(), Odometry(KIN)
    rng = random.Random(seed)
    odo.step([0.0, 0.0, 0.0])
    t = 0.0
    for _ in range(300):  # 3 s standing still, a sample a cycle with noise
        t += 0.01
        f.step(t, [ImuSample(t, bias + rng.gauss(0.0, 0.005))], odo.step([0.0, 0.0, 0.0]),
               True)
    # 300 samples of sigma 0.005: the mean's sigma is 0.0003; five of them
    assert f.b == pytest.approx(bias, abs=0.0015)
    assert f.var_bias < 0.005 ** 2 / 100
    assert f.theta == pytest.approx(0.0, abs=1e-3)  # standing still, the heading holds


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 2), st.floats(0.05, 0.2), st.integers(0, 100))
def test_the_fused_heading_holds_under_wheel_slip(wheel: int, ratio: float, seed: int) -> None:
    """Four 1 m squares with one wheel slipping and a biased, noisy gyro: the wheels'
    heading is off by degrees, the fused one within 2 degrees."""
    slip = tuple(ratio if i == wheel else 0.0 for i in range(3))
    f, odo = fusion(), Odometry(KIN)
    rng = random.Random(seed)
    plan = [(0.0, 0.0, 0.0, 1.5)]
    for _ in range(4):
        plan += [(0.5, 0.0, 0.0, 2.0), (0.0, 0.0, math.pi / 2, 1.0)]
    truth, _ = drive(f, odo, plan, slip=slip, bias=math.radians(0.5), noise=0.005, rng=rng)
    wheels_err = abs(math.degrees(odo.xyt[2] - truth))
    fused_err = abs(math.degrees(f.theta - truth))
    assert wheels_err > 5.0
    assert fused_err < 2.0


@settings(max_examples=30, deadline=None)
@given(st.lists(segment, min_size=1, max_size=3), st.floats(-0.05, 0.05))
def test_without_imu_samples_the_wheels_odometry_exactly(plan: list[tuple[float, ...]],
                                                         bias: float) -> None:
    f, odo = fusion(), Odometry(KIN)
    drive(f, odo, plan, slip=(0.0, 0.1, 0.0), bias=bias, imu=False)  # type: ignore[arg-type]
    assert f.xyt == pytest.approx(odo.xyt, abs=1e-9)
    assert not f.imu_live(1e9)


def test_a_silent_imu_falls_back_to_the_wheels_and_comes_back() -> None:
    f, odo = fusion(stale_s=0.2), Odometry(KIN)
    drive(f, odo, [(0.0, 0.0, 0.0, 1.0)], bias=0.01)
    theta0 = f.theta - odo.xyt[2]
    # The IMU goes silent for 2 s while the base turns with a slipping wheel.
    _, t = drive(f, odo, [(0.0, 0.0, 1.0, 2.0)], slip=(0.0, 0.1, 0.0), imu=False, t0=3.0)
    assert not f.imu_live(t)
    # After stale_s the fused heading moved with the wheels: the difference stays put
    # but for the first 0.2 s
    assert abs((f.theta - odo.xyt[2]) - theta0) < 0.2 * 1.0 * 0.1
    drive(f, odo, [(0.0, 0.0, 0.0, 0.5)], t0=t)
    assert f.imu_live(t + 0.5)


def test_the_heading_variance_grows_moving_and_shrinks_standing_still() -> None:
    f, odo = fusion(), Odometry(KIN)
    drive(f, odo, [(0.0, 0.0, 0.0, 0.5)], bias=0.01, still_s=0.0)
    v0 = f.var_theta
    drive(f, odo, [(0.4, 0.2, 1.0, 3.0)], bias=0.01, still_s=0.0, t0=1.0)
    moved = f.var_theta
    assert moved > v0
    drive(f, odo, [(0.0, 0.0, 0.0, 1.0)], bias=0.01, still_s=0.0, t0=5.0)
    assert f.var_theta < moved


def test_an_outlier_gyro_reading_is_dropped() -> None:
    f, odo = fusion(), Odometry(KIN)
    odo.step([0.0, 0.0, 0.0])
    f.step(0.01, [ImuSample(0.01, math.nan), ImuSample(0.01, 1e6)], odo.step([0.0] * 3), True)
    assert f.samples == 0 and f.b == 0.0
    assert math.isfinite(f.theta)


def test_params_are_checked() -> None:
    with pytest.raises(ValueError, match="gyro_noise must be a positive number"):
        FusionParams(gyro_noise=0.0)


def test_fused_odometry_warns_of_a_silent_imu_and_stops_only_if_asked() -> None:
    from omnican.core.wheel_odometry import EncoderCounters, WheelOdometry

    class Sample:
        raw: int | None = 0
        epoch = 0
        restarts = 0

    odo = Odometry(KIN)
    wheels = WheelOdometry(odo, EncoderCounters([Sample(), Sample(), Sample()], [32] * 3,
                                                [1000.0] * 3))
    for stop_on, expect in ((False, None), (True, "the IMU went silent")):
        fused = FusedOdometry(KIN, FusionParams(stale_s=0.2), odo, wheels,
                              stop_on_imu_stale=stop_on)
        assert fused.step(0.0, [ImuSample(0.0, 0.0)], True) is None
        assert fused.warnings == ()
        stops = [fused.step(0.01 * k, [], True) for k in range(1, 40)]
        warned: tuple[str, ...] = fused.warnings
        assert any("IMU silent" in text for text in warned)
        reasons = [s for s in stops if s is not None]
        if expect is None:
            assert reasons == []
        else:
            assert len(reasons) == 1 and expect in reasons[0]
        assert fused.values[7] is False
        fused.step(0.5, [ImuSample(0.5, 0.0)], True)
        assert fused.warnings == () and fused.values[7] is True
