"""The ROS 2 bridge as a front end's plug-in (:class:`omnican.front_end.FrontEnd`): its
table is ``[ros2]`` (:mod:`omnican.ros2.table`); it runs in its own command (``omnican
ros2``, whose flags are its own), where it makes the DDS participant before the drives
come up (:meth:`Ros2FrontEnd.prepare`) and bridges the base once it runs
(:class:`~omnican.ros2.bridge.Bridge`).
"""

from __future__ import annotations

import contextlib
import os
from typing import TYPE_CHECKING, Any

from omnican.errors import ConfigError
from omnican.front_end import Announce, FrontEnd
from omnican.ros2.table import TABLE

if TYPE_CHECKING:
    from omnican.chassis import Chassis
    from omnican.config import ChassisConfig
    from omnican.ros2.settings import Ros2Settings
    from omnican.telemetry.attach import Simulator


class Ros2FrontEnd(FrontEnd):
    """The base as a ROS 2 node over DDS (Cyclone DDS)."""

    name = "ros2"
    title = "ROS 2"
    table = TABLE

    def __init__(self, settings: Ros2Settings) -> None:
        super().__init__(settings)
        self.transport: Any = None  # the DdsTransport, once prepared
        self.bridge: Any = None  # the Bridge, once attached

    @classmethod
    def check_table(cls, table: Any, cfg: ChassisConfig, origin: str) -> None:
        from omnican.ros2.settings import from_table

        from_table(table, origin)
        names = table.get("joint_names")
        if names is not None and len(names) != len(cfg.wheels):
            raise ConfigError(f"{origin}: ros2.joint_names: {len(names)} names for "
                              f"{len(cfg.wheels)} wheels (one per [[wheel]], in order)")

    @property
    def drives(self) -> bool:
        return True

    def prepare(self, cfg: ChassisConfig) -> None:
        """The DDS participant, before the drives come up (a DDS that cannot start is one
        line, and nothing moved)."""
        from omnican.ros2.transport import DdsTransport

        self.transport = DdsTransport(self.settings, os.environ.get("CYCLONEDDS_URI"))
        self._stack.callback(self.transport.close)

    def _attach(self, stack: contextlib.ExitStack, base: Chassis | None,
                sim: Simulator | None, announce: Announce) -> None:
        from omnican.ros2.bridge import Bridge

        if base is None:
            raise ValueError("the ROS 2 bridge runs beside a base")
        if self.transport is None:
            self.prepare(base.cfg)
        self.bridge = stack.enter_context(Bridge(base, self.settings, self.transport,
                                                 sim=sim))  # type: ignore[arg-type]
