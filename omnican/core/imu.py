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
import math
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
    neither side locks). ``received`` counts samples put, ``dropped`` those pushed out
    because nobody drained, ``last_t`` is the newest one's time."""

    __slots__ = ("_samples", "dropped", "last_t", "received")

    def __init__(self, capacity: int = INBOX_SAMPLES) -> None:
        if capacity < 1:
            raise ValueError(f"an IMU inbox holds at least one sample, not {capacity}")
        self._samples: collections.deque[ImuSample] = collections.deque(maxlen=capacity)
        self.received = 0
        self.dropped = 0
        #: the host time (``t``) of the newest sample put, None before the first: a
        #: source gone silent stops moving it (the loop judges that against ``stale_s``)
        self.last_t: float | None = None

    def put(self, sample: ImuSample) -> None:
        if len(self._samples) == self._samples.maxlen:
            self.dropped += 1
        self._samples.append(sample)
        self.received += 1
        self.last_t = sample.t

    def drain(self) -> list[ImuSample]:
        """The samples since the last drain, oldest first."""
        out: list[ImuSample] = []
        pop = self._samples.popleft
        try:
            while True:
                out.append(pop())
        except IndexError:
            return out


# ------------------------------------------------------------ units and mounting

#: Angular-rate units an IMU may report in -> rad/s per unit. The spellings DBC files
#: use for them are here too ("°/s" is the common one).
RATE_UNITS: dict[str, float] = {
    "rad/s": 1.0,
    "deg/s": math.pi / 180.0,
    "°/s": math.pi / 180.0,
    "dps": math.pi / 180.0,
    "mrad/s": 1e-3,
}

#: Acceleration units -> m/s^2 per unit.
ACCEL_UNITS: dict[str, float] = {
    "m/s^2": 1.0,
    "m/s²": 1.0,
    "m/s**2": 1.0,
    "m/s2": 1.0,
    "g": 9.80665,
    "mg": 9.80665e-3,
}


def rate_unit(unit: str) -> float | None:
    """rad/s per ``unit`` of angular rate (any case, spaces ignored); None for a unit
    this module does not know (an empty one among them)."""
    return _unit(unit, RATE_UNITS)


def accel_unit(unit: str) -> float | None:
    """m/s^2 per ``unit`` of acceleration; None for one it does not know."""
    return _unit(unit, ACCEL_UNITS)


def _unit(unit: str, table: dict[str, float]) -> float | None:
    key = unit.replace(" ", "").lower()
    for name, factor in table.items():
        if name.lower() == key:
            return factor
    return None


@dataclass(frozen=True, slots=True)
class ImuMount:
    """How an IMU sits on the base: turned ``yaw_deg`` about the base's z axis (its x
    axis points that far counter-clockwise of the base's), and ``upside_down`` (turned
    over about its x axis: its z axis points down, so its yaw rate and its y axis are
    the base's negated). A yaw turn leaves the yaw rate as it is and turns the
    accelerations; REP-103 frames on both sides."""

    yaw_deg: float = 0.0
    upside_down: bool = False

    def to_base(self, t: float, yaw_rate: float, accel_x: float | None = None,
                accel_y: float | None = None) -> ImuSample:
        """A reading in the IMU's frame (rad/s, m/s^2) as an :class:`ImuSample` in the
        base's."""
        wz = -yaw_rate if self.upside_down else yaw_rate
        if accel_x is None or accel_y is None:
            return ImuSample(t, wz)
        ay = -accel_y if self.upside_down else accel_y
        c, s = math.cos(math.radians(self.yaw_deg)), math.sin(math.radians(self.yaw_deg))
        return ImuSample(t, wz, c * accel_x - s * ay, s * accel_x + c * ay)

    def from_base(self, yaw_rate: float, accel_x: float = 0.0,
                  accel_y: float = 0.0) -> tuple[float, float, float]:
        """What this IMU measures, in its own frame, of the base's yaw rate and
        accelerations: the inverse of :meth:`to_base` (the simulator's gyro)."""
        c, s = math.cos(math.radians(self.yaw_deg)), math.sin(math.radians(self.yaw_deg))
        ax, ay = c * accel_x + s * accel_y, -s * accel_x + c * accel_y
        if self.upside_down:
            return -yaw_rate, ax, -ay
        return yaw_rate, ax, ay


#: A stamp further from the host's clock than this is not believed (another clock, a
#: bag played back, a device that counts from its power-up): the arrival time stands.
MAX_STAMP_AGE_S = 1.0


def host_time(stamp_wall: float, now: float, now_wall: float,
              max_age_s: float = MAX_STAMP_AGE_S) -> float:
    """The host's monotonic time of a reading stamped ``stamp_wall`` (s since the epoch,
    as a CAN interface's receive time or a ROS header stamp on a synchronised clock),
    received at ``now`` (monotonic), when the wall clock read ``now_wall``. A stamp in
    the future or older than ``max_age_s`` is not believed: then ``now`` (the arrival)."""
    age = now_wall - stamp_wall
    if not (0.0 <= age <= max_age_s):
        return now
    return now - age


def sample_of_imu_msg(mount: ImuMount, stamp_s: float, angular_z: float, accel_x: float,
                      accel_y: float, rate_covariance0: float, accel_covariance0: float,
                      now: float, now_wall: float) -> ImuSample | None:
    """A ``sensor_msgs/Imu`` (header stamp ``stamp_s`` in s since the epoch, its
    ``angular_velocity.z``, ``linear_acceleration.x/.y``, element 0 of their covariances)
    as a sample in the base's frame, received at ``now`` (monotonic) when the wall clock
    read ``now_wall``. None where the message has no angular velocity (element 0 of its
    covariance -1, as sensor_msgs/Imu says for "no estimate") or a value is not finite;
    its accelerations are left out likewise. Its time: :func:`host_time` of the stamp."""
    if rate_covariance0 == -1.0 or not math.isfinite(angular_z):
        return None
    t = host_time(stamp_s, now, now_wall)
    if accel_covariance0 == -1.0 or not (math.isfinite(accel_x) and math.isfinite(accel_y)):
        return mount.to_base(t, angular_z)
    return mount.to_base(t, angular_z, accel_x, accel_y)
