"""The live view in Foxglove (``--foxglove``): the base's telemetry to a Foxglove
WebSocket server (:mod:`~omnican.live.view`), clients let in by either name of the
protocol and over TLS (:mod:`~omnican.live.relay`), and, when control is on, driving
from Foxglove (:mod:`~omnican.live.control`) under the settings of
:mod:`~omnican.live.settings`; as a front end's plug-in, :mod:`~omnican.live.front_end`.
Needs ``pip install 'omnican[foxglove]'``; importing this package does not, and imports
none of its modules until a name below is asked for.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from omnican.lazy import lazy_names

if TYPE_CHECKING:  # the same names for type checkers and editors
    from omnican.live.settings import DEFAULT_HOST as DEFAULT_HOST
    from omnican.live.settings import DEFAULT_PORT as DEFAULT_PORT
    from omnican.live.settings import FOXGLOVE_HELP as FOXGLOVE_HELP
    from omnican.live.settings import FoxgloveSettings as FoxgloveSettings
    from omnican.live.settings import foxglove_address as foxglove_address
    from omnican.live.settings import is_loopback as is_loopback
    from omnican.live.settings import parse_address as parse_address
    from omnican.live.settings import resolve as resolve
    from omnican.live.view import LiveView as LiveView
    from omnican.live.view import describe_control as describe_control
    from omnican.live.view import prepare as prepare
    from omnican.live.view import watch as watch

# Each name and the module it lives in.
_HOMES = {
    "DEFAULT_HOST": "settings", "DEFAULT_PORT": "settings", "FoxgloveSettings": "settings",
    "is_loopback": "settings", "parse_address": "settings", "resolve": "settings",
    "FOXGLOVE_HELP": "settings", "foxglove_address": "settings", "LiveView": "view",
    "describe_control": "view", "prepare": "view", "watch": "view",
}

__all__ = ["DEFAULT_HOST", "DEFAULT_PORT", "FOXGLOVE_HELP", "FoxgloveSettings", "LiveView",
           "describe_control", "foxglove_address", "is_loopback", "parse_address", "prepare",
           "resolve", "watch"]


__getattr__ = lazy_names(__name__, _HOMES, globals())


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
