"""The base (:class:`Chassis`) and the parts it is made of: the control cycle
(:mod:`~omnican.chassis.cycle`), the node supervisor (:mod:`~omnican.chassis.supervisor`),
the runner (:mod:`~omnican.chassis.runner`) with its thread's real-time priority
(:mod:`~omnican.chassis.realtime`) and signal handling (:mod:`~omnican.chassis.signals`).
The state types are :mod:`omnican.chassis.state`'s; what layers above attach to a base
(the telemetry, a recording) is :mod:`omnican.chassis.sink`'s."""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from omnican.chassis.base import Chassis as Chassis
    from omnican.chassis.state import ChassisStatus as ChassisStatus
    from omnican.chassis.state import WheelState as WheelState

# Lazy: the state types are read by layers above (telemetry), which must not pull in the
# whole base to name a snapshot.
_HOMES = {"Chassis": "base", "ChassisStatus": "state", "WheelState": "state"}
__all__ = list(_HOMES)


def __getattr__(name: str) -> Any:
    home = _HOMES.get(name)
    if home is None:
        raise AttributeError(f"module 'omnican.chassis' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"omnican.chassis.{home}"), name)
    globals()[name] = value
    return value
