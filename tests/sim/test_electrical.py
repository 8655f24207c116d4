"""The simulated drive's electrical model (omnican.sim.electrical), pure."""

from __future__ import annotations

import math

from hypothesis import given
from hypothesis import strategies as st

from omnican.sim import electrical as el

M = el.DEFAULT_MODEL
SPEED, ACCEL = st.floats(-3.0, 3.0), st.floats(-30.0, 30.0)


@given(speed=SPEED, accel=ACCEL, demand=SPEED, grounded=st.booleans(), jammed=st.booleans(),
       pushed=st.booleans())
def test_current_is_within_the_limit_and_nothing_unpowered(
        speed: float, accel: float, demand: float, grounded: bool, jammed: bool,
        pushed: bool) -> None:
    kw = {"grounded": grounded, "jammed": jammed, "pushed": pushed}
    i = el.motor_current(M, speed, accel, demand, powered=True, **kw)
    assert abs(i) <= M.limit_a
    assert el.motor_current(M, speed, accel, demand, powered=False, **kw) == 0.0


@given(speed=SPEED, accel=ACCEL)
def test_off_the_ground_a_wheel_carries_only_itself(speed: float, accel: float) -> None:
    """Off the ground the current is the wheel's own friction and inertia, no more (on
    the ground, braking, the base's inertia may even drive it); at a steady speed it is
    less than on the ground."""
    off = el.motor_current(M, speed, accel, speed, powered=True, grounded=False)
    assert abs(off) <= M.friction_a + M.accel_lifted_a * abs(accel) + 1e-9
    if abs(speed) > M.smooth_m_s:
        steady_on = el.motor_current(M, speed, 0.0, speed, powered=True)
        steady_off = el.motor_current(M, speed, 0.0, speed, powered=True, grounded=False)
        assert abs(steady_off) < abs(steady_on)


def test_a_jammed_wheel_pushes_at_the_limit_while_asked_to_move() -> None:
    assert el.motor_current(M, 0.0, 0.0, 0.3, powered=True, jammed=True) == M.limit_a
    assert el.motor_current(M, 0.0, 0.0, -0.3, powered=True, jammed=True) == -M.limit_a
    assert el.motor_current(M, 0.0, 0.0, 0.0, powered=True, jammed=True) == 0.0


@given(supply=st.floats(0.0, 60.0), currents=st.lists(st.floats(-10.0, 10.0), max_size=4))
def test_the_dc_link_sags_below_the_supply(supply: float, currents: list[float]) -> None:
    v = el.dc_link_voltage(M, supply, currents)
    assert 0.0 <= v <= supply
    assert math.isclose(v, max(0.0, supply - M.resistance_ohm * sum(map(abs, currents))))


@given(t0=st.floats(-20.0, 150.0), current=st.floats(-10.0, 10.0),
       steps=st.lists(st.floats(0.0, 30.0), min_size=1, max_size=20))
def test_the_temperature_heads_for_its_steady_state_and_never_overshoots(
        t0: float, current: float, steps: list[float]) -> None:
    steady = M.ambient_c + M.heating_c_per_a2 * current * current
    t = t0
    for dt in steps:
        after = el.temperature_after(M, t, current, dt)
        assert abs(after - steady) <= abs(t - steady) + 1e-9
        assert (after - steady) * (t - steady) >= 0  # the same side
        t = after
    # Held long enough, it gets there; and splitting a step changes nothing.
    assert math.isclose(el.temperature_after(M, t0, current, 1e4), steady, abs_tol=1e-6)
    one = el.temperature_after(M, t0, current, 10.0)
    two = el.temperature_after(M, el.temperature_after(M, t0, current, 4.0), current, 6.0)
    assert math.isclose(one, two, abs_tol=1e-9)
