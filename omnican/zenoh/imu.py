"""A ``sensor_msgs/Imu`` someone else publishes on Zenoh (rmw_zenoh's format), into the
base's IMU inbox, for the bridge (:mod:`omnican.zenoh.bridge`) when the config's
``[imu]`` says ``source = "zenoh"``.

The subscriber is on the topic's data key as rmw_zenoh writes it (domain, topic, DDS
type name, type hash: :func:`omnican.zenoh.rmw.data_key`), with a liveliness token so
the ROS graph sees it; each sample is decoded from CDR as it arrives (Zenoh's thread),
its ``angular_velocity.z`` (and linear accelerations) turned into the base's frame by
the ``[imu]`` mounting and put in the inbox. Its time: the header stamp on the host's
monotonic clock where believable (within a second of this host's wall clock), else the
moment it arrived (see :func:`omnican.core.imu.host_time`).
"""

from __future__ import annotations

import logging
import threading
import time
from typing import TYPE_CHECKING, Any

from omnican.command.imu_intake import ImuFields, ImuIntake
from omnican.core.imu import ImuInbox
from omnican.zenoh import rmw

if TYPE_CHECKING:
    from omnican.config import ImuSettings

logger = logging.getLogger(__name__)

IMU_TYPE = "sensor_msgs/msg/Imu"
#: The largest sample decoded: a sensor_msgs/Imu with a long frame id is well under it.
MAX_IMU_BYTES = 4096


class ZenohImu(ImuIntake):
    """Subscribes ``settings.topic`` (resolved in ``node``'s namespace) on ``session``
    into ``inbox`` until :meth:`close`. ``received``: samples that arrived, ``rejected``:
    those that did not decode or had no angular velocity, ``last``: the newest put
    (:class:`ImuIntake`)."""

    def __init__(self, session: Any, node: rmw.RosNode, entity_id: int, domain_id: int,
                 inbox: ImuInbox, settings: ImuSettings) -> None:
        super().__init__(inbox, settings, rmw.fully_qualified(node.namespace, settings.topic),
                         logger, f"that is not a {IMU_TYPE}")
        hash_ = rmw.type_hash(IMU_TYPE)
        self.key = rmw.data_key(domain_id, self.topic, IMU_TYPE, hash_)
        self._lock = threading.Lock()
        self._closed = False
        qos = rmw.Qos(reliability=rmw.Reliability.BEST_EFFORT, depth=5)  # sensor data
        self._token = session.liveliness().declare_token(node.endpoint_token(
            entity_id, rmw.Kind.SUBSCRIPTION, self.topic, IMU_TYPE, hash_, qos))
        self._sub = session.declare_subscriber(self.key, self._on_sample)

    def _on_sample(self, sample: Any) -> None:
        now, now_wall = time.monotonic(), time.time()
        with self._lock:
            if self._closed:
                return
            self.take(lambda: _fields(sample), now, now_wall)

    def close(self) -> None:
        """Undeclare the subscriber and its token. Idempotent."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        self._sub.undeclare()
        self._token.undeclare()
        self.flush()


def _fields(sample: Any) -> ImuFields:
    """A Zenoh sample's Imu fields (raises for one too large or not an Imu)."""
    from omnican.telemetry import cdr

    data = sample.payload.to_bytes()
    if len(data) > MAX_IMU_BYTES:
        raise ValueError(f"a {len(data)}-byte sample (at most {MAX_IMU_BYTES})")
    msg = cdr.decode(IMU_TYPE, data)
    stamp = msg["header"]["stamp"]
    rate, accel = msg["angular_velocity"], msg["linear_acceleration"]
    return (stamp["sec"] + stamp["nanosec"] * 1e-9, float(rate["z"]), float(accel["x"]),
            float(accel["y"]), float(msg["angular_velocity_covariance"][0]),
            float(msg["linear_acceleration_covariance"][0]))
