"""omnican.core.wheel_odometry: the one fold of encoder counters, the speed window and
the measured twist (the owner the control loop and replay share)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from omnican import Odometry, OmniKinematics, Pose2D, Twist
from omnican.core.wheel_odometry import (
    SPEED_WINDOW_S,
    CounterSampleSlot,
    EncoderCounters,
    WheelOdometry,
    fold_counter,
)

KIN = OmniKinematics.from_layout("b21", base_radius=0.19)
COUNTS_PER_M = [-4772.44 * 10, 5000.0, 123456.0]  # signed, as position_scale


def wheel_odometry(bits: list[int], counts_per_m: list[float] | None = None,
                   window_s: float = SPEED_WINDOW_S) -> tuple[WheelOdometry, list[CounterSampleSlot]]:
    samples = [CounterSampleSlot() for _ in bits]
    counters = EncoderCounters(samples, bits, counts_per_m or COUNTS_PER_M)
    return WheelOdometry(Odometry(KIN), counters, window_s), samples


def give(samples: list[CounterSampleSlot], raws: list[int], epoch: int) -> None:
    for s, raw in zip(samples, raws, strict=True):
        s.raw, s.epoch = raw, epoch


# ---------------------------------------------------------------- the fold


@given(bits=st.sampled_from([8, 16, 32]), start=st.integers(0, (1 << 32) - 1),
       steps=st.lists(st.integers(-(1 << 7) + 1, (1 << 7) - 1), max_size=60))
def test_fold_counter_follows_wraparound(bits: int, start: int, steps: list[int]) -> None:
    span = 1 << bits
    counts, last = 0.0, None
    true = 0
    for step in [0, *steps]:
        true += step
        raw = (start + true) % span
        counts = fold_counter(counts, last, raw, bits)
        last = raw
    assert counts == true


def test_fold_counter_without_a_previous_sample_keeps_the_count() -> None:
    assert fold_counter(123.0, None, 99999, 32) == 123.0


@st.composite
def counter_runs(draw: st.DrawFn) -> tuple[list[int], list[int], list[list[int]], set[int]]:
    """Counter widths, start values, per-sample steps below half each span, restarts."""
    bits = draw(st.lists(st.sampled_from([8, 16, 32]), min_size=3, max_size=3))
    starts = [draw(st.integers(0, (1 << b) - 1)) for b in bits]
    n = draw(st.integers(0, 50))
    steps = [[draw(st.integers(-(1 << (b - 1)) + 1, (1 << (b - 1)) - 1)) for b in bits]
             for _ in range(n)]
    restarts = set(draw(st.lists(st.integers(1, max(n, 1)), max_size=3)))
    return bits, starts, steps, restarts


@given(run=counter_runs())
def test_folding_wrapped_counters_gives_the_unwrapped_travel(
        run: tuple[list[int], list[int], list[list[int]], set[int]]) -> None:
    """Any sequence of wrapped counters, each step below half the counter's span, folds
    to the travel the wheels really made; a restart (the counter starts again anywhere)
    only seeds: the travel goes on from where it was, without a jump."""
    bits, starts, steps, restarts = run
    odo, samples = wheel_odometry(bits)
    true = [0] * 3  # counts really turned, restarts' jumps left out
    raw_now = list(starts)
    give(samples, [r % (1 << b) for r, b in zip(raw_now, bits, strict=True)], 0)
    assert odo.integrate(0, 0.0)
    expected = Odometry(KIN)  # fed the true travel
    expected.update([0.0, 0.0, 0.0])
    for k, step in enumerate(steps, start=1):
        if k in restarts:  # the drive rebooted: its counter restarts at some value
            for w, s in enumerate(samples):
                s.restarts += 1
                raw_now[w] = (raw_now[w] * 7919 + k) % (1 << bits[w])
        else:
            for w in range(3):
                true[w] += step[w]
                raw_now[w] += step[w]
        give(samples, [r % (1 << b) for r, b in zip(raw_now, bits, strict=True)], k)
        assert odo.integrate(k, 0.01 * k)
        assert odo.counters.counts() == true
        expected.update([c / s for c, s in zip(true, COUNTS_PER_M, strict=True)])
        assert odo.odometry.xyt == expected.xyt


def test_a_set_without_every_wheel_is_not_integrated() -> None:
    """A wheel without a sample of the SYNC: nothing is integrated; the wheels before
    it are folded, and folding their sample again changes nothing."""
    odo, samples = wheel_odometry([32, 32, 32], [1000.0] * 3)
    give(samples, [10, 20, 30], 1)
    assert odo.integrate(1, 0.01)
    assert odo.odometry.seeded and odo.odometry.xyt == (0.0, 0.0, 0.0)  # the first set only seeds
    give(samples, [110, 20, 30], 2)
    samples[1].epoch = 1  # wheel 1 has not answered SYNC 2
    assert not odo.integrate(2, 0.02)
    assert odo.odometry.xyt == (0.0, 0.0, 0.0)
    assert odo.counters.counts() == [100.0, 0.0, 0.0]
    samples[1].raw, samples[1].epoch = 20, 2
    assert odo.integrate(2, 0.02)
    assert odo.counters.counts() == [100.0, 0.0, 0.0]  # not folded twice
    assert odo.odometry.xyt != (0.0, 0.0, 0.0)
    samples[2].raw = None
    assert not odo.integrate(2, 0.03)


def test_the_counters_want_one_width_and_scale_per_wheel() -> None:
    with pytest.raises(ValueError, match="one of each per wheel"):
        EncoderCounters([CounterSampleSlot(), CounterSampleSlot()], [32, 32, 32], [1.0, 1.0])
    with pytest.raises(ValueError, match="expected 3 wheel counters, got 2"):
        WheelOdometry(Odometry(KIN), EncoderCounters([CounterSampleSlot(), CounterSampleSlot()], [32, 32], [1.0, 1.0]))


# ---------------------------------------------------------------- the window and the twist


@given(twist=st.builds(Twist, st.floats(-1, 1), st.floats(-1, 1), st.floats(-3, 3)),
       jitter=st.lists(st.floats(0.0, 0.004), min_size=3, max_size=40))
def test_the_measured_twist_of_constant_motion_is_that_motion(
        twist: Twist, jitter: list[float]) -> None:
    """Wheels turning at constant speeds, sampled at jittered SYNC times: every measured
    rim speed and the body twist are the true ones, whatever the jitter."""
    scale = [1e8, -1e8, 1e8]  # fine counters: the counts' rounding is negligible
    odo, samples = wheel_odometry([32, 32, 32], scale)
    rates = KIN.to_wheel_speeds(twist)
    times = np.arange(len(jitter)) * 0.01 + np.array(jitter)
    for k, t in enumerate(times):
        give(samples, [round(r * t * s) % (1 << 32) for r, s in zip(rates, scale, strict=True)],
             k)
        assert odo.integrate(k, float(t))
    np.testing.assert_allclose(odo.speeds(), rates, atol=1e-4)
    vx, vy, wz = odo.measured
    assert (vx, vy, wz) == pytest.approx((twist.vx, twist.vy, twist.wz), abs=1e-4)
    span = odo.window[2]
    assert span >= min(SPEED_WINDOW_S, times[-1] - times[0]) - 1e-12
    assert odo.settled(max(abs(rates)) + 1e-3)
    if max(abs(rates)) > 2e-3:
        assert not odo.settled(1e-3)


def test_the_window_averages_over_its_span() -> None:
    """The reference is the latest set at least the window older (else the oldest)."""
    odo, samples = wheel_odometry([32, 32, 32], [1.0] * 3, window_s=0.125)
    speeds = []
    for k, (t, c) in enumerate([(0.0, 0), (0.0625, 1), (0.125, 1), (0.1875, 1), (0.25, 3)]):
        give(samples, [c, 0, 0], k)
        odo.integrate(k, t)
        speeds.append(odo.speeds()[0])
    assert speeds == [0, 16, 8, 0, 16]


def test_forgotten_speeds_read_zero_until_the_window_refills() -> None:
    odo, samples = wheel_odometry([32, 32, 32], [1.0] * 3)
    for k in range(5):
        give(samples, [10 * k, 20 * k, 30 * k], k)
        odo.integrate(k, 0.01 * k)
    assert odo.speeds() == pytest.approx([1000, 2000, 3000])
    measured = odo.measured
    assert measured != (0.0, 0.0, 0.0)
    odo.forget_speeds((1,))
    assert odo.speeds() == pytest.approx([1000, 0, 3000])
    assert odo.measured == (0.0, 0.0, 0.0)
    give(samples, [50, 100, 150], 5)
    odo.integrate(5, 0.05)  # the window restarts: one set is no span yet
    assert odo.speeds() == pytest.approx([1000, 0, 3000])
    give(samples, [60, 120, 180], 6)
    odo.integrate(6, 0.06)
    assert odo.speeds() == pytest.approx([1000, 2000, 3000])
    assert odo.measured == pytest.approx(measured)


def test_reset_moves_the_pose_only() -> None:
    odo, samples = wheel_odometry([32, 32, 32], [1.0] * 3)
    for k in range(3):
        give(samples, [k, 2 * k, 0], k)
        odo.integrate(k, 0.01 * k)
    speeds, counts = odo.speeds(), odo.counters.counts()
    odo.odometry.reset(Pose2D(1.0, 2.0, math.pi))
    assert odo.odometry.pose == Pose2D(1.0, 2.0, math.pi)
    assert odo.speeds() == speeds and odo.counters.counts() == counts
    give(samples, [3, 6, 0], 3)
    odo.integrate(3, 0.03)
    assert odo.odometry.pose != Pose2D(1.0, 2.0, math.pi)  # integrates on from the new pose
