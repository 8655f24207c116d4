"""The live view in Foxglove (``--foxglove``): the base's telemetry to a Foxglove
WebSocket server (:mod:`~omnican.live.view`), clients let in by either name of the
protocol and over TLS (:mod:`~omnican.live.relay`), and, when control is on, driving
from Foxglove (:mod:`~omnican.live.control`) under the settings of
:mod:`~omnican.live.settings`. Needs ``pip install 'omnican[foxglove]'``; importing this
package does not.
"""

from __future__ import annotations

from omnican.live.settings import (
    DEFAULT_HOST,
    DEFAULT_PORT,
    FoxgloveSettings,
    is_loopback,
    parse_address,
    resolve,
)
from omnican.live.view import (
    FOXGLOVE_HELP,
    LiveView,
    describe_control,
    foxglove_address,
    prepare,
    watch,
)

__all__ = ["DEFAULT_HOST", "DEFAULT_PORT", "FOXGLOVE_HELP", "FoxgloveSettings", "LiveView",
           "describe_control", "foxglove_address", "is_loopback", "parse_address", "prepare",
           "resolve", "watch"]
