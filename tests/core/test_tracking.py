"""The tracking detector (omnican.core.tracking), pure: no bus, no clock."""

from __future__ import annotations

import math
from collections.abc import Sequence

import pytest
from hypothesis import example, given
from hypothesis import strategies as st

from omnican.core.tracking import (
    HOLD_LOAD_PCT,
    MIN_RELATIVE_M_S,
    NotFollowing,
    StandstillWatch,
    TrackingDetector,
)

DT = 0.02  # the chassis checks' period (50 Hz)
ERROR, TIME_S, LAG_S, RATIO = 0.1, 0.5, 0.3, 0.5


def run(targets: list[float], measured: list[float], fresh: bool = True, running: bool = True,
        detector: TrackingDetector | None = None) -> list[tuple[float, object]]:
    """One wheel through the detector; (time, finding) of each finding."""
    d = detector or TrackingDetector(1, ERROR, TIME_S, LAG_S, RATIO)
    out: list[tuple[float, object]] = []
    for k, (t, m) in enumerate(zip(targets, measured, strict=True)):
        for finding in d.update(k * DT, [t], [m], [fresh], running):
            out.append((k * DT, finding))
    return out


# A target a limiter could produce: piecewise constant accelerations within +-accel, speed
# within +-1 m/s (starts, stops, reversals).
@st.composite
def ramps(draw: st.DrawFn) -> list[float]:
    accel = draw(st.floats(0.1, 20.0))
    v, out = 0.0, []
    for _ in range(draw(st.integers(1, 8))):
        goal = draw(st.floats(-1.0, 1.0))
        hold = draw(st.integers(0, 40))
        while abs(goal - v) > 1e-12:
            v += max(-accel * DT, min(accel * DT, goal - v))
            out.append(v)
        out += [v] * hold
    return out or [0.0]


LAG_STEPS = round(LAG_S / DT)


@st.composite
def lags(draw: st.DrawFn) -> tuple[int, int]:
    """(delay, window) in checks, the oldest target averaged within the lag."""
    delay = draw(st.integers(0, LAG_STEPS - 1))
    return delay, draw(st.integers(1, LAG_STEPS - delay))


@given(targets=ramps(), lag=lags(), noise=st.lists(st.floats(-0.9, 0.9), min_size=1))
def test_a_wheel_that_follows_within_the_lag_never_trips(
        targets: list[float], lag: tuple[int, int], noise: list[float]) -> None:
    """However steep the ramp, through reversals and near zero: a measurement that is the
    target delayed and averaged over a window, all within the lag, give or take less than
    the error and less than (1 - ratio) of itself, follows."""
    delay, window = lag
    measured = []
    for k in range(len(targets)):
        lo = max(0, k - delay - window + 1)
        seen = targets[lo:max(lo + 1, k - delay + 1)]
        mean = sum(seen) / len(seen)
        measured.append(mean + noise[k % len(noise)] * min(ERROR, (1 - RATIO) * abs(mean)))
    assert run(targets, measured) == []


@given(target=st.floats(MIN_RELATIVE_M_S, 1.0), sign=st.sampled_from([-1.0, 1.0]),
       share=st.floats(-1.0, RATIO, exclude_max=True), steps=st.integers(1, 100))
@example(target=0.1, sign=-1.0, share=-7.19e-236, steps=1)  # at the band's edge (-0.1 + 0.1)
def test_a_wheel_under_its_share_of_any_target_trips_after_the_time(
        target: float, sign: float, share: float, steps: int) -> None:
    """A wheel at under ``ratio`` of its target, that way (standing, turning the wrong way)
    is not following, however slow the target (5 mm/s and up): stopped after
    ``tracking_time_s``, its wheel, target and speed named."""
    lag = round(LAG_S / DT)
    targets = [sign * target] * (lag + steps + round(TIME_S / DT))
    measured = [sign * target] * lag + [share * sign * target] * (steps + round(TIME_S / DT))
    found = run(targets, measured)
    assert found, "a wheel at under half its target must trip"
    first_t, first = found[0]
    assert first_t - lag * DT == pytest.approx(TIME_S, abs=DT + 1e-9)
    assert isinstance(first, NotFollowing)
    assert first.target == sign * target and first.measured == share * sign * target
    text = first.describe(2)
    assert "wheel 0 (node 2) not following its target for 0.5 s" in text
    assert f"target {sign * target:+.2f} m/s, measured {share * sign * target:+.2f} m/s" in text
    wanted, speed = sign * target, share * sign * target
    if wanted - ERROR <= speed <= wanted + ERROR:  # inside the m/s band: the share says it
        assert "under 50% of its target" in text


