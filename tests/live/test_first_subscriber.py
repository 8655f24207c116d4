"""The live view's first client costs the control loop nothing slow: ``prepare`` has
generated every ROS 2 serializer the view sends (rosbags compiles a type's serializer on
its first message, ~170 ms for the view's types, most of it holding the interpreter's
lock: a client that subscribed to every channel stalled the loop by ~100 ms)."""

from __future__ import annotations

import importlib.util
import sys
from typing import Any

import pytest

from omnican.live import prepare
from omnican.telemetry import cdr
from omnican.telemetry.attach import feed_of
from omnican.telemetry.model import Message
from tests.support.helpers import drive_for, lockstep_rig

_counting: list[str] | None = None


def _audit(event: str, args: tuple[Any, ...]) -> None:
    if _counting is not None and event == "compile":
        _counting.append(str(args[1]) if len(args) > 1 else "?")


sys.addaudithook(_audit)  # a hook stays for the process: it counts only inside the test


class Everything:
    """A sink subscribed to every topic that encodes every message, as the live view does
    for a client subscribed to every channel."""

    def __init__(self) -> None:
        self.messages = 0

    def wants(self, topic: str) -> bool:
        return True

    def publish(self, messages: list[Message]) -> None:
        for msg in messages:
            msg.payload()
        self.messages += len(messages)


@pytest.mark.skipif(importlib.util.find_spec("foxglove") is None, reason="needs foxglove-sdk")
def test_after_prepare_a_client_subscribed_to_everything_compiles_nothing(channel: str) -> None:
    global _counting
    # A process that has sent no ROS 2 message yet (earlier tests may have).
    cdr.typestore.cache_clear()
    cdr._builder.cache_clear()
    with lockstep_rig(channel) as (_clock, sim, base):
        prepare(base.cfg)
        feed = feed_of(base)
        feed.truth = sim
        sink = Everything()
        feed.add(sink)
        _counting = compiled = []
        try:
            drive_for(base, 1.0, vx=0.2, wz=0.5)  # every message of the view, a few times
        finally:
            _counting = None
            feed.remove(sink)
    assert sink.messages > 0
    assert not compiled, f"compiled on the first messages: {sorted(set(compiled))[:5]}"
