"""The motor model integrates exactly: lazy steps of any length agree."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from omnican.sim.motor import MotorState, advance

vel = st.floats(-5000, 5000)
rate = st.one_of(st.floats(100, 1e6), st.just(math.inf))
tau = st.one_of(st.just(0.0), st.floats(0.001, 0.2))
state = st.builds(MotorState, st.floats(-1e6, 1e6), vel, vel)


@given(state, vel, rate, rate, tau, st.floats(0, 0.5), st.floats(0, 0.5))
def test_split_steps_equal_one_step(s: MotorState, target: float, acc: float, dec: float,
                                    lag: float, a: float, b: float) -> None:
    one = advance(s, a + b, target, acc, dec, lag)
    two = advance(advance(s, a, target, acc, dec, lag), b, target, acc, dec, lag)
    assert two.position == pytest.approx(one.position, abs=1e-6, rel=1e-9)
    assert two.velocity == pytest.approx(one.velocity, abs=1e-6, rel=1e-9)
    assert two.demand == pytest.approx(one.demand, abs=1e-6, rel=1e-9)


@given(state, vel, st.floats(1000, 1e5), st.floats(1000, 1e5), st.floats(0.005, 0.1))
def test_matches_fine_euler_integration(s: MotorState, target: float, acc: float, dec: float,
                                        lag: float) -> None:
    dt, steps = 1e-5, 20_000  # 0.2 s
    p, v, d = s.position, s.velocity, s.demand
    for _ in range(steps):
        if d != target:
            slowing = (d > 0 and target < d) or (d < 0 and target > d)
            r = dec if slowing else acc
            d = min(d + r * dt, target) if target > d else max(d - r * dt, target)
        v_next = v + (d - v) * dt / lag
        p += 0.5 * (v + v_next) * dt
        v = v_next
    exact = advance(s, dt * steps, target, acc, dec, lag)
    assert exact.position == pytest.approx(p, abs=2.0)
    assert exact.velocity == pytest.approx(v, abs=2.0)


def test_ramp_then_hold() -> None:
    s = advance(MotorState(), 1.0, 100.0, 200.0, 400.0, 0.0)
    assert s.velocity == 100.0 and s.demand == 100.0
    assert s.position == pytest.approx(0.5 * 100 * 0.5 + 100 * 0.5)  # ramp 0.5 s, then hold
    back = advance(s, 0.1, -100.0, 200.0, 400.0, 0.0)  # reversing: decel to 0 first
    assert back.velocity == pytest.approx(100.0 - 400.0 * 0.1)


def test_bad_limits() -> None:
    with pytest.raises(ValueError):
        advance(MotorState(), 0.1, 1.0, 0.0, 1.0, 0.0)


@given(st.floats(-1e6, 1e6), vel, rate, rate, tau, st.floats(1e-6, 10.0))
def test_a_settled_motor_moves_exactly_as_the_general_formula_says(
        position: float, velocity: float, accel: float, decel: float, tau: float,
        dt: float) -> None:
    """The settled fast path (demand and velocity at the target) is the general
    closed form's result, bit for bit."""
    from omnican.sim.motor import _ramp_segments

    settled = MotorState(position, velocity, velocity)
    fast = advance(settled, dt, velocity, accel, decel, tau)
    ((duration, c0, c1),) = _ramp_segments(velocity, velocity, accel, decel, dt)
    if tau <= 0.0:
        p = position + (c0 * duration + 0.5 * c1 * duration * duration)
    else:
        e = math.exp(-duration / tau)
        k = velocity - c0 + c1 * tau
        p = position + (c0 * duration + 0.5 * c1 * duration * duration - c1 * tau * duration
                        + k * tau * (1.0 - e))
    assert fast == MotorState(p, velocity, velocity)
