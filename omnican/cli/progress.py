"""A long command's progress on a terminal: one line on stderr, redrawn at most ten
times a second, with the time left on the wall clock."""

from __future__ import annotations

import contextlib
import math
import sys
import time
from collections.abc import Callable, Iterator
from typing import Any


class ProgressBar:
    """A one-line progress display on stderr when it is a terminal and the work is long
    enough to want one; a ``progress(done_s, total_s, label)`` callback. It says how
    long is left on the wall clock (under --fast simulated time runs faster than it),
    once it has seen a second of progress, and redraws at most ten times a second."""

    def __init__(self, total_s: float, stream: Any = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.stream = stream or sys.stderr
        self.enabled = self.stream.isatty() and total_s > 2.0
        self._clock = clock
        self._start: tuple[float, float] | None = None  # (wall clock, done_s) at first
        self._drawn = -math.inf
        self._width = 0

    def __call__(self, done_s: float, total_s: float, label: str) -> None:
        if not self.enabled:
            return
        now = self._clock()
        if self._start is None:
            self._start = (now, done_s)
        if now - self._drawn < 0.1 and done_s < total_s:
            return
        self._drawn = now
        frac = min(1.0, done_s / total_s) if total_s > 0 else 1.0
        bar = "=" * int(frac * 30)
        line = f"[{bar:<30}] {frac:4.0%} {label:<10}"
        wall, done = now - self._start[0], done_s - self._start[1]
        if wall >= 1.0 and done > 0 and done_s < total_s:
            line += f" {clock_time((total_s - done_s) * wall / done)} left"
        self.stream.write("\r" + line.ljust(self._width))
        self.stream.flush()
        self._width = len(line)

    def close(self) -> None:
        if self.enabled:
            self.stream.write("\r" + " " * max(50, self._width) + "\r")
            self.stream.flush()


def clock_time(seconds: float) -> str:
    """``seconds`` as a clock shows a duration: ``0:42``, ``12:05``, ``3:10:00``."""
    whole = int(min(seconds, 359_999))  # 99:59:59
    hours, rest = divmod(whole, 3600)
    minutes, secs = divmod(rest, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"


@contextlib.contextmanager
def progress_bar(total_s: float) -> Iterator[ProgressBar]:
    """A :class:`ProgressBar` that is cleared from the line when the block ends."""
    bar = ProgressBar(total_s)
    try:
        yield bar
    finally:
        bar.close()
