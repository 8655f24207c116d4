"""An IMU's mounting, units and times, as the base reads them (pure)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from omnican.core.imu import (
    ImuInbox,
    ImuMount,
    ImuSample,
    accel_unit,
    host_time,
    rate_unit,
)

finite = st.floats(-100, 100, allow_nan=False)
mounts = st.builds(ImuMount, st.floats(-360, 360, allow_nan=False), st.booleans())


@given(mounts, finite, finite, finite)
def test_to_base_undoes_what_the_mounted_imu_measures(mount: ImuMount, wz: float, ax: float,
                                                      ay: float) -> None:
    measured = mount.from_base(wz, ax, ay)
    back = mount.to_base(1.0, *measured)
    assert back.yaw_rate == pytest.approx(wz, abs=1e-9)
    assert back.accel_x == pytest.approx(ax, abs=1e-9)
    assert back.accel_y == pytest.approx(ay, abs=1e-9)
    assert back.t == 1.0


@given(st.floats(-360, 360, allow_nan=False), finite)
def test_a_yaw_turn_keeps_the_yaw_rate_and_upside_down_negates_it(yaw: float,
                                                                   wz: float) -> None:
    assert ImuMount(yaw).to_base(0.0, wz).yaw_rate == wz
    assert ImuMount(yaw, upside_down=True).to_base(0.0, wz).yaw_rate == -wz


@given(mounts, finite, finite)
def test_the_accelerations_keep_their_size(mount: ImuMount, ax: float, ay: float) -> None:
    s = mount.to_base(0.0, 0.0, ax, ay)
    assert s.accel_x is not None and s.accel_y is not None
    assert math.hypot(s.accel_x, s.accel_y) == pytest.approx(math.hypot(ax, ay), abs=1e-9)


def test_an_imu_turned_a_quarter_left_reads_the_base_y_on_its_x() -> None:
    # Its x axis points along the base's y: 1 m/s^2 on its x is 1 m/s^2 to the base's left.
    s = ImuMount(90.0).to_base(0.0, 0.0, 1.0, 0.0)
    assert (s.accel_x, s.accel_y) == (pytest.approx(0.0, abs=1e-12), pytest.approx(1.0))
    # Upside down (turned over its x): its y points right.
    s = ImuMount(0.0, upside_down=True).to_base(0.0, 0.0, 0.0, 1.0)
    assert (s.accel_x, s.accel_y) == (0.0, -1.0)


def test_a_sample_without_both_accelerations_has_none() -> None:
    assert ImuMount(30.0).to_base(2.0, 0.1, 1.0, None) == ImuSample(2.0, 0.1)


@pytest.mark.parametrize(("unit", "factor"), [
    ("deg/s", math.pi / 180), ("°/s", math.pi / 180), ("Deg / s", math.pi / 180),
    ("rad/s", 1.0), ("mrad/s", 1e-3)])
def test_rate_units(unit: str, factor: float) -> None:
    assert rate_unit(unit) == pytest.approx(factor)


@pytest.mark.parametrize("unit", ["", "rpm", "m/s", "deg"])
def test_unknown_rate_units_are_none(unit: str) -> None:
    assert rate_unit(unit) is None


def test_accel_units() -> None:
    assert accel_unit("m/s^2") == 1.0
    assert accel_unit("g") == pytest.approx(9.80665)
    assert accel_unit("deg/s") is None


@given(st.floats(0, 1e6), st.floats(1e9, 2e9), st.floats(-5, 5))
def test_a_believable_stamp_moves_back_by_its_age_and_another_is_the_arrival(
        now: float, now_wall: float, age: float) -> None:
    stamp = now_wall - age
    age = now_wall - stamp  # as the float subtraction has it
    t = host_time(stamp, now, now_wall, max_age_s=1.0)
    if 0 <= age <= 1.0:
        assert t == pytest.approx(now - age)
        assert t <= now
    else:
        assert t == now


@given(st.lists(st.floats(0, 1e6), min_size=1, max_size=20))
def test_the_inbox_keeps_the_newest_time(times: list[float]) -> None:
    inbox = ImuInbox()
    assert inbox.last_t is None
    for t in times:
        inbox.put(ImuSample(t, 0.0))
    inbox.drain()
    assert inbox.last_t == times[-1]  # draining does not forget when the IMU last spoke
