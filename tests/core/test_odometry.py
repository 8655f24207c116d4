"""Odometry: exact SE(2) integration of wheel travel; no drift for a pure spin."""

from __future__ import annotations

import math
from dataclasses import astuple

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from omnican import Displacement, Odometry, OmniKinematics, Pose2D, Twist
from omnican.core.odometry import wrap_angle

KIN = OmniKinematics.from_layout("b21", base_radius=0.19)
finite = st.floats(-3, 3, allow_nan=False)
poses = st.builds(Pose2D, finite, finite, st.floats(-10, 10))


def drive(odo: Odometry, twist: Twist, duration: float, steps: int, start: np.ndarray) -> Pose2D:
    rates = KIN.to_wheel_speeds(twist)
    odo.update(start)
    for k in range(1, steps + 1):
        odo.update(start + rates * duration * k / steps)
    return odo.pose


@given(st.builds(Twist, finite, finite, st.floats(-4, 4)))
def test_one_step_equals_thousand_steps(t: Twist) -> None:
    start = np.array([10.0, -3.0, 7.5])
    one = drive(Odometry(KIN), t, 2.0, 1, start)
    many = drive(Odometry(KIN), t, 2.0, 1000, start)
    assert one.x == pytest.approx(many.x, abs=1e-9)
    assert one.y == pytest.approx(many.y, abs=1e-9)
    assert one.theta == pytest.approx(many.theta, abs=1e-9)


def test_constant_twist_traces_the_exact_arc() -> None:
    # 0.5 m/s forward while turning at 0.5 rad/s for 2 pi s: a half circle of radius 1 m.
    pose = drive(Odometry(KIN), Twist(0.5, 0, 0.5), 2 * math.pi, 1, np.zeros(3))
    assert pose.x == pytest.approx(0.0, abs=1e-12)
    assert pose.y == pytest.approx(2.0, abs=1e-12)
    assert pose.theta == pytest.approx(math.pi, abs=1e-12)


def test_first_update_only_seeds() -> None:
    odo = Odometry(KIN)
    assert odo.update([123.4, -55.0, 9.0]) == Pose2D()
    assert odo.seeded


def test_closed_square_returns_to_start() -> None:
    odo = Odometry(KIN)
    travel = np.array([1000.0, 2000.0, -3000.0])
    odo.update(travel)
    for _ in range(4):
        for t in (Twist(1.0, 0, 0), Twist(0, 0, math.pi / 2)):  # 1 m side, then turn 90 deg
            for _ in range(50):
                travel = travel + KIN.to_wheel_speeds(t) / 50
                odo.update(travel)
    assert odo.pose.x == pytest.approx(0.0, abs=1e-9)
    assert odo.pose.y == pytest.approx(0.0, abs=1e-9)
    assert odo.pose.theta == pytest.approx(2 * math.pi, abs=1e-9)  # continuous theta
    assert odo.pose.heading == pytest.approx(0.0, abs=1e-9)


def test_pure_spin_has_no_drift() -> None:
    odo = Odometry(KIN)
    travel = np.zeros(3)
    odo.update(travel)
    for _ in range(1000):
        travel = travel + 0.19 * 0.01  # every rim at R * dtheta
        odo.update(travel)
    assert odo.pose.x == pytest.approx(0.0, abs=1e-12)
    assert odo.pose.y == pytest.approx(0.0, abs=1e-12)
    assert odo.pose.theta == pytest.approx(10.0)


def test_twist_and_delta_of_last_step() -> None:
    odo = Odometry(KIN)
    odo.update([0.0, 0.0, 0.0])
    step = KIN.to_wheel_speeds(Twist(0.2, 0.1, 0.0)) * 0.01
    odo.update(step, dt_s=0.01)
    assert astuple(odo.twist) == pytest.approx((0.2, 0.1, 0.0), abs=1e-12)
    assert astuple(odo.delta) == pytest.approx((0.002, 0.001, 0.0), abs=1e-14)


def test_reset_keeps_reference() -> None:
    odo = Odometry(KIN)
    odo.update([0.0, 0.0, 0.0])
    odo.update([0.0, 0.5, -0.5])
    odo.reset(Pose2D(1.0, 2.0, 0.5))
    assert odo.pose == Pose2D(1.0, 2.0, 0.5)
    odo.update([0.0, 0.5, -0.5])  # no new travel -> no jump
    assert odo.pose == Pose2D(1.0, 2.0, 0.5)


