"""Kinematics: the seeds' correct formulas as vectors, their known errors as regressions."""

from __future__ import annotations

import math
from dataclasses import astuple

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from omnican import ConfigError, OmniKinematics, Twist

COS30, SIN30 = math.cos(math.radians(30)), 0.5
speeds = st.floats(-5, 5, allow_nan=False)
twists = st.builds(Twist, speeds, speeds, st.floats(-10, 10, allow_nan=False))
radii = st.floats(0.05, 1.0)


def sit_set_speed(vx: float, vy: float, vw: float, L: float) -> tuple[float, float, float]:
    """SIT AThreeChassis::setSpeed, as in the seed (returns setWheelSpeed(vb, vr, vl))."""
    vb = -vy + vw * L
    vl = -vx * COS30 + vy * SIN30 + vw * L
    vr = vx * COS30 + vy * SIN30 + vw * L
    return vb, vr, vl


def sit_get_speed(v1: float, v2: float, v3: float, L: float) -> tuple[float, float, float]:
    """SIT AThreeChassis::getSpeed, as in the seed."""
    return (v2 - v3) * (math.sqrt(3) / 3), (-2 * v1 + v2 + v3) / 3, (v1 + v2 + v3) / (3 * L)


def slamware_a12(vx: float, vy: float, w: float, R: float) -> tuple[float, float, float]:
    return (vy + R * w, -vx * COS30 - vy * SIN30 + R * w, vx * COS30 - vy * SIN30 + R * w)


def slamware_b21(vx: float, vy: float, w: float, R: float) -> tuple[float, float, float]:
    return (-vy + R * w, vx * COS30 + vy * SIN30 + R * w, -vx * COS30 + vy * SIN30 + R * w)


@given(twists, radii)
def test_b21_matches_sit_set_speed(t: Twist, r: float) -> None:
    kin = OmniKinematics.from_layout("b21", base_radius=r)
    np.testing.assert_allclose(kin.to_wheel_speeds(t), sit_set_speed(t.vx, t.vy, t.wz, r),
                               atol=1e-12)


@given(twists, radii)
def test_b21_matches_slamware_b21(t: Twist, r: float) -> None:
    kin = OmniKinematics.from_layout("b21", base_radius=r)
    np.testing.assert_allclose(kin.to_wheel_speeds(t), slamware_b21(t.vx, t.vy, t.wz, r),
                               atol=1e-12)


@given(twists, radii)
def test_a12_matches_slamware_a12(t: Twist, r: float) -> None:
    kin = OmniKinematics.from_layout("a12", base_radius=r)
    np.testing.assert_allclose(kin.to_wheel_speeds(t), slamware_a12(t.vx, t.vy, t.wz, r),
                               atol=1e-12)


@given(st.lists(speeds, min_size=3, max_size=3), radii)
def test_b21_forward_matches_sit_get_speed(v: list[float], r: float) -> None:
    kin = OmniKinematics.from_layout("b21", base_radius=r)
    got = kin.to_twist(v)
    np.testing.assert_allclose([got.vx, got.vy, got.wz], sit_get_speed(*v, r), atol=1e-9)


def test_known_vectors_b21() -> None:
    kin = OmniKinematics.from_layout("b21", base_radius=0.19)
    # Forward at 1 m/s: back wheel idle, right wheel +cos30, left wheel -cos30.
    np.testing.assert_allclose(kin.to_wheel_speeds(Twist(1, 0, 0)), [0, COS30, -COS30], atol=1e-15)
    # Left at 1 m/s: back wheel -1, the others +0.5.
    np.testing.assert_allclose(kin.to_wheel_speeds(Twist(0, 1, 0)), [-1, 0.5, 0.5], atol=1e-15)
    # Spin at 1 rad/s: every rim at R.
    np.testing.assert_allclose(kin.to_wheel_speeds(Twist(0, 0, 1)), [0.19] * 3, atol=1e-15)


