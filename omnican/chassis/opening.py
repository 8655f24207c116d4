"""What :meth:`Chassis.open <omnican.chassis.base.Chassis.open>` makes before a base
runs: the bus (recorded from its first frame on), one node per drive, and the base of
them; what was made is released again when a step fails.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, TypeVar

from omnican.chassis.sink import Recording
from omnican.clock import Clock
from omnican.config import ChassisConfig
from omnican.drive import DriveNode
from omnican.io.bus import CanBus
from omnican.plan.node import node_layouts

B = TypeVar("B")


def make_base(make: Callable[[CanBus, list[DriveNode]], B], cfg: ChassisConfig,
              bus: Mapping[str, Any] | None, record: Recording[Any] | None, clock: Clock) -> B:
    """``make(bus, nodes)``, the base, once the config passed its checks (EDS problems
    surface before a file or the bus is made), ``record`` is open and hears the bus,
    and a node per drive is on it. Raises what the step that failed raised, with the
    bus closed and every node detached (``record`` closed too)."""
    if record is not None and not hasattr(record, "attach"):
        raise TypeError(f"record: a recording, such as omnican.record.recording."
                        f"FileRecording(path), not {record!r}")
    layouts = node_layouts(cfg)
    try:
        can_bus = CanBus(bus if bus is not None else cfg.bus, clock=clock,
                         recorder=record.open(cfg) if record is not None else None)
    except BaseException:
        if record is not None:
            record.close()
        raise
    nodes: list[DriveNode] = []
    try:
        for layout in layouts:
            nodes.append(DriveNode(can_bus.network, layout, can_bus, clock))
        return make(can_bus, nodes)
    except BaseException:
        for n in nodes:
            n.detach()
        can_bus.close()
        if record is not None:
            record.close()
        raise
