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

import functools
import logging
import time
from typing import TYPE_CHECKING, Any

from omnican.command.imu_intake import ImuFields, ImuIntake
from omnican.core.imu import ImuInbox
from omnican.ros2.transport import TopicQos, Transport

if TYPE_CHECKING:
    from omnican.config import ImuSettings

logger = logging.getLogger(__name__)

#: Samples the reader keeps between two polls: a 1 kHz IMU for a tenth of a second.
IMU_DEPTH = 100


class ImuReader(ImuIntake):
    """Reads ``settings.topic`` into ``inbox``: :meth:`poll` from the bridge's poll.
    ``received``: samples taken, ``rejected``: those that did not parse or had no angular
    velocity, ``last``: the newest sample put (:class:`ImuIntake`)."""

    def __init__(self, inbox: ImuInbox, settings: ImuSettings, transport: Transport) -> None:
        from omnican.ros2 import msgs

        super().__init__(inbox, settings, settings.topic, logger, "did not parse")
        self._type = msgs.Imu
        self._reader = transport.reader(self.topic, msgs.Imu,
                                        TopicQos(reliable=False, depth=IMU_DEPTH))

    def poll(self) -> None:
        """Every sample that arrived since the last poll, oldest first, into the inbox."""
        got = self._reader()
        if not got:
            return
        now, now_wall = time.monotonic(), time.time()
        for r in got:
            self.take(functools.partial(self._fields, r.data), now, now_wall)

    def _fields(self, data: Any) -> ImuFields:
        msg = self._type.deserialize(data)
        stamp = msg.header.stamp
        return (stamp.sec + stamp.nanosec * 1e-9, msg.angular_velocity.z,
                msg.linear_acceleration.x, msg.linear_acceleration.y,
                msg.angular_velocity_covariance[0], msg.linear_acceleration_covariance[0])