def test_bad_travel_is_rejected() -> None:
    odo = Odometry(KIN)
    with pytest.raises(ValueError, match="non-finite"):
        odo.update([0.0, float("nan"), 0.0])
    with pytest.raises(ValueError, match="expected 3"):
        odo.update([0.0, 0.0])


@given(poses, poses)
def test_compose_inverse(a: Pose2D, b: Pose2D) -> None:
    ident = a.compose(a.inverse())
    assert ident.x == pytest.approx(0, abs=1e-9) and ident.y == pytest.approx(0, abs=1e-9)
    back = a.compose(b).relative_to(a)
    assert (back.x, back.y, back.theta) == pytest.approx((b.x, b.y, b.theta), abs=1e-9)


@given(st.builds(Displacement, finite, finite, st.floats(-3, 3)))
def test_exp_log_round_trip(t: Displacement) -> None:
    back = Pose2D.exp(t).log()
    assert (back.dx, back.dy, back.dtheta) == pytest.approx((t.dx, t.dy, t.dtheta), abs=1e-9)


@given(st.floats(-1e-3, 1e-3), finite, finite)
def test_small_angle_exp_is_continuous(theta: float, x: float, y: float) -> None:
    p = Pose2D.exp(Displacement(x, y, theta))
    c, s = math.cos(theta / 2), math.sin(theta / 2)  # chord of the arc at half angle
    chord = math.hypot(x, y) * (1 - theta**2 / 24)
    assert math.hypot(p.x, p.y) == pytest.approx(chord, abs=1e-9)
    assert c * p.x + s * p.y == pytest.approx(math.hypot(p.x, p.y) * math.cos(
        math.atan2(y, x)), abs=1e-6)


@given(st.floats(-100, 100))
def test_wrap_angle_range(a: float) -> None:
    w = wrap_angle(a)
    assert -math.pi < w <= math.pi
    assert math.cos(w) == pytest.approx(math.cos(a), abs=1e-9)


def _reference_steps(kin: OmniKinematics, travels: list[list[float]]) -> list[tuple[float, ...]]:
    """Odometry.step as a loop over any number of wheels: the pose and the step after
    each set of travels."""
    cols = kin.forward_cols
    x = y = th = 0.0
    out: list[tuple[float, ...]] = []
    last: list[float] | None = None
    for travel in travels:
        if last is not None:
            dx = dy = dw = 0.0
            for (ca, cb, cc), v1, v0 in zip(cols, travel, last, strict=True):
                d = v1 - v0
                dx += ca * d
                dy += cb * d
                dw += cc * d
            if -1e-4 < dw < 1e-4:
                t2 = dw * dw
                a, b = 1.0 - t2 / 6.0 + t2 * t2 / 120.0, dw / 2.0 - dw * t2 / 24.0
            else:
                a, b = math.sin(dw) / dw, (1.0 - math.cos(dw)) / dw
            lx, ly = a * dx - b * dy, b * dx + a * dy
            c, s = math.cos(th), math.sin(th)
            x, y, th = x + (c * lx - s * ly), y + (s * lx + c * ly), th + dw
            out.append((x, y, th, dx, dy, dw))
        last = travel
    return out


@given(st.lists(st.floats(-180, 180), min_size=3, max_size=3, unique=True),
       st.floats(0.05, 1.0),
       st.lists(st.lists(st.floats(-100, 100) | st.sampled_from([0.0, -0.0, 1e-9]),
                         min_size=3, max_size=3), min_size=2, max_size=20))
def test_three_wheels_integrate_as_the_loop_over_any_number_does(
        angles: list[float], radius: float, travels: list[list[float]]) -> None:
    """The three-wheel step (written out) gives the general loop's pose and step bit for
    bit, whatever the layout and the travel (zero, tiny and large steps, signed zeros)."""
    try:
        kin = OmniKinematics(angles_deg=angles, base_radius=radius)
    except ValueError:
        return  # a layout that cannot move the base in every direction
    odo = Odometry(kin)
    got = []
    for travel in travels:
        if odo.step(list(travel)) is not None:
            got.append((*odo.xyt, *odo.last_step))
    assert got == _reference_steps(kin, travels)
