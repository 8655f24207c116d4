"""The simulator's ground truth on Zenoh, for a simulator with no base in its process
(``omnican sim --zenoh``): ``<ns>/sim/true_pose`` (geometry_msgs/msg/PoseStamped) in
rmw_zenoh's format, from a node of its own (``omnican_sim`` beside the base's
``omnican``), so that a test or an operator compares the odometry a base reports with
where the simulated robot really is.

The truth is the simulator's telemetry (:func:`omnican.telemetry.attach.simulator_feed`,
what ``omnican sim --foxglove`` shows): the publisher is a sink of that feed and
publishes on the feed's thread at the odometry's rate of the settings, never on the
simulator's.
"""

from __future__ import annotations

import contextlib
import logging
import threading
from collections.abc import Iterator
from typing import Any

from omnican.telemetry import TOPICS, Message
from omnican.telemetry.attach import Simulator, simulator_feed
from omnican.zenoh import rmw
from omnican.zenoh.bridge import TRUE_POSE, _Publisher
from omnican.zenoh.settings import ZenohSettings

logger = logging.getLogger(__name__)

#: The rate of the truth: the odometry's (it is compared with it).
RATE_OF = "/odom"


class TruthPublisher:
    """Publishes a simulator's true pose on a Zenoh session (see the module docstring).
    It owns neither the simulator nor the session; :meth:`close` withdraws its node's
    and its publisher's liveliness tokens."""

    def __init__(self, settings: ZenohSettings, session: Any, state_rate_hz: float) -> None:
        self.settings = settings.validate()
        ns = settings.ros_namespace
        self.node = rmw.RosNode(settings.domain_id, str(session.info.zid()), 0,
                             settings.node_name, namespace=ns)
        self._node_token = session.liveliness().declare_token(self.node.token())
        self.publisher = _Publisher(session, self.node, 1,
                                    rmw.fully_qualified(ns, TRUE_POSE[1:]),
                                    TOPICS[TRUE_POSE][0], rmw.Qos(depth=10))
        self.rate_hz = min(settings.rates_hz[RATE_OF], state_rate_hz)
        self._every = max(1, round(state_rate_hz / self.rate_hz))
        self._seen = 0
        self._lock = threading.Lock()
        self._closed = False

    def wants(self, topic: str) -> bool:
        return topic == TRUE_POSE

    def publish(self, messages: list[Message]) -> None:
        with self._lock:  # close() may run meanwhile, on another thread
            if self._closed:
                return
            for message in messages:
                if message.topic != TRUE_POSE:
                    continue
                self._seen += 1
                if (self._seen - 1) % self._every == 0:
                    self.publisher.put(message.payload(), message.stamp_ns)

    def close(self) -> None:
        """Publish no more; the graph sees the node leave. Idempotent."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        self.publisher.close()
        self._node_token.undeclare()


@contextlib.contextmanager
def publish_truth(sim: Simulator, settings: ZenohSettings,
                  session: Any) -> Iterator[TruthPublisher]:
    """``sim``'s true pose on ``session`` while the block runs."""
    with simulator_feed(sim) as feed:
        truth = TruthPublisher(settings, session, feed.settings.state_rate_hz)
        try:
            feed.add(truth)
            try:
                yield truth
            finally:
                feed.remove(truth)
        finally:
            truth.close()
