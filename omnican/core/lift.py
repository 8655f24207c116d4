"""Is a wheel off the ground (or has it lost its roller)? Its drive follows the target as
before, so the encoders cannot tell (three wheels give three equations for three
unknowns); its current can. On the ground a wheel's motor carries friction, the ground's
rolling resistance and its share of the base's inertia; off it, only its own friction and
inertia.

So each wheel's current is compared with its siblings' at the same moment, where the
comparison is fair whatever the motors are like:

- holding speed (every compared wheel within ``STEADY_M_S2``, speeds within a factor
  ``SIMILAR_SPEED``: dry friction and rolling resistance hardly change with speed): the
  load current, the current in the direction of motion. The wheels compared also
  accelerate alike, within ``STEADY_SPREAD_M_S2``: a motor's inertia can carry as much
  current per m/s^2 as thirty times its load current, so one wheel easing off at
  0.09 m/s^2 beside one holding its speed could read as half loaded;
- speeding up (``ACCEL_M_S2`` or more in the direction of motion, accelerations within a
  factor ``SIMILAR_ACCEL`` of each other): the load current per m/s^2.

Decelerating wheels are not compared (friction helps them, their currents say little),
nor wheels slower than ``MIN_SPEED_M_S``. A wheel
whose figure is below ``ratio`` of its siblings' (their median) is off the ground, once
it has been every time it was compared, ``LIFT_CHECKS`` times over at least ``time_s``;
compared and found loaded once, it is back on it.

In the simulator's motor model a lifted wheel's ratio is 0.43 holding speed and below 0.3
speeding up; on the ground it is 1 holding speed, and no less than 0.8 speeding up (the
friction's share per m/s^2 differs with the acceleration). A load resting unevenly on the
wheels lowers a wheel's ratio by its share against the others' (tests/core/test_lift.py draws
shares within 1.5 : 1 and motors' constants, and never sees a grounded wheel taken).
Pure: no I/O, no clock; the caller gives the time.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

LIFT_RATIO = 0.5  # below this share of its siblings' current: off the ground
LIFT_TIME_S = 1.0  # ... every time it was compared, over at least this long
LIFT_CHECKS = 4  # ... and this many times
MIN_SPEED_M_S = 0.1  # slower wheels are not compared (friction's sign, standing still)
STEADY_M_S2 = 0.1  # holding speed
STEADY_SPREAD_M_S2 = 0.01  # ... and compared only with wheels whose acceleration is this close
ACCEL_M_S2 = 0.3  # speeding up
SIMILAR_ACCEL = 1.25  # accelerations compared (speeding up) within this factor
SIMILAR_SPEED = 3.0  # speeds compared (holding) within this factor
MIN_LOAD = 0.05  # A (A per m/s^2): siblings' figure below this says nothing
MAX_GAP_S = 1.0  # speeds further apart in time give no acceleration
#: (phase, the figure compared, what similarity is judged on, acceleration along the motion)
Figure = tuple[str, float, float, float]


@dataclass(frozen=True)
class Lifted:
    """A wheel that turns on ``ratio`` of its siblings' current, found over ``for_s``."""

    wheel: int
    ratio: float
    for_s: float

    def describe(self, node_id: int, axis: int = 0) -> str:
        node = f"node {node_id}" + (f" axis {axis}" if axis else "")
        return (f"wheel {self.wheel} ({node}) off the ground or without its roller: it turns "
                f"on {100 * self.ratio:.0f} % of its siblings' current ({self.for_s:.1f} s)")


def _median(values: list[float]) -> float:
    values = sorted(values)
    mid = len(values) // 2
    return values[mid] if len(values) % 2 else 0.5 * (values[mid - 1] + values[mid])


def _similar(a: float, b: float, factor: float) -> bool:
    a, b = abs(a), abs(b)
    return a <= factor * b and b <= factor * a


