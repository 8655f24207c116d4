"""The teleop command model: key map, speed scales within the limits, and the input
timeout / deadman rule a keyboard and a gamepad share. Pure: no bus, no threads."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from omnican import Twist, default_config
from omnican.command.teleop import (
    MOVE_BINDINGS,
    SPEED_BINDINGS,
    Intent,
    TeleopModel,
    key_action,
    speed_limits,
)

keys = st.text(min_size=1, max_size=1)
times = st.floats(0, 1e6, allow_nan=False)


def model(timeout_s: float = 0.6, speed: float = 0.3, turn: float = 1.0,
          max_speed: float = 1.0, max_turn: float = 5.0) -> TeleopModel:
    return TeleopModel(speed, turn, max_speed, max_turn, timeout_s)


@given(keys, times)
def test_every_key_does_one_thing(key: str, now: float) -> None:
    m = model()
    action = m.press(key, now)
    assert action == key_action(key)
    command = m.command(now)
    if action.intent is Intent.MOVE:
        x, y, th = MOVE_BINDINGS[key]
        assert command == Twist(x * 0.3, y * 0.3, th * 1.0)
    else:  # speed keys, recover, quit and every unbound key leave the base still
        assert command == Twist()
    assert m.recover_requested == (action.intent is Intent.RECOVER)
    assert m.quit_requested == (action.intent is Intent.QUIT)
    assert m.last_input == key and m.last_input_at == now


@given(st.lists(keys, max_size=30), st.floats(0.01, 2.0))
def test_speeds_never_exceed_the_limits(pressed: list[str], timeout: float) -> None:
    m = model(timeout, max_speed=0.5, max_turn=1.5)
    for k, key in enumerate(pressed):
        m.press(key, float(k) * 0.01)
        assert 0 < m.speed <= 0.5 and 0 < m.turn <= 1.5
        cmd = m.command(float(k) * 0.01)
        assert abs(cmd.vx) <= 0.5 and abs(cmd.vy) <= 0.5 and abs(cmd.wz) <= 1.5


@given(st.sampled_from(sorted(SPEED_BINDINGS)))
def test_speed_keys_scale_as_in_teleop_twist_keyboard(key: str) -> None:
    m = model(max_speed=math.inf, max_turn=math.inf)
    m.press(key, 0.0)
    lin, ang = SPEED_BINDINGS[key]
    assert (m.speed, m.turn) == pytest.approx((0.3 * lin, 1.0 * ang))


@given(st.sampled_from(sorted(MOVE_BINDINGS)), st.floats(0.05, 5.0), times,
       st.floats(0.0, 10.0))
def test_the_command_lapses_when_keys_stop(key: str, timeout: float, t0: float,
                                           after: float) -> None:
    m = model(timeout)
    m.press(key, t0)
    now = t0 + after
    moving = m.command(now) != Twist()
    assert moving == (now - t0 <= timeout)
    if not moving:  # and stays stopped until the next key
        assert m.command(t0 + after / 2) == Twist()


@given(st.sampled_from(sorted(MOVE_BINDINGS)), st.floats(0.0, 1e5))
def test_a_timeout_of_zero_never_lapses(key: str, after: float) -> None:
    m = model(0.0)
    m.press(key, 0.0)
    assert m.command(after) != Twist()


@given(st.tuples(st.floats(-5, 5), st.floats(-5, 5), st.floats(-5, 5)), times)
def test_a_gamepad_moves_within_the_speeds_until_released(stick: tuple[float, float, float],
                                                          now: float) -> None:
    m = model(0.5)
    m.move(stick, now, "gamepad")
    cmd = m.command(now)
    assert abs(cmd.vx) <= 0.3 and abs(cmd.vy) <= 0.3 and abs(cmd.wz) <= 1.0
    assert cmd.vx == pytest.approx(max(-1.0, min(1.0, stick[0])) * 0.3)
    m.release()  # deadman let go: stops at once, not after the timeout
    assert m.command(now) == Twist()
    assert m.command(now + 0.1) == Twist()


def test_a_gamepad_that_goes_quiet_stops_after_the_timeout() -> None:
    m = model(0.5)
    m.move((1.0, 0.0, 0.0), 10.0, "gamepad")
    assert m.command(10.4) == Twist(0.3, 0.0, 0.0)
    assert m.command(10.6) == Twist()


def test_recover_is_taken_once() -> None:
    m = model()
    m.press("r", 0.0)
    assert m.take_recover() and not m.take_recover()


def test_the_limits_come_from_the_config() -> None:
    cfg = default_config()
    max_speed, max_turn = speed_limits(cfg)
    c = cfg.chassis
    assert max_speed == min(c.max_speed, c.max_wheel_speed)
    assert max_turn == pytest.approx(c.max_wheel_speed / c.base_radius)
    m = TeleopModel.for_config(cfg, speed=100.0, turn=100.0, timeout_s=0.6)
    assert (m.speed, m.turn) == (max_speed, max_turn)


@pytest.mark.parametrize("kwargs", [{"speed": 0.0}, {"turn": -1.0}, {"speed": math.nan},
                                    {"timeout_s": -1.0}, {"timeout_s": math.inf}])
def test_bad_settings_are_refused(kwargs: dict[str, float]) -> None:
    args = {"speed": 0.3, "turn": 1.0, "max_speed": 1.0, "max_turn": 5.0, "timeout_s": 0.6}
    args.update(kwargs)
    with pytest.raises(ValueError):
        TeleopModel(**args)