def test_seed_compute_scales_translation_by_two_thirds() -> None:
    """The RPi seed's compute() is a12 with the front wheel labelled c, but its
    translation terms are 2/3 of the physical ones: ours must not copy that."""
    R = 0.2
    speed, angle, omega = 0.6, 30.0, 0.5
    vx, vy = speed * math.cos(math.radians(angle)), speed * math.sin(math.radians(angle))
    seed_a = math.sqrt(3) / 3 * vx - 1 / 3 * vy + omega * R
    seed_b = -math.sqrt(3) / 3 * vx - 1 / 3 * vy + omega * R
    seed_c = 2 / 3 * vy + omega * R
    kin = OmniKinematics.from_layout("a12", base_radius=R)
    front, rear_left, rear_right = kin.to_wheel_speeds(Twist(vx, vy, omega))
    ours = np.array([rear_right, rear_left, front]) - omega * R  # seed order a, b, c
    seed = np.array([seed_a, seed_b, seed_c]) - omega * R
    np.testing.assert_allclose(seed, ours * 2 / 3, atol=1e-12)
    assert not np.allclose(seed, ours)


@given(twists, radii, st.sampled_from(["a12", "b21"]))
def test_round_trip(t: Twist, r: float, layout: str) -> None:
    kin = OmniKinematics.from_layout(layout, base_radius=r)
    back = kin.to_twist(kin.to_wheel_speeds(t))
    np.testing.assert_allclose([back.vx, back.vy, back.wz], [t.vx, t.vy, t.wz], atol=1e-9)


@given(twists, st.integers(3, 8), radii)
def test_round_trip_n_wheels_least_squares(t: Twist, n: int, r: float) -> None:
    kin = OmniKinematics([360.0 * i / n + 10 for i in range(n)], base_radius=r)
    back = kin.to_twist(kin.to_wheel_speeds(t))
    np.testing.assert_allclose([back.vx, back.vy, back.wz], [t.vx, t.vy, t.wz], atol=1e-9)


def test_least_squares_with_four_wheels_averages_noise() -> None:
    kin = OmniKinematics([45, 135, 225, 315], base_radius=0.2)
    exact = kin.to_wheel_speeds(Twist(0.3, -0.2, 0.5))
    noise = np.array([0.01, -0.01, 0.01, -0.01])  # orthogonal to the column space
    assert np.allclose(kin.matrix.T @ noise, 0)
    got = kin.to_twist(exact + noise)
    assert astuple(got) == pytest.approx((0.3, -0.2, 0.5), abs=1e-12)


def test_per_wheel_radius_and_drive_angle() -> None:
    # A non-standard base: wheel 0 further out; a spin moves each rim at its own radius.
    kin = OmniKinematics([0, 120, -120], base_radius=[0.3, 0.2, 0.2], drive_angles_deg=[90, 210, -30])
    np.testing.assert_allclose(kin.to_wheel_speeds(Twist(0, 0, 1)), [0.3, 0.2, 0.2], atol=1e-12)
    # Wheel 0 tilted by 20 deg from the tangent: a spin drives it at R * cos(20 deg).
    tilted = OmniKinematics([0, 120, -120], base_radius=0.3, drive_angles_deg=[110, 210, -30])
    assert tilted.to_wheel_speeds(Twist(0, 0, 1))[0] == pytest.approx(0.3 * math.cos(math.radians(20)))
    # A wheel driving radially contributes nothing to a spin, yet the base stays controllable.
    radial = OmniKinematics([0, 120, -120], base_radius=0.2, drive_angles_deg=[0, 210, 30])
    assert radial.to_wheel_speeds(Twist(0, 0, 1))[0] == pytest.approx(0.0, abs=1e-12)
    t = Twist(0.1, 0.2, 0.3)
    back = radial.to_twist(radial.to_wheel_speeds(t))
    assert astuple(back) == pytest.approx(astuple(t))


@given(st.lists(speeds, min_size=3, max_size=6), st.floats(0.01, 3.0))
def test_desaturate_keeps_ratios_and_bound(v: list[float], max_speed: float) -> None:
    arr = np.array(v)
    out = OmniKinematics.desaturate(arr, max_speed)
    assert np.max(np.abs(out)) <= max_speed * (1 + 1e-12)
    peak = np.max(np.abs(arr))
    if peak <= max_speed:
        np.testing.assert_array_equal(out, arr)
    else:
        np.testing.assert_allclose(out * (peak / max_speed), arr, rtol=1e-9, atol=1e-12)


