"""What the front ends publish about the base, built once for all of them.

:mod:`~omnican.telemetry.messages` builds each message from a sample (pure);
:mod:`~omnican.telemetry.covariance` is the odometry's uncertainty;
:mod:`~omnican.telemetry.model` keeps what spans samples (:class:`Telemetry`);
:mod:`~omnican.telemetry.frames` makes CAN frames into messages, raw and decoded;
:mod:`~omnican.telemetry.feed` is the one feed front ends subscribe to (:class:`Feed`);
:mod:`~omnican.telemetry.attach` attaches it to a base (``feed_of(base)``) or a simulator;
:mod:`~omnican.telemetry.settings` reads from the config what they all say alike.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from omnican.lazy import lazy_names

if TYPE_CHECKING:
    from omnican.telemetry.feed import Feed, Sink
    from omnican.telemetry.messages import (
        CAN_FRAME,
        CAN_RX,
        CAN_TX,
        JSON,
        JSON_SCHEMAS,
        ROS2,
        TOPICS,
        TelemetrySample,
    )
    from omnican.telemetry.model import Message, Telemetry
    from omnican.telemetry.settings import TelemetrySettings

__all__ = ["CAN_FRAME", "CAN_RX", "CAN_TX", "JSON", "JSON_SCHEMAS", "ROS2", "TOPICS", "Feed",
           "Message", "Sink", "Telemetry", "TelemetrySample", "TelemetrySettings"]

# Each name from its module when first asked for: a base run beside a simulator imports
# this package (omnican.telemetry.attach) and uses none of it until a front end attaches.
_HOME = {"Feed": "feed", "Sink": "feed", "Message": "model", "Telemetry": "model",
         "TelemetrySettings": "settings",
         **{name: "messages" for name in ("CAN_FRAME", "CAN_RX", "CAN_TX", "JSON",
                                          "JSON_SCHEMAS", "ROS2", "TOPICS",
                                          "TelemetrySample")}}


__getattr__ = lazy_names(__name__, _HOME, globals())
