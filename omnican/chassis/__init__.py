"""The base (:class:`Chassis`) and the parts it is made of: the control cycle
(:mod:`~omnican.chassis.cycle`), the node supervisor (:mod:`~omnican.chassis.supervisor`),
the runner (:mod:`~omnican.chassis.runner`) with its thread's real-time priority
(:mod:`~omnican.chassis.realtime`) and signal handling (:mod:`~omnican.chassis.signals`).
The state types are :mod:`omnican.state`'s."""

from omnican.chassis.base import Chassis
from omnican.state import ChassisStatus, WheelState

__all__ = ["Chassis", "ChassisStatus", "WheelState"]
