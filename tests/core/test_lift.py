"""The lifted-wheel detector (omnican.core.lift), pure: three wheels of a kiwi base through
ramps and square runs, their currents from a motor model like the simulator's, with
the motors' constants, the load on each wheel and the time the current is sampled drawn
by hypothesis."""

from __future__ import annotations

import math

from hypothesis import given, settings
from hypothesis import strategies as st

from omnican.core.kinematics import OmniKinematics
from omnican.core.lift import LiftDetector

DT = 0.2  # the health values' period (5 Hz)
SUB = 20  # motion steps per check
KIN = OmniKinematics.from_layout("b21", base_radius=0.19)


def motor_current(speed: float, accel: float, friction: float, rolling: float,
                  inertia: float, grounded: bool) -> float:
    direction = math.tanh(speed / 0.005)
    if grounded:
        return (friction + rolling) * direction + inertia * accel
    return friction * direction + 0.1 * accel


@st.composite
def runs(draw: st.DrawFn) -> list[tuple[float, float, float]]:
    """Body twists held for a while each (a square run, spins, diagonals), reached at
    the limiter's accelerations."""
    legs = draw(st.lists(st.tuples(st.floats(-0.8, 0.8), st.floats(-0.8, 0.8),
                                   st.floats(-3.0, 3.0), st.integers(2, 15)),
                         min_size=1, max_size=6))
    accel = draw(st.floats(0.3, 2.0))
    out, v = [], (0.0, 0.0, 0.0)
    for vx, vy, wz, hold in [*legs, (0.0, 0.0, 0.0, 5)]:
        goal = (vx, vy, wz)
        while v != goal:
            d = [g - c for g, c in zip(goal, v, strict=True)]
            norm = max(math.hypot(d[0], d[1]), abs(d[2]) / 3.0)
            step = accel * DT / SUB
            k = 1.0 if norm <= step else step / norm
            v = (v[0] + k * d[0], v[1] + k * d[1], v[2] + k * d[2])
            out.append(v)
        out += [v] * (hold * SUB)
    return out


def detect(twists: list[tuple[float, float, float]], consts: tuple[float, float, float],
           shares: tuple[float, float, float], tau: float, delay: int,
           lifted: int | None = None) -> list[int]:
    """The wheels found off the ground over a run (each wheel's speed follows its target
    with time constant ``tau``; the speeds a check is given are ``delay`` motion steps
    older than its currents, or the currents older when ``delay`` is negative)."""
    friction, rolling, inertia = consts
    det = LiftDetector(3)
    speed = [0.0, 0.0, 0.0]
    speeds: list[list[float]] = []
    currents: list[list[float]] = []
    found: list[int] = []
    h = DT / SUB
    for k, twist in enumerate(twists):
        target = KIN.wheel_speeds_of(*twist)
        accel = [(t - s) / tau for t, s in zip(target, speed, strict=True)]
        speed = [s + a * h for s, a in zip(speed, accel, strict=True)]
        speeds.append(speed)
        currents.append([motor_current(s, a, friction, rolling * w, inertia * w, i != lifted)
                         for i, (s, a, w) in enumerate(zip(speed, accel, shares, strict=True))])
        if k % SUB == SUB - 1:
            measured = speeds[max(0, k - max(0, delay))]
            current = currents[max(0, k - max(0, -delay))]
            found += [f.wheel for f in det.update(k * h, measured, current)]
    return found


CONSTS = st.tuples(st.floats(0.05, 1.0), st.floats(0.05, 1.0), st.floats(0.3, 3.0))
SHARES = st.tuples(st.floats(0.8, 1.2), st.floats(0.8, 1.2), st.floats(0.8, 1.2))


@settings(max_examples=150, deadline=None)
@given(twists=runs(), consts=CONSTS, shares=SHARES, tau=st.floats(0.01, 0.15),
       delay=st.integers(-SUB // 2, SUB // 2))
def test_wheels_on_the_ground_are_never_taken_for_lifted(
        twists: list[tuple[float, float, float]], consts: tuple[float, float, float],
        shares: tuple[float, float, float], tau: float, delay: int) -> None:
    """Whatever the ramps, the motors' friction, rolling resistance and inertia, a load
    shared unevenly (within 1.5 : 1), a slow velocity loop, a current sampled up to
    half a check before or after the speeds."""
    assert detect(twists, consts, shares, tau, delay) == []


def square(speed: float = 0.4, hold: int = 40) -> list[tuple[float, float, float]]:
    out: list[tuple[float, float, float]] = []
    for vx, vy in ((1, 0), (0, 1), (-1, 0), (0, -1)):
        out += [(speed * vx, speed * vy, 0.0)] * hold * SUB
    return out


@given(wheel=st.sampled_from([0, 1, 2]), consts=st.sampled_from([(0.3, 0.4, 1.5)]))
def test_a_lifted_wheel_is_found_in_a_square_run(wheel: int,
                                                 consts: tuple[float, float, float]) -> None:
    """The simulator's motor: each wheel, off the ground, is found (once)."""
    assert detect(square(), consts, (1.0, 1.0, 1.0), 0.01, 0, lifted=wheel) == [wheel]


def test_a_wheel_found_back_on_the_ground_is_cleared() -> None:
    det = LiftDetector(2, time_s=0.0, checks=1)
    for t in (0.0, 0.2, 0.4):  # holding speed from 0.2 s on, its current 0.4 s confirmed
        assert det.update(t, [0.5, 0.5], [0.7, 0.2]) == []
    assert [f.wheel for f in det.update(0.6, [0.5, 0.5], [0.7, 0.7])] == [1]
    assert set(det.lifted) == {1}
    assert "wheel 1 (node 3) off the ground" in det.lifted[1].describe(3)
    det.update(0.8, [0.5, 0.5], [0.7, 0.7])
    assert det.lifted == {}
