"""Simulated CiA 402 wheel drives and a simulated base with ground truth.

A product feature (``omnican sim``, ``--sim``), not a test helper: the drives behave
on the wire like real ones, so code that works against them works on a robot.

A drive (:mod:`~omnican.sim.drive`) is its CiA 301 node side (:mod:`~omnican.sim.node`,
:mod:`~omnican.sim.objects`, :mod:`~omnican.sim.process_data`,
:mod:`~omnican.sim.heartbeat`, :mod:`~omnican.sim.pdo`, :mod:`~omnican.sim.transmit`),
the CiA 402 device behind it (:mod:`~omnican.sim.device`: the power stage
:mod:`~omnican.sim.stage`, the axes' motion :mod:`~omnican.sim.axis` over the motor
model :mod:`~omnican.sim.motor`, the drive's health :mod:`~omnican.sim.health`) and its
fault injection (:mod:`~omnican.sim.faults`); the base (:mod:`~omnican.sim.base`) makes
one per node as the config reads them (:mod:`~omnican.sim.wiring`) and adds the ground
truth (:mod:`~omnican.sim.truth`).
"""

from omnican.clock import SimClock
from omnican.sim.base import SimulatedBase
from omnican.sim.drive import SimulatedDrive
from omnican.sim.scheduler import SimScheduler

__all__ = ["SimClock", "SimScheduler", "SimulatedBase", "SimulatedDrive"]
