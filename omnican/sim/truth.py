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

import threading

import numpy as np
import numpy.typing as npt

from omnican.clock import Clock
from omnican.core.kinematics import OmniKinematics, Twist
from omnican.core.odometry import Odometry, Pose2D
from omnican.sim.drive import SimulatedDrive


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
        self._lock = threading.Lock()
        self._stopped = False
        self._loop = 0  # the thread (threading.get_ident) of the loop running the drives
        self._kept: tuple[Pose2D, Twist] | None = None  # as of the loop's last cycle
        self._odo.update(self._travel())

    def _travel(self, now: float | None = None, moved: bool = True) -> list[float]:
        """What each wheel rolled on the ground (a wheel off the ground moves nothing), at
        ``now`` (default the present); ``moved=False``: as the drives last moved them."""
        t = self.clock.now() if now is None else now
        return [(d.ground_counts(axis, t) if moved else d.axes[axis].ground_position)
                * (1.0 - d.slip) / scale
                for (d, axis), scale in zip(self.wheel_axes, self._scales, strict=True)]

    def follow(self, now: float) -> None:
        """Follow the wheels as their drives last moved them (on the SYNC, or in their own
        housekeeping when no SYNC comes): moving them here as well would move every
        motor twice a cycle. While a loop runs the drives (this is its thread: the drives
        just moved), keep the truth for other threads to read."""
        with self._lock:
            if not self._stopped:
                self._odo.step(self._travel(now, moved=False))
                if self._loop:
                    self._kept = (self._odo.pose, self._twist(advance=False))

    @property
    def pose(self) -> Pose2D:
        """The true pose (m, m, rad; theta continuous); see the module docstring."""
        kept = self._elsewhere()
        if kept is not None:
            return kept[0]
        with self._lock:
            return self._odo.update(self._travel())

    @property
    def twist(self) -> Twist:
        """The true body velocity now (m/s, m/s, rad/s); see the module docstring."""
        kept = self._elsewhere()
        return kept[1] if kept is not None else self._twist(advance=True)

    def _twist(self, advance: bool) -> Twist:
        speeds = np.array([(d.velocity_counts(axis) if advance else d.axes[axis].state.velocity)
                           * (1.0 - d.slip) if d.axes[axis].grounded else 0.0
                           for d, axis in self.wheel_axes]) / self._counts_per_metre
        return self.kinematics.to_twist(speeds)

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
