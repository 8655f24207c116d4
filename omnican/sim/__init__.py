"""Simulated CiA 402 wheel drives and a simulated base with ground truth.

A product feature (``omnican sim``, ``--sim``), not a test helper: the drives behave
on the wire like real ones, so code that works against them works on a robot.
"""

from omnican.clock import SimClock
from omnican.sim.base import SimulatedBase
from omnican.sim.drive import SimulatedDrive
from omnican.sim.scheduler import SimScheduler

__all__ = ["SimClock", "SimScheduler", "SimulatedBase", "SimulatedDrive"]