@given(target=st.floats(-MIN_RELATIVE_M_S, MIN_RELATIVE_M_S, exclude_min=True,
                        exclude_max=True), speed=st.floats(-0.9 * ERROR, 0.9 * ERROR))
def test_a_target_near_zero_is_judged_in_m_s_only(target: float, speed: float) -> None:
    """Below 5 mm/s a wheel is as good as standing: a target there is judged in m/s alone
    (a wheel within the error of it follows, whatever the share)."""
    n = round((LAG_S + TIME_S) / DT) * 3
    assert run([target] * n, [target + speed] * n) == []


def test_a_ratio_of_zero_judges_in_m_s_only() -> None:
    n = round((LAG_S + TIME_S) / DT) * 3
    d = TrackingDetector(1, ERROR, TIME_S, LAG_S, 0.0)
    assert run([0.087] * n, [0.0] * n, detector=d) == []
    assert run([0.087] * n, [0.0] * n)  # at the default share: a stalled wheel


def test_a_ratio_must_be_a_share_below_one() -> None:
    for ratio in (-0.1, 1.0, math.nan):
        with pytest.raises(ValueError, match="share of the target"):
            TrackingDetector(1, ERROR, TIME_S, LAG_S, ratio)


@given(target=st.floats(-1.0, 1.0).filter(lambda t: abs(t) > 2 * ERROR),
       steps=st.integers(1, 100))
def test_a_stalled_wheel_trips_after_the_time_and_not_before(target: float, steps: int) -> None:
    targets = [target] * (round(LAG_S / DT) + steps + round(TIME_S / DT))
    measured = [target] * round(LAG_S / DT) + [0.0] * (steps + round(TIME_S / DT))
    found = run(targets, measured)
    assert found, "a stalled wheel must trip"
    first_t, first = found[0]
    stalled_at = round(LAG_S / DT) * DT
    assert first_t - stalled_at == pytest.approx(TIME_S, abs=DT + 1e-9)
    text = first.describe(3)  # type: ignore[attr-defined]
    assert "wheel 0 (node 3) not following its target for 0.5 s" in text
    assert "stalled, slipping or off the ground" in text


def test_a_wheel_turning_with_a_zero_target_says_so() -> None:
    n = round((LAG_S + TIME_S) / DT) + 5
    found = run([0.0] * n, [0.0] * 5 + [0.25] * (n - 5))
    assert found
    finding = found[0][1]
    assert finding.zero_target  # type: ignore[attr-defined]
    text = finding.describe(2, axis=1)  # type: ignore[attr-defined]
    assert "wheel 0 (node 2 axis 1) not following its target" in text
    assert "turns at +0.25 m/s with a zero target (pushed, or a runaway drive)" in text


@pytest.mark.parametrize(("fresh", "running"), [(False, True), (True, False)])
def test_no_finding_without_a_fresh_sample_or_while_stopped(fresh: bool, running: bool) -> None:
    n = round((LAG_S + TIME_S) / DT) * 3
    assert run([0.5] * n, [0.0] * n, fresh=fresh, running=running) == []


def test_a_wheel_that_drops_out_starts_over() -> None:
    d = TrackingDetector(1, ERROR, TIME_S, LAG_S)
    k = 0
    for _ in range(3):  # 0.4 s away, a sample missing, 0.4 s away: never 0.5 s in a row
        for fresh in [True] * 20 + [False]:
            assert d.update(k * DT, [0.5], [0.0], [fresh], True) == []
            k += 1


