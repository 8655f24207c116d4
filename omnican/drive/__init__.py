"""One CANopen CiA 402 node: the stage drivers (:mod:`~omnican.drive.stage`), its cyclic
frames (:mod:`~omnican.drive.cyclic`), its SDO configuration (:mod:`~omnican.drive.setup`)
and the node itself (:mod:`~omnican.drive.node`)."""

from omnican.drive.cyclic import AxisIO, SdoCounts
from omnican.drive.node import DriveNode
from omnican.drive.stage import StageDriver

__all__ = ["AxisIO", "DriveNode", "SdoCounts", "StageDriver"]
