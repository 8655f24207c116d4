"""A ``sensor_msgs/Imu`` someone else publishes, into the base's IMU inbox, for the bridge
(:mod:`omnican.ros2.bridge`) when the config's ``[imu]`` says ``source = "ros2"``.

The reader is best effort (it matches a sensor-data publisher and a reliable one alike)
and keeps :data:`IMU_DEPTH` samples between polls; each poll puts every sample that
arrived, oldest first, into the inbox: its ``angular_velocity.z`` (and linear
accelerations) turned into the base's frame by the ``[imu]`` mounting. A sample's time
is its header stamp on the host's monotonic clock where the stamp is believable (within
a second of this host's wall clock: a publisher on this machine, or on a synchronised
one), else the time the poll took it (late by up to a poll period): the stamp is when
the IMU measured; the arrival is only when DDS got round to it.
"""

from __future__ import annotations

import logging
import time
from typing import TYPE_CHECKING

from omnican.core.imu import ImuInbox, ImuMount, ImuSample, sample_of_imu_msg
from omnican.log_throttle import Throttle
from omnican.ros2.transport import TopicQos, Transport

if TYPE_CHECKING:
    from omnican.config import ImuSettings

logger = logging.getLogger(__name__)

#: Samples the reader keeps between two polls: a 1 kHz IMU for a tenth of a second.
IMU_DEPTH = 100


class ImuReader:
    """Reads ``settings.topic`` into ``inbox``: :meth:`take` from the bridge's poll.
    ``received``: samples taken, ``rejected``: those that did not parse or had no angular
    velocity, ``last``: the newest sample put."""

    def __init__(self, inbox: ImuInbox, settings: ImuSettings, transport: Transport) -> None:
        from omnican.ros2 import msgs

        self.inbox = inbox
        self.topic = settings.topic
        self._mount = ImuMount(settings.mount_yaw_deg, settings.upside_down)
        self._type = msgs.Imu
        self._take = transport.reader(self.topic, msgs.Imu,
                                      TopicQos(reliable=False, depth=IMU_DEPTH))
        self._throttle = Throttle(logger)
        self.received = 0
        self.rejected = 0
        self.last: ImuSample | None = None

    def take(self) -> None:
        got = self._take()
        if not got:
            return
        self.received += len(got)
        now, now_wall = time.monotonic(), time.time()
        for r in got:
            try:
                msg = self._type.deserialize(r.data)
                stamp = msg.header.stamp
                sample = sample_of_imu_msg(
                    self._mount, stamp.sec + stamp.nanosec * 1e-9, msg.angular_velocity.z,
                    msg.linear_acceleration.x, msg.linear_acceleration.y,
                    msg.angular_velocity_covariance[0],
                    msg.linear_acceleration_covariance[0], now, now_wall)
            except Exception as exc:  # a malformed sample must not stop the poll
                self.rejected += 1
                self._throttle.warning("parse", "%s: a sample did not parse (%d so far): %s",
                                       self.topic, self.rejected, exc)
                continue
            if sample is None:
                self.rejected += 1
                self._throttle.warning("empty", "%s: a sample without angular velocity "
                                       "(covariance -1 or not finite; %d so far)", self.topic,
                                       self.rejected)
                continue
            self.inbox.put(sample)
            self.last = sample

    def flush(self) -> None:
        self._throttle.flush()