def test_desaturate_rows_independently() -> None:
    out = OmniKinematics.desaturate([[2.0, -1.0, 0.5], [0.1, 0.2, 0.3]], 1.0)
    np.testing.assert_allclose(out, [[1.0, -0.5, 0.25], [0.1, 0.2, 0.3]])


@given(st.lists(twists, min_size=1, max_size=20), radii)
def test_vectorised_forms_match_scalar(ts: list[Twist], r: float) -> None:
    kin = OmniKinematics.from_layout("b21", base_radius=r)
    arr = np.array([t.as_array() for t in ts])
    wheels = kin.to_wheel_speeds_array(arr)
    for row, t in zip(wheels, ts, strict=True):
        np.testing.assert_allclose(row, kin.to_wheel_speeds(t), atol=1e-12)
    np.testing.assert_allclose(kin.to_twist_array(wheels), arr, atol=1e-9)



@given(twists, st.integers(3, 6), radii, st.data())
def test_the_loops_float_forms_match_the_numpy_ones(t: Twist, n: int, r: float,
                                                     data: st.DataObject) -> None:
    """wheel_speeds_of, body_of and body_of_change (what the control loop, odometry and
    the measured speed use each cycle) are to_wheel_speeds and to_twist on plain floats."""
    kin = OmniKinematics([360.0 * i / n + 10 for i in range(n)], base_radius=r)
    np.testing.assert_allclose(kin.wheel_speeds_of(t.vx, t.vy, t.wz), kin.to_wheel_speeds(t),
                               atol=1e-12)
    now = data.draw(st.lists(st.floats(-1e3, 1e3), min_size=n, max_size=n))
    before = data.draw(st.lists(st.floats(-1e3, 1e3), min_size=n, max_size=n))
    change = [a - b for a, b in zip(now, before, strict=True)]
    expected = kin.to_twist(change).as_array()
    np.testing.assert_allclose(kin.body_of(change), expected, atol=1e-9)
    np.testing.assert_allclose(kin.body_of_change(now, before), expected, atol=1e-9)

@pytest.mark.parametrize(
    ("args", "message"),
    [
        (dict(angles_deg=[0, 120], base_radius=0.2), "at least 3 wheels"),
        (dict(angles_deg=[0, 0, 0], base_radius=0.2), "degenerate"),
        (dict(angles_deg=[0, 120, 240], base_radius=0.2, drive_angles_deg=[0, 120, 240]),
         "degenerate"),
        (dict(angles_deg=[0, 120, float("nan")], base_radius=0.2), "non-finite"),
        (dict(angles_deg=[0, 120, 240], base_radius=float("inf")), "non-finite"),
        (dict(angles_deg=[0, 120, 240], base_radius=-0.1), "positive"),
        (dict(angles_deg=[0, 120, 240], base_radius=[0.1, 0.2]), "2 values for 3 wheels"),
    ],
)
def test_bad_geometry_is_a_config_error(args: dict[str, object], message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        OmniKinematics(**args)  # type: ignore[arg-type]


def test_unknown_layout() -> None:
    with pytest.raises(ConfigError, match="unknown layout 'x99'"):
        OmniKinematics.from_layout("x99", 0.2)


def test_non_finite_inputs_are_rejected() -> None:
    kin = OmniKinematics.from_layout("b21", 0.2)
    with pytest.raises(ValueError, match="non-finite"):
        kin.to_wheel_speeds(Twist(float("nan"), 0, 0))
    with pytest.raises(ValueError, match="non-finite"):
        kin.to_twist([0.0, float("inf"), 0.0])
    with pytest.raises(ValueError, match="expected 3 wheel values"):
        kin.to_twist([0.0, 1.0])
    with pytest.raises(ValueError, match="positive"):
        kin.desaturate([1.0, 2.0, 3.0], 0.0)
