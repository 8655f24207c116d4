"""A front end that leaves the telemetry feed gets nothing more once it has left: a
sample being handed to it is waited for (issue 36, item 17: the ROS 2 bridge closed its
DDS writers while the feed's thread was still publishing to it, and ``omnican ros2``
ended in a DDSException traceback after Ctrl-C)."""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any

from omnican import default_config
from omnican.clock import REAL_TIME
from omnican.core.kinematics import Twist
from omnican.core.odometry import Pose2D
from omnican.telemetry.feed import Feed
from omnican.telemetry.settings import TelemetrySettings
from tests.support.helpers import wait_for


@dataclass
class Truth:
    true_pose: Pose2D
    true_twist: Twist


class SlowSink:
    """Blocks in its first publish until released; counts what it was handed, and
    whether anything came after it said it had gone."""

    def __init__(self) -> None:
        self.inside = threading.Event()
        self.release = threading.Event()
        self.handed = 0
        self.gone = False
        self.after_gone = 0

    def wants(self, topic: str) -> bool:
        return True

    def publish(self, messages: list[Any]) -> None:
        if self.gone:
            self.after_gone += 1
        self.handed += 1
        self.inside.set()
        self.release.wait(10.0)


def feed() -> Feed:
    cfg = default_config()
    made = Feed(TelemetrySettings.from_config(cfg), cfg.kinematics(), REAL_TIME,
                has_base=False)
    made.truth = Truth(Pose2D(0.0, 0.0, 0.0), Twist(0.0, 0.0, 0.0))
    return made


def test_remove_waits_for_a_sample_being_handed_over() -> None:
    f = feed()
    sink = SlowSink()
    f.add(sink)
    try:
        f.offer(None)
        assert wait_for(sink.inside.is_set, 10.0)
        returned = threading.Event()

        def leave() -> None:
            f.remove(sink)
            sink.gone = True  # as the bridge closes its writers right after
            returned.set()

        leaving = threading.Thread(target=leave, name="test-leave")
        leaving.start()
        assert not returned.wait(0.3)  # still handing one over: remove() waits
        sink.release.set()
        assert returned.wait(10.0)
        leaving.join(10.0)
        for _ in range(20):
            f.offer(None)
        f.close()
    finally:
        sink.release.set()
        f.close()
    assert sink.handed >= 1 and sink.after_gone == 0


def test_a_front_end_may_leave_from_inside_its_own_publish() -> None:
    """The hand-over lock is re-entrant: a sink leaving on the feed's thread does not
    wait for itself."""
    f = feed()
    left = threading.Event()

    class Leaver:
        def wants(self, topic: str) -> bool:
            return True

        def publish(self, messages: list[Any]) -> None:
            f.remove(self)
            left.set()

    f.add(Leaver())
    try:
        f.offer(None)
        assert left.wait(10.0)
    finally:
        f.close()
