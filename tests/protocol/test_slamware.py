"""SLAMWARE 0x41 codec and dead reckoning."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from omnican import OmniKinematics, Twist
from omnican.protocol.slamware import (
    DeadReckoner,
    decode_deadreckon_response,
    decode_velocity_request,
    encode_deadreckon_response,
    encode_velocity_request,
)

COS30 = math.cos(math.radians(30))


def test_velocity_request_bytes() -> None:
    # 0.5 m/s = 0x8000, -0.25 m/s = -0x4000, 1.0 rad/s = 0x10000.
    data = encode_velocity_request(0.5, -0.25, 1.0)
    assert data == bytes.fromhex("00800000" "00c0ffff" "00000100")
    assert len(data) == 12
    assert decode_velocity_request(data) == (0.5, -0.25, 1.0)


def test_deadreckon_response_bytes() -> None:
    # dx 1 mm -> 0x10000; dy -2 mm -> -0x20000; dtheta pi/2 -> 90 deg -> 0x5A0000; status 3.
    data = encode_deadreckon_response(0.001, -0.002, math.pi / 2, status=3)
    assert data == bytes.fromhex("00000100" "0000feff" "00005a00" "03")
    assert len(data) == 13
    dx, dy, dth, status = decode_deadreckon_response(data)
    assert (dx, dy, status) == (pytest.approx(0.001), pytest.approx(-0.002), 3)
    assert dth == pytest.approx(math.pi / 2)


def test_rounds_to_nearest_q16_step() -> None:
    # 1/3 m/s * 65536 = 21845.33 -> 21845 (the seed's truncation agrees here) ...
    assert struct.unpack("<iii", encode_velocity_request(1 / 3, -1 / 3, 0))[:2] == (21845, -21845)
    # ... and 2/3 m/s = 43690.67 -> 43691 (truncation would lose a step).
    assert struct.unpack("<iii", encode_velocity_request(2 / 3, 0, 0))[0] == 43691


def test_out_of_range_saturates() -> None:
    raw = struct.unpack("<iii", encode_velocity_request(1e6, -1e6, math.inf))
    assert raw == (2**31 - 1, -(2**31), 2**31 - 1)
    dx_raw = struct.unpack("<iiiB", encode_deadreckon_response(100.0, 0, 0))[0]
    assert dx_raw == 2**31 - 1  # 100 m = 1e5 mm is beyond Q16's 32767 mm


def test_wrong_length_and_bad_values() -> None:
    with pytest.raises(ValueError, match="must be 12 bytes, got 11"):
        decode_velocity_request(b"\x00" * 11)
    with pytest.raises(ValueError, match="must be 13 bytes, got 12"):
        decode_deadreckon_response(b"\x00" * 12)
    with pytest.raises(ValueError, match="NaN"):
        encode_velocity_request(float("nan"), 0, 0)
    with pytest.raises(ValueError, match="status"):
        encode_deadreckon_response(0, 0, 0, status=256)


q16_range = st.floats(-32767, 32767, allow_nan=False)


@given(q16_range, q16_range, q16_range)
def test_velocity_round_trip(vx: float, vy: float, w: float) -> None:
    got = decode_velocity_request(encode_velocity_request(vx, vy, w))
    assert got == pytest.approx((vx, vy, w), abs=0.5 / 65536)


@given(st.floats(-32, 32), st.floats(-32, 32), st.floats(-500, 500), st.integers(0, 255))
def test_response_round_trip(dx: float, dy: float, dth: float, status: int) -> None:
    got = decode_deadreckon_response(encode_deadreckon_response(dx, dy, dth, status))
    assert got[:3] == pytest.approx((dx, dy, dth), abs=1e-6)
    assert got[3] == status


@given(st.binary(min_size=12, max_size=12))
def test_any_request_bytes_round_trip(data: bytes) -> None:
    assert encode_velocity_request(*decode_velocity_request(data)) == data


def seed_b21_fixed(da: float, db: float, dc: float) -> tuple[float, float]:
    """The note's b21 Dx, with the corrected Dy of DESIGN.md."""
    return (db / COS30 - dc / COS30) / 2, (-2 * da + db + dc) / 3


def seed_a12_code(da: float, db: float, dc: float, R: float) -> tuple[float, float, float]:
    """The note's a12 C code, as printed (its Dy is wrong under rotation)."""
    return (-db / COS30 + dc / COS30) / 2, (da - db / 0.5 - dc / 0.5) / 3, (da + db + dc) / R / 3


@given(st.floats(-1, 1), st.floats(-1, 1))
def test_matches_seed_without_rotation(vx: float, vy: float) -> None:
    for layout in ("b21", "a12"):
        kin = OmniKinematics.from_layout(layout, 0.18)
        dr = DeadReckoner(kin)
        dr.displacement([5.0, 6.0, 7.0])
        travel = np.array([5.0, 6.0, 7.0]) + kin.to_wheel_speeds(Twist(vx, vy, 0))
        moved = dr.displacement(travel)
        d = travel - np.array([5.0, 6.0, 7.0])
        if layout == "b21":
            expect = seed_b21_fixed(*d)
        else:
            expect = seed_a12_code(*d, 0.18)[:2]
        assert (moved.x, moved.y) == pytest.approx(expect, abs=1e-9)
        assert moved.theta == pytest.approx(0.0, abs=1e-12)


def test_spin_in_place_reports_no_translation() -> None:
    R = 0.18
    kin = OmniKinematics.from_layout("a12", R)
    dr = DeadReckoner(kin)
    first = dr.handle(encode_velocity_request(0, 0, 1.0), [0.0, 0.0, 0.0])
    assert decode_deadreckon_response(first.response)[:3] == (0.0, 0.0, 0.0)
    step = dr.handle(encode_velocity_request(0, 0, 1.0), [R * 0.5] * 3)
    dx, dy, dth, _ = decode_deadreckon_response(step.response)
    assert (dx, dy) == (0.0, 0.0)
    assert dth == pytest.approx(0.5, abs=1e-6)
    # The note's a12 code reports a lateral drift of -R * dtheta for the same interval.
    assert seed_a12_code(R * 0.5, R * 0.5, R * 0.5, R)[1] == pytest.approx(-R * 0.5)
    np.testing.assert_allclose(step.wheel_speeds, [R] * 3)
    assert step.velocity == Twist(0.0, 0.0, 1.0)


def test_displacement_is_in_previous_frame_with_rotation() -> None:
    kin = OmniKinematics.from_layout("b21", 0.2)
    dr = DeadReckoner(kin)
    dr.displacement([0.0, 0.0, 0.0])
    # Constant twist 1 m/s forward, pi/2 rad/s for 1 s: a quarter circle of radius 2/pi.
    moved = dr.displacement(kin.to_wheel_speeds(Twist(1.0, 0.0, math.pi / 2)))
    r = 2 / math.pi
    assert (moved.x, moved.y, moved.theta) == pytest.approx((r, r, math.pi / 2))
