"""Slip events from the wheels' and the gyro's disagreement (omnican.core.slip): when it
began and how big, a warning once it lasts, which wheel with more than three."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from omnican.core.fusion import FusionParams, HeadingFusion
from omnican.core.imu import ImuSample
from omnican.core.kinematics import OmniKinematics
from omnican.core.odometry import Odometry
from omnican.core.slip import SlipDetector, slipping_wheel

KIN = OmniKinematics.from_layout("b21", 0.19)


@given(st.integers(0, 500), st.integers(4, 300), st.floats(0.02, 1.0))
def test_an_event_names_its_start_and_size_and_a_lasting_one_warns(
        before: int, lasting: int, size: float) -> None:
    """``before`` cycles within the gate, ``lasting`` cycles of 10 ms beyond it."""
    slip = SlipDetector(confirm_s=0.03, release_s=0.1, warn_s=0.5, hold_s=2.0)
    k = 0
    for k in range(before):
        slip.update(k * 0.01, 0.001, False)
    start = before * 0.01
    for k in range(before, before + lasting):
        slip.update(k * 0.01, size, True)
    t = k * 0.01
    assert slip.started == 1
    event = slip.events[-1]
    assert event.t == start
    assert event.size == pytest.approx(size)
    warned = slip.warning is not None
    assert warned == (event.duration_s >= 0.5 - 1e-9)
    for j in range(1, 301):
        slip.update(t + j * 0.01, 0.0, False)
    assert slip.active is None and slip.warning is None and slip.started == 1


def test_noise_beyond_the_gate_for_less_than_confirm_s_is_no_event() -> None:
    slip = SlipDetector(confirm_s=0.03)
    for k in range(200):
        slip.update(k * 0.01, 0.5, k % 3 == 0)  # a cycle beyond it now and then
    assert slip.started == 0


@settings(max_examples=60, deadline=None)
@given(st.integers(4, 8), st.data())
def test_with_more_than_three_wheels_the_slipping_one_is_named(n: int,
                                                               data: st.DataObject) -> None:
    """Four wheels and the gyro, or five wheels and more with or without it."""
    kin = OmniKinematics([360.0 * i / n for i in range(n)] if n != 4
                         else [0.0, 80.0, 180.0, 250.0], 0.2)  # a kite: see below
    gyro = n == 4 or data.draw(st.booleans())
    vx, vy, wz = (data.draw(st.floats(-1.0, 1.0)) for _ in range(3))
    speeds = kin.wheel_speeds_of(vx, vy, wz)
    wheel = data.draw(st.integers(0, n - 1))
    extra = data.draw(st.floats(0.05, 0.5)) * data.draw(st.sampled_from([-1.0, 1.0]))
    measured = list(speeds)
    measured[wheel] += extra
    rate = wz if gyro else None
    # A wheel's slip leaves a residual along its column of the projector; a wheel whose
    # column is close to another's (opposite wheels of an even base drive one line: more
    # on one looks like more on the other) is seen but cannot be placed surely. Never the
    # wrong wheel; the right one whenever no other's column is within cos^2 0.5 of its own.
    m = np.vstack([kin.matrix, [0.0, 0.0, 0.2]]) if gyro else kin.matrix
    proj = np.eye(m.shape[0]) - m @ np.linalg.pinv(m)
    col = proj[:, wheel]
    close = max((col @ proj[:, i]) ** 2 / (col @ col) / (proj[:, i] @ proj[:, i])
                for i in range(n) if i != wheel)
    named = slipping_wheel(kin.matrix, measured, rate)
    assert named == wheel or (named is None and close >= 0.5 - 1e-9)
    assert slipping_wheel(kin.matrix, speeds, rate) is None  # a motion: nothing left over


def test_three_wheels_name_none_nor_four_without_a_gyro() -> None:
    assert slipping_wheel(KIN.matrix, [0.1, 0.5, -0.3], 0.2) is None
    four = OmniKinematics([0.0, 90.0, 180.0, 270.0], 0.2)
    assert slipping_wheel(four.matrix, [0.6, 0.0, 0.0, 0.0]) is None


def test_a_five_wheel_base_names_the_wheel_through_the_fusion() -> None:
    kin = OmniKinematics([0.0, 72.0, 144.0, 216.0, 288.0], 0.2)
    f = HeadingFusion(kin.rows, kin.forward_rows[2], FusionParams())
    speeds: list[float] = []
    f.wheel_speeds = lambda: speeds
    f.isolate = lambda v: slipping_wheel(kin.matrix, v, f.gyro_rate)
    odo = Odometry(kin)
    travel = [0.0] * 5
    odo.step(list(travel))
    t = 0.0
    for k in range(300):
        t += 0.01
        rims = kin.wheel_speeds_of(0.5, 0.0, 0.0)
        slipping = k >= 100
        # wheel 1 turns 20 % more than the ground takes: its encoder reads more
        measured = [v * (1.2 if slipping and i == 1 else 1.0) for i, v in enumerate(rims)]
        speeds[:] = measured
        travel = [a + v * 0.01 for a, v in zip(travel, measured, strict=True)]
        f.step(t, [ImuSample(t, 0.0)], odo.step(list(travel)), False)
    assert f.slip.started >= 1
    event = f.slip.events[0]
    assert event.wheel == 1
    assert 1.0 <= event.t <= 1.2  # flagged within 200 ms of its start
    assert math.isfinite(event.size) and abs(event.size) > 0.05
    assert np.isfinite(f.theta) and abs(f.theta) < 0.01  # the gyro held the heading