class LiftDetector:
    """Each wheel's current against its siblings' (see the module docstring)."""

    def __init__(self, wheels: int, ratio: float = LIFT_RATIO, time_s: float = LIFT_TIME_S,
                 checks: int = LIFT_CHECKS) -> None:
        if not (0.0 < ratio < 1.0 and time_s >= 0.0 and checks >= 1):
            raise ValueError("ratio must be within (0, 1), time_s not negative, checks >= 1")
        self.wheels = wheels
        self.ratio = ratio
        self.time_s = time_s
        self.checks = checks
        self._last: tuple[float, Sequence[float | None]] | None = None
        self._phases = [""] * wheels  # each wheel's phase at the last check ("": none)
        self._pending: list[Figure | None] = [None] * wheels  # the last check's figures
        self._since: list[float | None] = [None] * wheels
        self._count = [0] * wheels
        self._ratios: list[list[float]] = [[] for _ in range(wheels)]
        #: the wheels found off the ground, and not yet found back on it
        self.lifted: dict[int, Lifted] = {}

    def reset(self) -> None:
        self.paused()
        self._since = [None] * self.wheels
        self._count = [0] * self.wheels
        self._ratios = [[] for _ in range(self.wheels)]
        self.lifted = {}

    def _figures(self, now: float, speeds: Sequence[float | None],
                 currents: Sequence[float | None]) -> list[Figure | None]:
        """Per wheel: (phase, figure, what similarity is judged on), or None. A wheel's
        figure is made of the previous check's current, once the wheel has held its phase
        from the check before that to this one: a current sampled a little before or after
        the speeds (the speed window lags) still belongs to that phase."""
        last, self._last = self._last, (now, speeds)
        phases, before = [""] * self.wheels, self._phases
        made: list[Figure | None] = [None] * self.wheels
        pending, self._pending = self._pending, made
        self._phases = phases
        if last is None or not 0.0 < now - last[0] <= MAX_GAP_S:
            return [None] * self.wheels
        dt = now - last[0]
        for i in range(self.wheels):
            v, v0, current = speeds[i], last[1][i], currents[i]
            if v is None or v0 is None or abs(v) < MIN_SPEED_M_S:
                continue
            a = (v - v0) / dt
            along = 1.0 if v > 0 else -1.0  # current and acceleration along the motion
            if abs(a) <= STEADY_M_S2:
                phases[i] = "steady"
            elif along * a >= ACCEL_M_S2:
                phases[i] = "accel"
            if current is None or not phases[i] or phases[i] != before[i]:
                continue
            if phases[i] == "steady":
                made[i] = ("steady", along * current, v, along * a)
            else:
                made[i] = ("accel", along * current / abs(a), a, along * a)
        return [f if f is not None and phases[i] == f[0] else None
                for i, f in enumerate(pending)]

    def update(self, now: float, speeds: Sequence[float | None],
               currents: Sequence[float | None]) -> list[Lifted]:
        """One check at ``now`` (s) of a running base: each wheel's measured speed (m/s,
        None: not known) and motor current (A, signed as the torque; None: not known).
        Returns the wheels found off the ground at this check (each once, until it is
        found back on it)."""
        figures = self._figures(now, speeds, currents)
        found = []
        for i, mine in enumerate(figures):
            if mine is None:
                continue
            phase, figure, basis, accel = mine
            steady = phase == "steady"
            others = [f[1] for j, f in enumerate(figures)
                      if j != i and f is not None and f[0] == phase and
                      _similar(basis, f[2], SIMILAR_SPEED if steady else SIMILAR_ACCEL) and
                      (not steady or abs(accel - f[3]) <= STEADY_SPREAD_M_S2)]
            if not others:
                continue
            ref = _median(others)
            if ref < MIN_LOAD:
                continue
            ratio = figure / ref
            if ratio >= self.ratio:  # loaded: on the ground
                self._since[i], self._count[i], self._ratios[i] = None, 0, []
                self.lifted.pop(i, None)
                continue
            since = self._since[i]
            if since is None:
                self._since[i] = since = now
            self._count[i] += 1
            self._ratios[i] = [*self._ratios[i][-9:], ratio]
            if (i not in self.lifted and self._count[i] >= self.checks and
                    now - since >= self.time_s):
                lifted = Lifted(i, max(0.0, _median(self._ratios[i])), now - since)
                self.lifted[i] = lifted
                found.append(lifted)
        return found

    def paused(self) -> None:
        """The base stopped running: no acceleration across the gap."""
        self._last = None
        self._phases = [""] * self.wheels
        self._pending = [None] * self.wheels
