"""Is each wheel following its target? A wheel whose measured speed stays outside what
its target was, give or take ``error``, for ``time_s`` is not: stalled (a jammed roller,
a wall), slipping, off the ground, a drive browning out; or, with a zero target,
turning when it should stand (pushed, a runaway drive).

"What its target was" is the range the target spanned over the last ``lag_s``: the
measured speed is an average over a window and lags a drive following a ramp (its own
velocity loop, a cycle or two on the bus), so on the acceleration ramp the measurement
stays inside that range and nothing trips, however steep the ramp, as long as the lag
is within ``lag_s``. Steady, the band is the target plus or minus ``error``.

A slow wheel is judged against its own target too: ``error`` in m/s alone lets a wheel
that stands still pass while its target is under ``error``. A wheel whose every target
over the lag window went one way, at ``MIN_RELATIVE_M_S`` or more, follows only at
``ratio`` of the least of them or more, that way (0: no such check). On a ramp up the
least is the oldest, which a measurement lagging within ``lag_s`` has passed; on a ramp
down the measurement lags above it; a window that holds a reversal (targets both ways)
or a target near zero asks nothing more than the band.

Only wheels with a fresh measurement count, and only while the base runs (every drive
enabled, nothing latched): :meth:`TrackingDetector.update` is told which. A wheel that
drops out starts over. Pure: no I/O, no clock; the caller gives the time.
"""

from __future__ import annotations

import collections
import math
from collections.abc import Sequence
from dataclasses import dataclass

ZERO_M_S = 1e-6  # a target below this is zero
#: Targets below this are not judged against their size: a wheel this slow is one the base
#: calls standing still (``speeds_settled``), and its measured speed is mostly the
#: encoder's resolution over the speed window.
MIN_RELATIVE_M_S = 0.005


@dataclass(frozen=True)
class NotFollowing:
    """A wheel that has not followed its target for ``for_s`` (m/s; ``band`` is what its
    target spanned over the lag window, error included)."""

    wheel: int
    target: float
    measured: float
    for_s: float
    zero_target: bool  # the target was zero all along: it turns when it should not
    #: within the band but under this share of its target (None: outside the band)
    under_ratio: float | None = None

    def describe(self, node_id: int, axis: int = 0) -> str:
        """The stop's reason (always says "not following its target", names the wheel, its
        target and its speed)."""
        node = f"node {node_id}" + (f" axis {axis}" if axis else "")
        head = f"wheel {self.wheel} ({node}) not following its target for {self.for_s:.1f} s"
        if self.zero_target:
            return (f"{head}: turns at {self.measured:+.2f} m/s with a zero target (pushed, or "
                    "a runaway drive)")
        share = "" if self.under_ratio is None else (
            f", under {self.under_ratio:.0%} of its target")
        return (f"{head}: stalled, slipping or off the ground (target {self.target:+.2f} m/s, "
                f"measured {self.measured:+.2f} m/s{share})")


class TrackingDetector:
    """Each wheel's measured speed against its recent targets (see the module docstring)."""

    def __init__(self, wheels: int, error: float, time_s: float, lag_s: float,
                 ratio: float = 0.0) -> None:
        if not (error > 0 and time_s > 0 and lag_s >= 0):
            raise ValueError("error and time_s must be positive, lag_s not negative")
        if not 0 <= ratio < 1:
            raise ValueError(f"ratio is a share of the target, 0 or more and below 1, got {ratio}")
        self.wheels = wheels
        self.error = error
        self.time_s = time_s
        self.lag_s = lag_s
        self.ratio = ratio
        self._targets: collections.deque[tuple[float, tuple[float, ...]]] = collections.deque()
        self._since: list[float | None] = [None] * wheels

    def reset(self) -> None:
        """Start over (the base stopped, recovered): nothing is held against any wheel."""
        self._targets.clear()
        self._since = [None] * self.wheels

    def band(self, wheel: int) -> tuple[float, float]:
        """(lowest, highest) speed that counts as following, now (m/s)."""
        values = [targets[wheel] for _, targets in self._targets]
        return _band(min(values), max(values), self.error, self.ratio)

    def update(self, now: float, targets: Sequence[float], measured: Sequence[float],
               fresh: Sequence[bool], running: bool) -> list[NotFollowing]:
        """One check at ``now`` (s): each wheel's target and measured speed (m/s), which
        wheels have a fresh measurement, whether the base runs. Returns the wheels not
        following for ``time_s`` or more, as of this check."""
        if not running or math.isinf(self.error):
            if self._targets:
                self.reset()
            return []
        history = self._targets
        history.append((now, tuple(targets)))
        while len(history) > 1 and now - history[1][0] >= self.lag_s:
            history.popleft()
        out = []
        since = self._since
        error, ratio = self.error, self.ratio
        # Each wheel's targets over the window, in one pass (a few entries, at the check rate).
        columns = zip(*[t for _, t in history], strict=True)
        for i, column in enumerate(columns):
            if not fresh[i]:
                since[i] = None
                continue
            speed = measured[i]
            lo, hi = _band(min(column), max(column), error, ratio)
            if lo <= speed <= hi:
                since[i] = None
                continue
            start = since[i]
            if start is None:
                since[i] = now
                continue
            if now - start >= self.time_s:
                zero = max(map(abs, column)) < ZERO_M_S
                inside = min(column) - error <= speed <= max(column) + error
                out.append(NotFollowing(i, targets[i], speed, now - start, zero,
                                        ratio if inside else None))
        return out


