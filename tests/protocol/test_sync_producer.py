"""The SYNC producer's pure parts (issue 41): the counter's sequence (CiA 301 1019h), the
bounded count the kernel sends after each re-arm, when a re-arm comes too late, and who
sends SYNC."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from omnican.protocol.sync_producer import (
    COUNTER_MAX,
    COUNTER_MIN,
    HOLD_MIN,
    HOLD_S,
    counter_payloads,
    expired,
    hold_count,
    sync_mode,
)


def test_no_counter_is_one_empty_sync() -> None:
    assert counter_payloads(0) == (b"",)


@given(st.integers(COUNTER_MIN, COUNTER_MAX), st.integers(0, 1000))
def test_the_counter_runs_1_to_overflow_and_starts_at_1_again(overflow: int, n: int) -> None:
    payloads = counter_payloads(overflow)
    assert len(payloads) == overflow
    assert all(len(p) == 1 for p in payloads)
    # The n-th SYNC (from 0) as the kernel sends it, cycling through the list.
    assert payloads[n % overflow][0] == n % overflow + 1
    assert payloads[0] == b"\x01" and payloads[-1] == bytes([overflow])


@given(st.one_of(st.just(1), st.integers(COUNTER_MAX + 1, 10_000), st.integers(-10_000, -1)))
def test_a_counter_the_standard_reserves_is_refused(overflow: int) -> None:
    with pytest.raises(ValueError, match="0 or 2-240"):
        counter_payloads(overflow)


@given(st.floats(1 / 5000, 1.0))
def test_the_hold_covers_hold_s_and_never_less_than_two(period_s: float) -> None:
    hold = hold_count(period_s)
    assert hold >= HOLD_MIN
    assert hold * period_s >= HOLD_S - 1e-9 * period_s  # SYNC goes on for HOLD_S at least
    if hold > HOLD_MIN:  # and not a SYNC more than it takes
        assert (hold - 1) * period_s < HOLD_S


def test_the_hold_at_the_usual_rates() -> None:
    assert [hold_count(1 / hz) for hz in (50, 100, 250, 1000)] == [5, 10, 25, 100]


@given(st.floats(max_value=0.0, allow_nan=False) | st.just(math.nan))
def test_a_period_must_be_positive(period_s: float) -> None:
    with pytest.raises(ValueError):
        hold_count(period_s)


@given(st.integers(1, 1000), st.integers(0, 2000))
def test_a_rearm_is_too_late_once_every_sync_of_the_hold_came(hold: int, seen: int) -> None:
    assert expired(seen, hold) == (seen >= hold)


@given(st.sampled_from(["auto", "kernel", "loop"]), st.booleans())
def test_the_kernel_sends_sync_only_on_socketcan_and_unless_told_loop(setting: str,
                                                                      socketcan: bool) -> None:
    mode = sync_mode(setting, socketcan)
    assert mode == ("kernel" if socketcan and setting != "loop" else "loop")


@given(st.text().filter(lambda s: s not in ("auto", "kernel", "loop")), st.booleans())
def test_an_unknown_setting_is_refused(setting: str, socketcan: bool) -> None:
    with pytest.raises(ValueError, match="auto, kernel, loop"):
        sync_mode(setting, socketcan)
