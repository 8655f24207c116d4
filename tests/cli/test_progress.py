"""The progress display of long runs (drive, calibrate, plot --sim): on a terminal's
stderr only, with the time left on the wall clock (under --fast simulated time runs
faster than it), redrawn at most ten times a second."""

from __future__ import annotations

import io

from hypothesis import given
from hypothesis import strategies as st

from omnican.cli.progress import ProgressBar, clock_time


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_a_fast_run_says_the_wall_clock_time_left() -> None:
    """Issue 36 item 9: a long --fast run showed its share of simulated time only: at
    100x real time a day of it sat at 0 % for minutes. It says the time left, as the
    run goes: 10 simulated seconds a wall second, 900 s to go: 1:30."""
    out, clock = Terminal(), Clock()
    bar = ProgressBar(1000.0, out, clock)
    bar(0.0, 1000.0, "drive")
    clock.now += 10.0
    bar(100.0, 1000.0, "drive")
    assert out.getvalue().endswith("10% drive      1:30 left")
    bar.close()
    assert out.getvalue().endswith("\r")


def test_it_draws_at_most_ten_times_a_second_and_always_the_end() -> None:
    out, clock = Terminal(), Clock()
    bar = ProgressBar(1000.0, out, clock)
    for step in range(100):  # a hundred calls in half a second of wall clock
        bar(float(step), 1000.0, "drive")
        clock.now += 0.005
    assert out.getvalue().count("\r") <= 6
    bar(1000.0, 1000.0, "done")
    assert "100% done" in out.getvalue().rsplit("\r", 1)[-1]


def test_not_on_a_pipe_nor_for_short_work() -> None:
    piped = io.StringIO()
    ProgressBar(1000.0, piped)(10.0, 1000.0, "drive")
    short = Terminal()
    ProgressBar(1.0, short)(0.5, 1.0, "drive")
    assert piped.getvalue() == "" and short.getvalue() == ""


@given(st.floats(0, 1e9))
def test_clock_time_reads_as_a_clock(seconds: float) -> None:
    said = clock_time(seconds)
    parts = [int(p) for p in said.split(":")]
    assert all(p < 60 for p in parts[1:])
    total = sum(p * 60 ** i for i, p in enumerate(reversed(parts)))
    assert total == min(int(seconds), 359_999)
