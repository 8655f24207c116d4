"""What configuring a node needs of it: the :class:`ConfigurableNode` protocol that NMT
and boot (:mod:`~omnican.drive.nmt`), the SDO configuration
(:mod:`~omnican.drive.sdo_config`) and the PDO configuration
(:mod:`~omnican.drive.pdo_config`) take, so that none of them imports the node that runs
them (:class:`omnican.drive.node.DriveNode`).
"""

from __future__ import annotations

import threading
from typing import Any, Protocol

import canopen

from omnican.clock import Clock
from omnican.config import ChassisSettings
from omnican.drive.cyclic import AxisIO
from omnican.drive.health import NodeHealth
from omnican.drive.power_state import StageDriver
from omnican.plan.health import HealthPlan
from omnican.plan.node import NodeLayout
from omnican.plan.pdo import NodePlan
from omnican.protocol.cia402 import Mode
from omnican.protocol.heartbeat import HeartbeatWatch


class ConfigurableNode(Protocol):
    """What the configuration needs of a node (:class:`omnican.drive.DriveNode`)."""

    node_id: int
    network: canopen.Network
    remote: canopen.RemoteNode
    settings: ChassisSettings
    layout: NodeLayout
    dictionary: Any
    eds_name: str
    mode: Mode
    has_consumer: bool
    clock: Clock
    stages: list[StageDriver]
    axes: list[AxisIO]
    nmt_state: int | None
    seen_operational: bool
    twins: bool
    boot_count: int
    configured_boot: int
    _boot_seen: threading.Condition

    health: NodeHealth
    heartbeat: HeartbeatWatch

    def use_plan(self, plan: NodePlan) -> None: ...

    def use_health(self, plan: HealthPlan) -> None: ...
