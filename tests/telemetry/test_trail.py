"""The path so far behind the base in Foxglove's 3D panel (omnican.telemetry.trail, pure):
bounded whatever the run, covering all of it, and restarted where the odometry jumps."""

from __future__ import annotations

import math

from hypothesis import given
from hypothesis import strategies as st

from omnican.core.odometry import Pose2D
from omnican.telemetry.trail import JUMP_M, Trail

step = st.tuples(st.floats(-0.05, 0.05), st.floats(-0.05, 0.05), st.floats(-0.3, 0.3))


@given(steps=st.lists(step, min_size=1, max_size=400), max_points=st.integers(2, 40))
def test_a_trail_is_bounded_and_covers_the_whole_run(
        steps: list[tuple[float, float, float]], max_points: int) -> None:
    trail = Trail(max_points=max_points)
    x = y = theta = 0.0
    first = Pose2D(x, y, theta)
    assert trail.add(0, first)
    for i, (dx, dy, dt) in enumerate(steps, 1):
        x, y, theta = x + dx, y + dy, theta + dt
        kept = trail.add(i, Pose2D(x, y, theta))
        assert len(trail.points) <= max_points
        last = trail.points[-1][1]
        # The newest point is the base, or less than one spacing behind it.
        assert kept or (math.hypot(x - last.x, y - last.y) < trail.spacing_m
                        and abs(theta - last.theta) < trail.spacing_rad)
    assert trail.points[0] == (0, first)  # the start stays
    stamps = [t for t, _ in trail.points]
    assert stamps == sorted(set(stamps))


def test_a_trail_keeps_a_point_per_spacing_and_thins_out_when_full() -> None:
    trail = Trail(spacing_m=0.125, max_points=4)  # binary fractions: exact steps
    kept = [trail.add(i, Pose2D(0.0625 * i, 0.0, 0.0)) for i in range(9)]  # 0 .. 0.5 m
    assert kept == [True, False, True, False, True, False, True, False, True]
    # A fifth point would not fit in 4: every second went and the spacing doubled.
    assert [p.x for _, p in trail.points] == [0.0, 0.25, 0.5]
    assert trail.spacing_m == 0.25
    assert not trail.add(9, Pose2D(0.625, 0.0, 0.0))
    assert trail.add(10, Pose2D(0.75, 0.0, 0.0))


def test_a_jump_of_the_odometry_starts_a_new_trail() -> None:
    trail = Trail()
    for i in range(10):
        trail.add(i, Pose2D(0.05 * i, 0.0, 0.0))
    assert len(trail.points) == 10
    trail.add(10, Pose2D(0.45 + JUMP_M + 0.01, 0.0, 0.0))  # reset_odometry elsewhere
    assert [t for t, _ in trail.points] == [10]
