"""How the simulated base's wheels slip: what the ground really takes of their motion.

The drives' encoders count every turn of the rims; the ground takes less (a slipping
wheel), more in another direction (a roller that gives way sideways) or adds its own (a
ramp's gravity). :class:`SimSlip` says how much, and the ground truth
(:mod:`omnican.sim.truth`) moves the true pose by it; nothing the host reads changes, as
on a real base: only a gyro (or a camera) sees the difference.

- ``ratios``: per wheel, the fraction of its rim's motion the ground does not take (0: it
  grips, 0.1: 10 % lost): the rim transmits ``1 - ratio`` of its travel.
- ``surfaces``: patches of floor (:class:`Surface`, a rectangle in the world frame) with
  their own ratio per wheel, taken while the base's centre is on them (carpet, a wet tile).
- ``roller``: per wheel, a fraction of its rim speed by which its contact point slides
  along its roller's axis too (a roller that gives way, a lateral slip): the base moves
  the least that does it (the other wheels drag along), which turns it too.
- ``ramp_grade_deg``, ``ramp_downhill_deg``: a ramp of that grade, falling towards that
  direction (world frame, degrees); the base creeps downhill at ``ramp_creep`` (m/s per
  m/s^2 of gravity along the ramp) while its wheels turn (free rollers give way to the
  pull; a base at rest is held by its drives' position).

:func:`set_slip` gives a simulated base its ground's slip; a config's ``[sim.slip]``
table gives it one from the start (:meth:`SimSlip.of`). Pure module: no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from omnican.config import SimSlipSettings
from omnican.core.kinematics import OmniKinematics

G = 9.81


@dataclass(frozen=True)
class Surface:
    """A rectangle of floor (world frame, m) where wheel ``i`` loses ``ratio[i]`` of its
    motion (one number: every wheel)."""

    x0: float
    y0: float
    x1: float
    y1: float
    ratio: float | tuple[float, ...]

    def holds(self, x: float, y: float) -> bool:
        return (min(self.x0, self.x1) <= x <= max(self.x0, self.x1)
                and min(self.y0, self.y1) <= y <= max(self.y0, self.y1))

    def of(self, wheel: int) -> float:
        return self.ratio if isinstance(self.ratio, (int, float)) else self.ratio[wheel]


@dataclass(frozen=True)
class SimSlip:
    """The simulated ground's slip (see the module docstring)."""

    ratios: tuple[float, ...] = ()
    surfaces: tuple[Surface, ...] = ()
    roller: dict[int, float] = field(default_factory=dict)
    ramp_grade_deg: float = 0.0
    ramp_downhill_deg: float = 0.0
    ramp_creep: float = 0.005

    def __post_init__(self) -> None:
        for r in (*self.ratios, *(s.of(i) for s in self.surfaces
                                  for i in range(len(s.ratio) if isinstance(s.ratio, tuple)
                                                 else 1))):
            if not (math.isfinite(r) and 0.0 <= r <= 1.0):
                raise ValueError(f"a slip ratio is a fraction 0-1, not {r!r}")
        if not (math.isfinite(self.ramp_grade_deg) and -60.0 <= self.ramp_grade_deg <= 60.0):
            raise ValueError(f"ramp_grade_deg: -60 to 60, not {self.ramp_grade_deg!r}")

    @classmethod
    def of(cls, table: SimSlipSettings) -> SimSlip:
        """The slip a config's ``[sim.slip]`` table says (:class:`SimSlipSettings`)."""
        return cls(ratios=table.ratio,
                   surfaces=tuple(Surface(s.x0, s.y0, s.x1, s.y1, s.ratio)
                                  for s in table.surfaces),
                   roller={i: give for i, give in enumerate(table.roller) if give},
                   ramp_grade_deg=table.ramp_grade_deg,
                   ramp_downhill_deg=table.ramp_downhill_deg, ramp_creep=table.ramp_creep)

    def ratio(self, wheel: int, x: float, y: float) -> float:
        """The share of wheel ``wheel``'s rim travel the ground does not take with the
        base's centre at (x, y)."""
        for s in self.surfaces:
            if s.holds(x, y):
                return s.of(wheel)
        return self.ratios[wheel] if wheel < len(self.ratios) else 0.0

    def lateral(self, kinematics: OmniKinematics,
                rim_steps: Sequence[float]) -> tuple[float, float, float]:
        """The body displacement (dx, dy, dtheta; body frame) the rollers that give way add
        over a step in which each wheel's rim moved ``rim_steps`` (m): each such wheel's
        contact point slides ``give * |rim step|`` along its roller's axis (the other wheels
        drag along: they slip too), by the least body motion that does it (least squares:
        the rollers' rows and their slides)."""
        if not self.roller:
            return 0.0, 0.0, 0.0
        rows, target = [], []
        for i, give in sorted(self.roller.items()):
            beta = math.radians(kinematics.drive_angles_deg[i])
            phi = math.radians(kinematics.angles_deg[i])
            radius = kinematics.base_radius[i]
            x, y = radius * math.cos(phi), radius * math.sin(phi)
            # the contact point's velocity (vx - wz y, vy + wz x) along the roller's axis
            rows.append((-math.sin(beta), math.cos(beta),
                         math.sin(beta) * y + math.cos(beta) * x))
            target.append(give * abs(rim_steps[i]))
        d = np.linalg.pinv(np.asarray(rows)) @ np.asarray(target)
        return float(d[0]), float(d[1]), float(d[2])

    def creep(self, theta: float, dt: float) -> tuple[float, float]:
        """The world-frame creep (dx, dy, m) down the ramp over ``dt`` s while moving."""
        if not self.ramp_grade_deg:
            return 0.0, 0.0
        speed = self.ramp_creep * G * math.sin(math.radians(self.ramp_grade_deg))
        a = math.radians(self.ramp_downhill_deg)
        return speed * math.cos(a) * dt, speed * math.sin(a) * dt


class _Simulated(Protocol):
    """A simulated base (:class:`omnican.sim.SimulatedBase`): its ground truth."""

    _truth: Any


def set_slip(sim: _Simulated, slip: SimSlip | None) -> None:
    """The ground under ``sim`` slips as ``slip`` says from now on (None: it grips; the
    drives' own ``slip`` stays). The encoders count as before: only the truth changes."""
    sim._truth.slip = slip
