"""A ``sensor_msgs/Imu`` from a network into the base's IMU inbox, as the ROS 2 and Zenoh
front ends take it alike (:mod:`omnican.ros2.imu`, :mod:`omnican.zenoh.imu`).

A front end reads a sample its own way (DDS's types, or CDR from Zenoh) into the fields
:func:`omnican.core.imu.sample_of_imu_msg` takes; :meth:`ImuIntake.take` counts it,
turns it into the base's frame by the ``[imu]`` mounting and puts it in the inbox. One
that does not read, or has no angular velocity, is counted as rejected and said in a
log line every few seconds at most (a malformed sample must not stop the front end's
poll, nor reach Zenoh's thread).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import TYPE_CHECKING

from omnican.core.imu import ImuInbox, ImuMount, ImuSample, sample_of_imu_msg
from omnican.log_throttle import Throttle

if TYPE_CHECKING:
    from omnican.config import ImuSettings

#: (header stamp in s since the epoch, angular_velocity.z, linear_acceleration.x and .y,
#: element 0 of the angular velocity's covariance, and of the acceleration's)
ImuFields = tuple[float, float, float, float, float, float]


class ImuIntake:
    """One IMU topic's samples into ``inbox`` (see the module docstring), logged to
    ``logger``. ``received``: samples taken, ``rejected``: those that did not read or had
    no angular velocity, ``last``: the newest sample put."""

    def __init__(self, inbox: ImuInbox, settings: ImuSettings, topic: str,
                 logger: logging.Logger, unreadable: str) -> None:
        self.inbox = inbox
        self.topic = topic
        self.mount = ImuMount(settings.mount_yaw_deg, settings.upside_down)
        self._unreadable = unreadable  # how a sample that did not read is told
        self._throttle = Throttle(logger)
        self.received = 0
        self.rejected = 0
        self.last: ImuSample | None = None

    def take(self, read: Callable[[], ImuFields], now: float, now_wall: float) -> None:
        """One sample, read by ``read`` (whatever it raises: rejected), that arrived at
        ``now`` (monotonic) when the wall clock read ``now_wall``."""
        self.received += 1
        try:
            sample = sample_of_imu_msg(self.mount, *read(), now, now_wall)
        except Exception as exc:  # a malformed sample is counted and said, never raised
            self.rejected += 1
            self._throttle.warning("parse", "%s: a sample %s (%d so far): %s", self.topic,
                                   self._unreadable, self.rejected, exc)
            return
        if sample is None:
            self.rejected += 1
            self._throttle.warning("empty", "%s: a sample without angular velocity "
                                   "(covariance -1 or not finite; %d so far)", self.topic,
                                   self.rejected)
            return
        self.inbox.put(sample)
        self.last = sample

    def flush(self) -> None:
        """Say what the throttle held back."""
        self._throttle.flush()
