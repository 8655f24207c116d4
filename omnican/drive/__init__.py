"""One CANopen CiA 402 node, in the standard's words: NMT and boot
(:mod:`~omnican.drive.nmt`), the SDO configuration (:mod:`~omnican.drive.sdo_config`,
through canopen's SDO client, :mod:`~omnican.drive.sdo_client`), the PDO configuration
(:mod:`~omnican.drive.pdo_config`), the power state machine
(:mod:`~omnican.drive.power_state`), its cyclic frames (:mod:`~omnican.drive.cyclic`),
its health values (:mod:`~omnican.drive.health`) and the node that holds them
(:mod:`~omnican.drive.node`)."""

from omnican.drive.cyclic import AxisIO, SdoCounts
from omnican.drive.node import DriveNode
from omnican.drive.power_state import StageDriver

__all__ = ["AxisIO", "DriveNode", "SdoCounts", "StageDriver"]
