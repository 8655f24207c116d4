"""Wheel slip, seen where the wheels' yaw rate and a gyro's disagree beyond their noise.

:class:`~omnican.core.fusion.HeadingFusion` low-passes the difference of the wheels' yaw
rate and the gyro's (bias removed) and gates it by its variance (Mahalanobis d^2); each
step it tells :class:`SlipDetector` the difference and whether it was beyond the gate.
Beyond it for ``confirm_s`` without a break is a slip event (:class:`SlipEvent`: when it
began, how big: the mean disagreement in rad/s, and for how long); beyond it for
``warn_s`` is a warning (:attr:`SlipDetector.warning`), held ``hold_s`` after the slip
ended, which the chassis shows on ``/status`` and the dashboard and may stop the base
for (``[fusion]``).

Which wheel: with three wheels the kinematics has no redundancy (three speeds, three
unknowns: every set of speeds is a motion) and the gyro adds one equation, which shows a
slip but not where (each wheel of a symmetric base adds alike to the yaw rate); so the
event names none. With more than three, the least-squares residual of the wheel speeds
and the gyro's rate against the kinematics (:func:`slipping_wheel`) points at the wheel
whose speed does not fit the others'.

How this agrees with the current-based lift detection (:mod:`omnican.core.lift`): a wheel
off the ground (or without its roller) turns freely, its encoder counts motion the base
does not make, exactly as a slipping wheel does, and the gyro sees it as slip. The lift
check names the wheel from its current (a light load) after a second or more; the slip
check sees the heading disagree within a fraction of a second but, on a three-wheel base,
cannot say which wheel. A slip event with a lifted wheel is the same fault seen twice; a
slip event without one is a wheel on the ground that does not grip (carpet, a ramp, a
worn roller), which the currents cannot see.

Pure module: no I/O, no clock (the caller gives the time).
"""

from __future__ import annotations

import collections
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

CONFIRM_S = 0.03  # beyond the gate this long: a slip event
RELEASE_S = 0.1  # within the gate this long: the event is over
WARN_S = 0.5  # a slip lasting this long: a warning
HOLD_S = 2.0  # the warning stays this long after the slip ended
EVENTS_KEPT = 32


@dataclass(frozen=True)
class SlipEvent:
    """A slip: it began at ``t`` (the caller's clock, s), the wheels' yaw rate was off the
    gyro's by ``size`` on average (rad/s, signed: wheels minus gyro) and ``peak`` at most,
    for ``duration_s`` (so far, while it lasts); ``wheel`` the one that slipped (by index;
    None: not known, a three-wheel base)."""

    t: float
    size: float
    peak: float
    duration_s: float
    wheel: int | None = None

    def describe(self) -> str:
        who = f"wheel {self.wheel}" if self.wheel is not None else "the wheels"
        return (f"{who} slipping: their yaw rate off the gyro's by "
                f"{abs(self.size):.3f} rad/s for {self.duration_s:.1f} s")


