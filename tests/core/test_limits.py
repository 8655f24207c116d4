"""Limits: direction kept, limits never exceeded over random command sequences."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from omnican import OmniKinematics, Twist, VelocityLimiter, VelocityLimits
from omnican.core.limits import desaturate_twist, longest_stop_s

KIN = OmniKinematics.from_layout("b21", base_radius=0.19)
LIMITS = VelocityLimits(
    max_linear=0.8, max_angular=2.0, max_linear_accel=1.0, max_angular_accel=3.0,
    stop_linear_decel=2.5, stop_angular_decel=6.0, max_wheel_speed=0.7,
)
cmd = st.builds(Twist, st.floats(-3, 3), st.floats(-3, 3), st.floats(-8, 8))
zero_or_cmd = st.one_of(cmd, st.just(Twist()))
EPS = 1e-9


def parallel(a: Twist, b: Twist) -> bool:
    """b is a non-negative multiple of a (same direction in twist space)."""
    va, vb = a.as_array(), b.as_array()
    if np.linalg.norm(vb) < 1e-12:
        return True
    cross = np.linalg.norm(np.outer(va, vb) - np.outer(vb, va))
    return bool(cross < 1e-9 * max(1.0, np.linalg.norm(va) ** 2) and va @ vb >= 0)


@given(cmd)
def test_target_keeps_direction_and_limits(c: Twist) -> None:
    lim = VelocityLimiter(LIMITS, KIN)
    t = lim.target(c)
    assert parallel(c, t)
    assert t.linear_speed <= LIMITS.max_linear + EPS
    assert abs(t.wz) <= LIMITS.max_angular + EPS
    assert np.max(np.abs(KIN.to_wheel_speeds(t))) <= LIMITS.max_wheel_speed + EPS


def test_per_axis_clipping_would_bend_the_path() -> None:
    lim = VelocityLimiter(VelocityLimits(max_linear=1.0))
    t = lim.target(Twist(3.0, 1.0, 0.0))
    assert t.vy / t.vx == pytest.approx(1 / 3)
    assert t.linear_speed == pytest.approx(1.0)


@settings(max_examples=60)
@given(st.lists(st.tuples(zero_or_cmd, st.integers(1, 40)), min_size=1, max_size=12),
       st.sampled_from([0.001, 0.01, 0.05]))
def test_limits_never_exceeded_over_a_sequence(seq: list[tuple[Twist, int]], dt: float) -> None:
    lim = VelocityLimiter(LIMITS, KIN)
    prev = Twist()
    for command, cycles in seq:
        for _ in range(cycles):
            out = lim.step(command, dt)
            assert out.linear_speed <= LIMITS.max_linear + EPS
            assert abs(out.wz) <= LIMITS.max_angular + EPS
            assert np.max(np.abs(KIN.to_wheel_speeds(out))) <= LIMITS.max_wheel_speed + EPS
            dv = math.hypot(out.vx - prev.vx, out.vy - prev.vy) / dt
            dw = abs(out.wz - prev.wz) / dt
            lin_lim = LIMITS.stop_linear_decel if command.is_zero() else LIMITS.max_linear_accel
            ang_lim = LIMITS.stop_angular_decel if command.is_zero() else LIMITS.max_angular_accel
            assert dv <= lin_lim * (1 + 1e-9)
            assert dw <= ang_lim * (1 + 1e-9)
            prev = out


@given(cmd)
def test_accelerating_from_rest_keeps_direction(c: Twist) -> None:
    lim = VelocityLimiter(LIMITS, KIN)
    target = lim.target(c)
    for _ in range(500):
        out = lim.step(c, 0.01)
        assert parallel(target, out)
    assert out.as_array() == pytest.approx(target.as_array(), abs=1e-9)


def test_stop_uses_the_larger_deceleration() -> None:
    lim = VelocityLimiter(LIMITS, KIN)
    lim.reset(Twist(0.5, 0.0, 0.0))
    out = lim.step(Twist(), 0.1)
    assert out.vx == pytest.approx(0.5 - 0.25)  # 2.5 m/s^2 * 0.1 s
    lim.reset(Twist(0.5, 0.0, 0.0))
    out = lim.step(Twist(0.1, 0.0, 0.0), 0.1)  # slowing, not stopping: accel limit
    assert out.vx == pytest.approx(0.5 - 0.1)


def test_bad_input_is_rejected() -> None:
    lim = VelocityLimiter(LIMITS, KIN)
    with pytest.raises(ValueError, match="non-finite"):
        lim.step(Twist(float("nan"), 0, 0), 0.01)
    with pytest.raises(ValueError, match="dt"):
        lim.step(Twist(), float("nan"))
    with pytest.raises(ValueError, match="max_linear must be a positive number"):
        VelocityLimits(max_linear=0.0)
    assert lim.output == Twist()


@given(
    cmds=st.lists(st.tuples(st.floats(-3, 3), st.floats(-3, 3), st.floats(-10, 10)),
                  min_size=1, max_size=30),
    dt=st.floats(0.0, 0.05),
)
def test_loop_form_matches_the_three_steps(cmds: list[tuple[float, float, float]],
                                           dt: float) -> None:
    """step_xyz (the control loop's float form) is the same limiter as clamp ->
    desaturate -> limit_step composed on Twist objects."""
    from omnican.core.limits import limit_step

    lim = VelocityLimiter(LIMITS, KIN)
    prev = Twist()
    for vx, vy, wz in cmds:
        expected = limit_step(prev, lim.target(Twist(vx, vy, wz)), dt, LIMITS)
        got = lim.step_xyz(vx, vy, wz, dt)
        assert got == pytest.approx((expected.vx, expected.vy, expected.wz), abs=1e-12)
        prev = expected


@given(
    cmds=st.lists(st.tuples(st.tuples(st.floats(-3, 3), st.floats(-3, 3), st.floats(-10, 10)),
                            st.integers(1, 40)), min_size=1, max_size=8),
    dt=st.floats(0.0, 0.05),
)
def test_a_held_command_gives_what_a_fresh_computation_gives(
        cmds: list[tuple[tuple[float, float, float], int]], dt: float) -> None:
    """Commands held for many cycles (the loop's usual case: the limiter reuses its last
    target and output) ramp, and then hold, exactly as the three steps say."""
    from omnican.core.limits import limit_step

    lim = VelocityLimiter(LIMITS, KIN)
    prev = Twist()
    for (vx, vy, wz), repeats in cmds:
        for _ in range(repeats):
            expected = limit_step(prev, lim.target(Twist(vx, vy, wz)), dt, LIMITS)
            got = lim.step_xyz(vx, vy, wz, dt)
            assert got == pytest.approx((expected.vx, expected.vy, expected.wz), abs=1e-12)
            prev = Twist(*got)


# ---------------------------------------------------------------- the longest stop

@settings(max_examples=60)
@given(vx=st.floats(-5, 5), vy=st.floats(-5, 5), wz=st.floats(-20, 20),
       decel=st.floats(0.2, 10), adecel=st.floats(0.5, 30), radius=st.floats(0.1, 0.5))
def test_no_stop_ramp_outlasts_the_longest_stop(vx: float, vy: float, wz: float, decel: float,
                                                adecel: float, radius: float) -> None:
    """From any twist the limiter reaches (at its wheel limit), a stop command brings the
    output to zero within longest_stop_s."""
    kin = OmniKinematics.from_layout("b21", base_radius=radius)
    lim = VelocityLimits(max_linear_accel=100.0, max_angular_accel=300.0,
                         stop_linear_decel=decel, stop_angular_decel=adecel,
                         max_wheel_speed=1.0)
    limiter = VelocityLimiter(lim, kin)
    for _ in range(40):
        limiter.step(Twist(vx, vy, wz), 0.05)
    bound = longest_stop_s(lim, kin)
    dt, t = 0.01, 0.0
    while not limiter.output.is_zero():
        limiter.step(Twist(), dt)
        t += dt
        assert t <= bound + dt


# ---------------------------------------------------------------- the stop in bounded time

_decel = st.floats(1e-300, 1e3)
_wheel = st.floats(0.05, 5.0)


@given(st.builds(Twist, st.floats(-100, 100), st.floats(-100, 100), st.floats(-100, 100)),
       _decel, _decel, _wheel, st.sampled_from([0.001, 0.01, 0.05]))
@settings(max_examples=60)
def test_a_stop_ends_within_max_stop_s_whatever_the_decelerations(
        command: Twist, lin: float, ang: float, wheel: float, dt: float) -> None:
    """From whatever the limiter outputs, a stop reaches zero within MAX_STOP_S (and one
    step), be the stop decelerations 1e-300 or the limits unlimited."""
    from omnican.core.limits import MAX_STOP_S

    limits = VelocityLimits(max_linear_accel=1e3, max_angular_accel=1e3,
                            stop_linear_decel=lin, stop_angular_decel=ang,
                            max_wheel_speed=wheel)
    lim = VelocityLimiter(limits, KIN)
    for _ in range(200):
        lim.step(command, 0.01)
    assert lim.stop_time_s() <= MAX_STOP_S + 1e-9
    steps = 0
    while not lim.output.is_zero():
        lim.step(Twist(), dt)
        steps += 1
        assert steps * dt <= MAX_STOP_S + dt + 1e-9, lim.output


@given(st.floats(0.05, 5.0), st.builds(Twist, st.floats(-3, 3), st.floats(-3, 3),
                                       st.floats(-8, 8)))
def test_top_speeds_bound_every_twist_the_wheels_allow(wheel: float, t: Twist) -> None:
    """b21 at the wheel limit w: 4/3 w linear (two wheels +w, one -w), w / R spinning;
    no twist within the wheel limit is faster."""
    from omnican.core.limits import top_speeds

    lin, ang = top_speeds(VelocityLimits(max_wheel_speed=wheel), KIN)
    assert lin == pytest.approx(4.0 / 3.0 * wheel)
    assert ang == pytest.approx(wheel / 0.19)
    feasible = desaturate_twist(t, KIN, wheel)
    assert feasible.linear_speed <= lin + 1e-9 and abs(feasible.wz) <= ang + 1e-9


def test_lowering_the_limits_while_fast_keeps_the_stop_bounded() -> None:
    """Limits lowered while the output is above them: the stop from there still ends
    within MAX_STOP_S."""
    from omnican.core.limits import MAX_STOP_S

    lim = VelocityLimiter(VelocityLimits(max_wheel_speed=5.0, stop_linear_decel=1e-9,
                                         stop_angular_decel=1e-9), KIN)
    lim.step(Twist(3.0, 0.0, 0.0), 1.0)
    lim.limits = VelocityLimits(max_linear=0.01, max_wheel_speed=5.0, stop_linear_decel=1e-9,
                                stop_angular_decel=1e-9)
    assert lim.stop_time_s() <= MAX_STOP_S


@pytest.mark.parametrize(("twist", "problem"), [
    ((1e308, 0.0, 0.0), "vx 1e+308 m/s is beyond any wheeled base (at most 100"),
    ((0.0, -101.0, 0.0), "vy -101 m/s is beyond any wheeled base"),
    ((0.0, 0.0, 1e9), "wz 1e+09 rad/s is beyond any wheeled base"),
    ((math.nan, 0.0, 0.0), "vx must be a finite number, got nan"),
    ((0.0, 0.0, -math.inf), "wz must be a finite number, got -inf"),
])
def test_a_command_beyond_sense_is_refused_with_the_reason(
        twist: tuple[float, float, float], problem: str) -> None:
    from omnican.core.limits import command_problem

    assert (command_problem(*twist) or "").startswith(problem)


@given(st.floats(-100, 100), st.floats(-100, 100), st.floats(-100, 100))
def test_a_command_within_sense_is_taken(vx: float, vy: float, wz: float) -> None:
    from omnican.core.limits import command_problem

    assert command_problem(vx, vy, wz) is None


def test_a_pose_beyond_sense_is_refused() -> None:
    from omnican.core.limits import pose_problem

    assert pose_problem(1e308, 0.0, 0.0) == ("x 1e+308 m is beyond 1e+06 m (the motion "
                                             "added to it would be lost to rounding)")
    assert pose_problem(0.0, 0.0, math.nan) == "theta must be a finite number, got nan"
    assert pose_problem(-1e6, 1e6, 1e3) is None