def test_a_detector_that_never_trips_when_the_error_is_infinite() -> None:
    d = TrackingDetector(1, math.inf, TIME_S, LAG_S)
    assert run([0.5] * 100, [0.0] * 100, detector=d) == []


# ---------------------------------------------------------------- a stopped base

SETTLE_S = 1.2  # the longest stop ramp and the lag
HOLD_S = SETTLE_S + TIME_S


def watch_run(measured: list[float], loads: Sequence[float | None] | None = None,
              watched: bool = True, fresh: bool = True) -> list[tuple[float, object]]:
    w = StandstillWatch(1, ERROR, TIME_S, SETTLE_S)
    loads = loads if loads is not None else [None] * len(measured)
    out: list[tuple[float, object]] = []
    for k, (m, load) in enumerate(zip(measured, loads, strict=True)):
        out += [(k * DT, f) for f in w.update(k * DT, [watched], [m], [fresh], [load])]
    return out


@given(speed=st.floats(-2.0, 2.0), decel=st.floats(0.6, 50.0), extra=st.integers(0, 200),
       load=st.one_of(st.none(), st.floats(-0.99 * HOLD_LOAD_PCT, 0.99 * HOLD_LOAD_PCT)))
def test_a_wheel_that_stops_within_the_hold_time_is_never_named(
        speed: float, decel: float, extra: int, load: float | None) -> None:
    """A wheel slowing from any speed to a standstill on a ramp that ends within the
    settling time and the check's (its length capped to it), its drive below its rating,
    is never named."""
    steps = max(1, min(round(abs(speed) / decel / DT), round(HOLD_S / DT) - 1))
    ramp = [speed * (1 - k / steps) for k in range(steps + 1)] + [0.0] * extra
    assert watch_run(ramp, [load] * len(ramp)) == []


@given(speed=st.floats(ERROR * 1.01, 2.0), sign=st.sampled_from([-1.0, 1.0]))
def test_a_wheel_that_keeps_turning_is_named_after_the_hold_time(speed: float,
                                                                 sign: float) -> None:
    found = watch_run([sign * speed] * (round(HOLD_S / DT) + 3))
    assert found and found[0][0] == pytest.approx(HOLD_S)
    f = found[0][1]
    assert f.measured == sign * speed and f.load_pct is None  # type: ignore[attr-defined]
    assert "turns at" in f.describe(2) and "node 2" in f.describe(2)  # type: ignore[attr-defined]


@given(after=st.integers(round(SETTLE_S / DT), 200), speed=st.floats(ERROR * 1.01, 2.0))
def test_a_wheel_that_starts_turning_once_settled_is_named_as_on_a_running_base(
        after: int, speed: float) -> None:
    """Pushed once the stop has settled: named after tracking_time_s, not the ramp's."""
    found = watch_run([0.0] * after + [speed] * (round(TIME_S / DT) + 3))
    assert found and after * DT + TIME_S - 1e-9 <= found[0][0] <= after * DT + TIME_S + 1.5 * DT


@given(load=st.floats(HOLD_LOAD_PCT, 400.0), sign=st.sampled_from([-1.0, 1.0]))
def test_a_drive_pushing_against_a_zero_target_is_named(load: float, sign: float) -> None:
    n = round(HOLD_S / DT) + 3
    found = watch_run([0.0] * n, [sign * load] * n)
    assert found and found[0][1].load_pct == load  # type: ignore[attr-defined]
    assert "energised at" in found[0][1].describe(1)  # type: ignore[attr-defined]


def test_an_unwatched_or_stale_wheel_is_never_named() -> None:
    n = round(HOLD_S / DT) * 3
    assert watch_run([1.0] * n, watched=False) == []
    assert watch_run([1.0] * n, fresh=False) == []
    # A break in what it does starts the time again.
    settled = [0.0] * round(SETTLE_S / DT)
    assert watch_run(settled + ([1.0] * (round(TIME_S / DT) - 1) + [0.0]) * 3) == []
