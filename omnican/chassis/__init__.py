"""The base (:class:`Chassis`) and the parts it is made of: the control cycle
(:mod:`~omnican.chassis.cycle`), the node supervisor (:mod:`~omnican.chassis.supervisor`),
the runner (:mod:`~omnican.chassis.runner`) with its thread's real-time priority
(:mod:`~omnican.chassis.realtime`) and signal handling (:mod:`~omnican.chassis.signals`).
The state types are :mod:`omnican.chassis.state`'s; what layers above attach to a base
(the telemetry, a recording) is :mod:`omnican.chassis.sink`'s."""

from __future__ import annotations

from typing import TYPE_CHECKING

from omnican.lazy import lazy_names

if TYPE_CHECKING:
    from omnican.chassis.base import Chassis as Chassis
    from omnican.chassis.state import ChassisStatus as ChassisStatus
    from omnican.chassis.state import WheelState as WheelState

# Lazy: the state types are read by layers above (telemetry), which must not pull in the
# whole base to name a snapshot.
_HOMES = {"Chassis": "base", "ChassisStatus": "state", "WheelState": "state"}
__all__ = list(_HOMES)


__getattr__ = lazy_names(__name__, _HOMES, globals())