class SlipDetector:
    """Slip events from the gated disagreement (see the module docstring). ``update`` once
    a step; :attr:`events` the latest events (the one under way last, updated in place as
    it lasts), :attr:`active` the one under way, :attr:`warning` the text to show."""

    __slots__ = ("_n", "_over_since", "_peak", "_sum", "_under_since", "_warn_until",
                 "active", "confirm_s", "events", "hold_s", "release_s", "started", "warn_s",
                 "warning")

    def __init__(self, confirm_s: float = CONFIRM_S, release_s: float = RELEASE_S,
                 warn_s: float = WARN_S, hold_s: float = HOLD_S) -> None:
        self.confirm_s, self.release_s, self.warn_s, self.hold_s = (
            confirm_s, release_s, warn_s, hold_s)
        self.events: collections.deque[SlipEvent] = collections.deque(maxlen=EVENTS_KEPT)
        self.active: SlipEvent | None = None
        self.started = 0  # events so far
        self.warning: str | None = None
        self._over_since: float | None = None
        self._under_since: float | None = None
        self._sum = 0.0
        self._n = 0
        self._peak = 0.0
        self._warn_until = -1.0

    def update(self, now: float, diff: float, over: bool,
               wheel_speeds: Callable[[], Sequence[float]] | None = None,
               isolate: Callable[[Sequence[float]], int | None] | None = None) -> None:
        """One step at ``now``: the disagreement ``diff`` (rad/s) and whether it was beyond
        the gate. ``wheel_speeds`` and ``isolate`` (a base with more than three wheels;
        :func:`slipping_wheel`): read when an event starts, to name the wheel."""
        if over:
            self._under_since = None
            if self._over_since is None:
                self._over_since = now
                self._sum, self._n, self._peak = 0.0, 0, 0.0
            self._sum += diff
            self._n += 1
            if abs(diff) > abs(self._peak):
                self._peak = diff
            begun = self._over_since
            if self.active is None and now - begun >= self.confirm_s - 1e-9:
                wheel = None
                if wheel_speeds is not None and isolate is not None:
                    wheel = isolate(wheel_speeds())
                self.active = SlipEvent(begun, diff, diff, now - begun, wheel)
                self.events.append(self.active)
                self.started += 1
            active = self.active
            if active is not None:
                active = self.active = SlipEvent(active.t, self._sum / self._n, self._peak,
                                                 now - active.t, active.wheel)
                self.events[-1] = active
                if active.duration_s >= self.warn_s - 1e-9:
                    self.warning = active.describe()
                    self._warn_until = now + self.hold_s
        else:
            if self._under_since is None:
                self._under_since = now
            # Not yet an event: it had to hold for confirm_s without a break. An event
            # ends once within the gate for release_s.
            if self._over_since is not None and (
                    self.active is None or now - self._under_since >= self.release_s - 1e-9):
                self._over_since = None
                self.active = None
            if self._over_since is None and self._n:
                self._n = 0
        if self.warning is not None and self.active is None and now >= self._warn_until:
            self.warning = None

    def clear(self) -> None:
        """Nothing under way (the IMU went silent, the base stopped)."""
        self._over_since = self._under_since = None
        self.active = None
        self._n = 0


def slipping_wheel(matrix: np.ndarray, speeds: Sequence[float], yaw_rate: float | None = None,
                   min_ratio: float = 2.0) -> int | None:
    """The wheel whose measured speed fits the others' (and the gyro's) least.

    ``matrix``: the kinematics' N x 3 map (wheel speeds = matrix @ twist); ``speeds``: the
    measured rim speeds; ``yaw_rate``: the gyro's (bias removed; None: no gyro), one more
    equation, scaled to a rim speed by the wheels' mean lever. The least-squares residual
    ``r = (I - M M+) v`` is what no motion explains; a slip ``s`` of wheel ``i`` alone
    leaves ``r = s p_i`` with ``p_i`` the projector's column ``i``, so the wheel explaining
    the most of ``r``, ``(r . p_i)^2 / (p_i . p_i)``, is the one, if it explains
    ``min_ratio`` times more than the next. Naming one takes two redundant equations (one
    shows a slip but not where) and a geometry that tells the wheels' signatures apart:
    five wheels and more; four and a gyro leave pairs of wheels alike (opposite wheels
    drive one line). None without them, or with no clear one."""
    m = np.asarray(matrix, dtype=np.float64)
    n = m.shape[0]
    v = np.asarray(speeds, dtype=np.float64)
    if yaw_rate is not None:
        lever = float(np.mean(np.abs(m[:, 2])))
        m = np.vstack([m, [0.0, 0.0, lever]])
        v = np.append(v, lever * yaw_rate)
    rows = m.shape[0]
    if rows - np.linalg.matrix_rank(m) < 2:
        return None
    proj = np.eye(rows) - m @ np.linalg.pinv(m)
    r = proj @ v
    cols = proj[:, :n]
    norms = np.einsum("ij,ij->j", cols, cols)
    explained = np.where(norms > 1e-12, (r @ cols) ** 2 / np.maximum(norms, 1e-12), 0.0)
    order = np.argsort(explained)[::-1]
    best, second = float(explained[order[0]]), float(explained[order[1]])
    if best <= 1e-12 or best < min_ratio * second:
        return None
    return int(order[0])