def _band(lo: float, hi: float, error: float, ratio: float) -> tuple[float, float]:
    """The speeds that follow targets spanning ``lo``-``hi`` (m/s): within ``error`` of
    that span, and where every target went one way at ``MIN_RELATIVE_M_S`` or more, at
    ``ratio`` of the least of them or more, that way."""
    low, high = lo - error, hi + error
    if lo >= MIN_RELATIVE_M_S:
        low = max(low, ratio * lo)
    elif hi <= -MIN_RELATIVE_M_S:
        high = min(high, ratio * hi)
    return low, high


#: A drive holding a stopped wheel at this share of its rated torque (or current), %,
#: pushes against something: a base at rest on level ground needs next to none, one held
#: on a ramp it can climb well under its rated torque.
HOLD_LOAD_PCT = 100.0


@dataclass(frozen=True)
class NotStill:
    """A wheel of a stopped base whose drive is still energised and that turns, or whose
    drive pushes (``load_pct`` of its rated torque), for ``for_s`` (m/s, %)."""

    wheel: int
    measured: float | None  # it turns at this speed (None: it does not, or not known)
    load_pct: float | None  # its drive pushes at this share of its rating (None: it does not)
    for_s: float

    def describe(self, node_id: int, axis: int = 0) -> str:
        """What the stop says of it (always names the wheel and says its drive is disabled)."""
        node = f"node {node_id}" + (f" axis {axis}" if axis else "")
        if self.measured is not None:
            what = (f"turns at {self.measured:+.2f} m/s while the base is stopped "
                    f"(pushed, or a runaway drive)")
        else:
            what = (f"drive energised at {self.load_pct:.0f} % of its rated torque against a "
                    f"zero target (pushing against something)")
        return f"wheel {self.wheel} ({node}) {what} for {self.for_s:.1f} s: its drive disabled"


class StandstillWatch:
    """The wheels of a stopped base (a latched stop, a drive out of OPERATION ENABLED):
    a wheel whose drive is still energised may neither turn (outside ``error``, m/s) nor
    be pushed by its drive (``HOLD_LOAD_PCT`` of its rating) for ``time_s``, as on a running
    base, once ``settle_s`` (the longest stop ramp and the lag of the measurement behind
    it) has passed since it was first watched; until then, for ``settle_s + time_s``. Pure:
    the caller gives the time and says which wheels are watched (energised, zero target,
    the base stopped)."""

    def __init__(self, wheels: int, error: float, time_s: float, settle_s: float) -> None:
        if not (error > 0 and time_s > 0 and settle_s >= 0):
            raise ValueError("error and time_s must be positive, settle_s not negative")
        self.wheels = wheels
        self.error = error
        self.time_s = time_s
        self.settle_s = settle_s
        self._since: list[float | None] = [None] * wheels  # not still since
        self._watched: list[float | None] = [None] * wheels  # watched since

    def reset(self) -> None:
        self._since = [None] * self.wheels
        self._watched = [None] * self.wheels

    def update(self, now: float, watched: Sequence[bool], measured: Sequence[float],
               fresh: Sequence[bool], load_pct: Sequence[float | None]) -> list[NotStill]:
        """One check at ``now`` (s). ``watched``: the wheel's drive is energised while the
        base is stopped and its target is zero; ``measured`` its speed (m/s, counted where
        ``fresh``); ``load_pct`` its drive's torque or current, % of rated (None: not
        known). Returns the wheels not still for long enough, as of this check."""
        out = []
        since, watched_since = self._since, self._watched
        error = self.error
        for i in range(self.wheels):
            if not watched[i]:
                since[i] = watched_since[i] = None
                continue
            first = watched_since[i]
            if first is None:
                watched_since[i] = first = now
            turns = fresh[i] and abs(measured[i]) > error
            load = load_pct[i]
            pushes = load is not None and abs(load) >= HOLD_LOAD_PCT
            if not (turns or pushes):
                since[i] = None
                continue
            start = since[i]
            if start is None:
                since[i] = start = now
            if now - start >= self.time_s and now - first >= self.settle_s + self.time_s:
                out.append(NotStill(i, measured[i] if turns else None,
                                    abs(load) if pushes and load is not None else None,
                                    now - start))
        return out
