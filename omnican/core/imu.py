"""IMU samples as the base reads them, whoever measured them.

An IMU source (a CAN IMU decoded through its DBC, a ``sensor_msgs/Imu`` from ROS 2 or
Zenoh, the simulator's gyro) turns what it receives into :class:`ImuSample` in the
base's frame (its mounting applied, SI units) and puts them in an :class:`ImuInbox`;
the control loop drains the inbox once per cycle and fuses what it finds
(:mod:`omnican.core.fusion`). The inbox is the only thing the two sides share: a
source's receive thread appends, the loop takes, and neither waits for the other.

Pure module: no I/O.
"""

from __future__ import annotations

import collections
from dataclasses import dataclass

#: Samples an inbox keeps when the loop does not drain it (the oldest go first):
#: about 2 s of a 500 Hz gyro.
INBOX_SAMPLES = 1024


@dataclass(frozen=True, slots=True)
class ImuSample:
    """One IMU reading in the base's frame: ``t`` the host's monotonic time it stands for
    (s), ``yaw_rate`` about the base's z axis (rad/s, counter-clockwise positive, as
    ``Twist.wz``), and the base-frame accelerations (m/s^2) where the IMU gives them."""

    t: float
    yaw_rate: float
    accel_x: float | None = None
    accel_y: float | None = None


class ImuInbox:
    """Where one IMU's samples wait for the loop: :meth:`put` from any thread,
    :meth:`drain` from the loop (deque appends and pops are atomic in CPython, so
    neither side locks). ``dropped`` counts samples pushed out because nobody drained."""

    __slots__ = ("_samples", "dropped", "received")

    def __init__(self, capacity: int = INBOX_SAMPLES) -> None:
        if capacity < 1:
            raise ValueError(f"an IMU inbox holds at least one sample, not {capacity}")
        self._samples: collections.deque[ImuSample] = collections.deque(maxlen=capacity)
        self.received = 0
        self.dropped = 0

    def put(self, sample: ImuSample) -> None:
        if len(self._samples) == self._samples.maxlen:
            self.dropped += 1
        self._samples.append(sample)
        self.received += 1

    def drain(self) -> list[ImuSample]:
        """The samples since the last drain, oldest first."""
        out: list[ImuSample] = []
        pop = self._samples.popleft
        try:
            while True:
                out.append(pop())
        except IndexError:
            return out
