"""The ground truth of a simulated base: where it really is and how fast it really moves.

The true pose is integrated from the drives' *physical* wheel motion (not from the
encoder values they report, which may be noisy, wrapped or reset by a reboot) through
the base's true kinematics; a wheel off the ground moves nothing, a slipping one less.

While a base's control loop runs the drives (``stepped``, :mod:`omnican.io.stepped`),
the loop's thread follows the wheels each cycle and keeps a copy for the other threads:
they read the truth as of the loop's last cycle, since taking the drives' locks there
could hold the loop up.
"""

from __future__ import annotations

import math
import threading

import numpy as np
import numpy.typing as npt

from omnican.clock import Clock
from omnican.core.kinematics import OmniKinematics, Twist
from omnican.core.odometry import Odometry, Pose2D
from omnican.sim.drive import SimulatedDrive
from omnican.sim.slip import SimSlip


class GroundTruth:
    """The truth of the wheels ``wheel_axes`` ((drive, axis) per wheel of the config) on
    a base of ``kinematics`` whose wheels really count ``counts_per_metre`` (per wheel);
    ``clock``: the drives'. Thread-safe; :meth:`stop` before the drives close."""

    def __init__(self, wheel_axes: list[tuple[SimulatedDrive, int]],
                 kinematics: OmniKinematics, counts_per_metre: npt.NDArray[np.float64],
                 clock: Clock) -> None:
        self.wheel_axes = wheel_axes
        self.kinematics = kinematics
        self.clock = clock
        self._counts_per_metre = counts_per_metre
        self._scales = [float(c) for c in counts_per_metre]
        self._odo = Odometry(kinematics)
        #: the ground's slip beyond the drives' own (None: none; omnican.sim.slip)
        self.slip: SimSlip | None = None
        self._ground: list[float] | None = None  # each wheel's ground counts, last read
        self._taken = [0.0] * len(wheel_axes)  # what the ground took of each rim, m
        self._rims: list[float] = []  # each rim's travel of the last step, m (slip only)
        self._t: float | None = None
        self._lock = threading.Lock()
        self._stopped = False
        self._loop = 0  # the thread (threading.get_ident) of the loop running the drives
        self._kept: tuple[Pose2D, Twist] | None = None  # as of the loop's last cycle
        self._odo.update(self._travel())

    def _travel(self, now: float | None = None, moved: bool = True) -> list[float]:
        """What each wheel rolled on the ground (a wheel off the ground moves nothing, a
        slipping one less: the drive's ``slip`` and the ground's, :attr:`slip`), at ``now``
        (default the present); ``moved=False``: as the drives last moved them. Summed step
        by step, so a slip that starts (or a surface the base reaches) changes what the
        ground takes from then on, not what it took."""
        last, slip, taken = self._ground, self.slip, self._taken
        if not moved and slip is None and last is not None:
            # Each step of the truth (as the drives last moved the wheels, no ground slip):
            # the loops below in one, the same sums.
            ground = []
            for i, ((d, axis), scale) in enumerate(zip(self.wheel_axes, self._scales,
                                                       strict=True)):
                g1 = d.axes[axis].ground_position
                ground.append(g1)
                taken[i] += (g1 - last[i]) / scale * (1.0 - d.slip)
            self._ground = ground
            return list(taken)
        t = self.clock.now() if now is None else now
        ground = [d.ground_counts(axis, t) if moved else d.axes[axis].ground_position
                  for d, axis in self.wheel_axes]
        self._ground = ground
        if last is None:
            return self._taken
        if slip is None:  # the drives' own slip only (the loop below, without the ground's)
            for i, ((d, _), scale, g0, g1) in enumerate(zip(self.wheel_axes, self._scales,
                                                           last, ground, strict=True)):
                taken[i] += (g1 - g0) / scale * (1.0 - d.slip)
            return list(taken)
        x, y = self._odo.xyt[0], self._odo.xyt[1]
        rims = []
        for i, ((d, _), scale, g0, g1) in enumerate(zip(self.wheel_axes, self._scales, last,
                                                       ground, strict=True)):
            rim = (g1 - g0) / scale
            rims.append(rim)
            lost = 1.0 - (1.0 - d.slip) * (1.0 - slip.ratio(i, x, y))
            taken[i] += rim * (1.0 - lost)
        self._rims = rims
        return list(taken)

    def _ground_effects(self, t: float) -> None:
        """After a step: what the rollers that give way and a ramp add to the true pose."""
        slip = self.slip
        dt = t - self._t if self._t is not None else 0.0
        self._t = t
        if slip is None or not any(self._rims):
            return
        dx, dy, dw = slip.lateral(self.kinematics, self._rims)
        x, y, th = self._odo.xyt
        cx, cy = slip.creep(th, dt) if dt > 0 else (0.0, 0.0)
        c, s = math.cos(th), math.sin(th)
        self._odo.reset(Pose2D(x + c * dx - s * dy + cx, y + s * dx + c * dy + cy, th + dw))
        self._rims = []

    def follow(self, now: float) -> None:
        """Follow the wheels as their drives last moved them (on the SYNC, or in their own
        housekeeping when no SYNC comes): moving them here as well would move every
        motor twice a cycle. While a loop runs the drives (this is its thread: the drives
        just moved), keep the truth for other threads to read."""
        with self._lock:
            if not self._stopped:
                self._odo.step(self._travel(now, moved=False))
                if self.slip is None:  # _ground_effects without the ground's: the time only
                    self._t = now
                else:
                    self._ground_effects(now)
                if self._loop:
                    self._kept = (self._odo.pose, self._twist(advance=False))

    @property
    def pose(self) -> Pose2D:
        """The true pose (m, m, rad; theta continuous); see the module docstring."""
        kept = self._elsewhere()
        if kept is not None:
            return kept[0]
        with self._lock:
            t = self.clock.now()
            self._odo.update(self._travel(t))
            self._ground_effects(t)
            return self._odo.pose

    @property
    def twist(self) -> Twist:
        """The true body velocity now (m/s, m/s, rad/s); see the module docstring."""
        kept = self._elsewhere()
        return kept[1] if kept is not None else self._twist(advance=True)

    def _twist(self, advance: bool) -> Twist:
        rims = np.array([(d.velocity_counts(axis) if advance else d.axes[axis].state.velocity)
                         if d.axes[axis].grounded else 0.0
                         for d, axis in self.wheel_axes]) / self._counts_per_metre
        slip = self.slip
        if slip is None:
            return self.kinematics.to_twist(rims * [1.0 - d.slip for d, _ in self.wheel_axes])
        x, y, _ = self._odo.xyt
        taken = [v * (1.0 - d.slip) * (1.0 - slip.ratio(i, x, y))
                 for i, (v, (d, _)) in enumerate(zip(rims, self.wheel_axes, strict=True))]
        vx, vy, wz = self.kinematics.to_twist(np.asarray(taken)).as_array()
        lx, ly, lw = slip.lateral(self.kinematics, [float(v) for v in rims])
        return Twist(float(vx) + lx, float(vy) + ly, float(wz) + lw)

    def _elsewhere(self) -> tuple[Pose2D, Twist] | None:
        """The truth of the loop's last cycle, for a thread other than the loop's while
        the loop runs the drives; None otherwise."""
        kept, loop = self._kept, self._loop
        if kept is None or not loop or threading.get_ident() == loop:
            return None
        return kept

    def reset(self, pose: Pose2D | None = None) -> None:
        """The true pose is ``pose`` (default the origin) from now on."""
        with self._lock:
            self._odo.update(self._travel())
            self._odo.reset(pose)

    def run_on(self, thread: int) -> None:
        """A loop's thread (``threading.get_ident``) runs the drives from now on; 0: none
        does (the drives' own threads again)."""
        if thread:
            self._kept = None
        self._loop = thread

    def stop(self) -> None:
        """Follow the wheels no more (their drives are closing)."""
        with self._lock:
            self._stopped = True
