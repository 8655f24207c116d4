"""A simulated CiA 402 wheel drive on a canopen network.

Four parts, each in modules of its own, put together here:

- :mod:`omnican.sim.node`: the CiA 301 side on :class:`canopen.LocalNode` (NMT, the
  SDO server, SYNC, EMCY), with the objects' reads and writes in
  :mod:`omnican.sim.objects`, the PDOs at run time in :mod:`omnican.sim.process_data`
  and the heartbeats in :mod:`omnican.sim.heartbeat`;
- :mod:`omnican.sim.device`: the CiA 402 device behind it, which the node side calls:
  the power stage of each controlword (:mod:`omnican.sim.stage`, pure), the motors
  (:mod:`omnican.sim.axis`: modes, ramps, counters, advanced lazily) and what the
  drive reports of itself (:mod:`omnican.sim.health`: current, torque, DC link,
  temperature, following error, the e-stop input, from :mod:`omnican.sim.electrical`);
- :mod:`omnican.sim.faults`: fault injection (faults, silence, reboots; a jammed,
  pushed or lifted wheel, a following error, the supply voltage, the e-stop).

:class:`SimulatedDrive` wires them: it builds the device and its node side, shares
one lock between them, reads the wheel's physical state, and runs the housekeeping.

Threads: frames are handled on the network's Notifier thread; a
:class:`SimScheduler` tick covers time-driven work. One lock per drive.
"""

from __future__ import annotations

import random
import threading
from collections.abc import Mapping, Sequence
from pathlib import Path

import canopen
from canopen import objectdictionary as od

from omnican.clock import REAL_TIME, Clock
from omnican.config import WHEEL_EDS
from omnican.protocol.cia402 import State
from omnican.protocol.object_map import parse_eds
from omnican.sim.axis import DEFAULT_TAU_S
from omnican.sim.device import CIA402_SERVO_DRIVE, Device
from omnican.sim.faults import DriveFaults
from omnican.sim.health import DEFAULT_COUNTS_PER_M, EstopInput
from omnican.sim.node import SimNode
from omnican.sim.program import SimProgram
from omnican.sim.program import attach as attach_program
from omnican.sim.scheduler import SimScheduler

__all__ = ["CIA402_SERVO_DRIVE", "SimulatedDrive"]

Key = tuple[int, int]


class SimulatedDrive(DriveFaults):
    """A simulated CiA 402 drive attached to a connected ``canopen.Network``.

    What a test or the fault console does to it (:meth:`inject_fault`, :meth:`jam`,
    :meth:`reboot` ...) comes from :class:`~omnican.sim.faults.DriveFaults`.

    Args:
        network: a connected network (``network.connect(...)`` done).
        node_id: CANopen node id.
        eds: EDS of the drive; default the bundled omnican wheel drive.
        counts_per_unit: encoder counts per second per unit of the velocity
            objects (60FFh, 6042h), one value for all axes or one per axis.
        tau_s: velocity lag time constant of the motor.
        encoder_noise: standard deviation (counts) added to reported positions.
        slip: fraction of wheel motion lost to slip (read by the simulated base).
        frame_loss: probability that a PDO or heartbeat frame is lost (either way).
        max_mapping_entries: mapping entries a PDO accepts (None: the EDS decides).
        remappable: False for a drive that refuses any PDO remapping.
        accept_unmappable: True for a drive that maps objects its EDS marks not
            PDO-mappable (PDOMapping=0), as real drives behind understating EDS files
            do; False (default) refuses them with the SDO abort "object cannot be mapped".
        initial_position: encoder counts at power-up, per axis (to test wrap-around).
        counts_per_m: encoder counts per metre at the rim, per axis (for the motor
            current; a simulated base gives its wheels').
        signals: vendor objects that carry a health value, as a config names them:
            (index, sub) -> (quantity, axis, SI units per unit); see
            :mod:`omnican.sim.health`.
        estop_input: where the e-stop shows (default: 60FDh bit 16).
        scheduler: share a housekeeping thread; default one of its own.
        boot: send the boot-up frame and enter PRE-OPERATIONAL now.
        seed: random seed for noise and frame loss.
        program: the drive takes programs over the bus (CiA 302-3: 1F50h, 1F51h, 1F56h,
            1F57h; :mod:`omnican.sim.program`), added to its dictionary where its EDS
            lacks them; a :class:`~omnican.sim.program.SimProgram` to share one flash
            across drives made again (a power cycle that rebuilds them); False: none.
        clock: :data:`~omnican.clock.REAL_TIME`, or the
            :class:`~omnican.clock.SimClock` of a lock-step simulation (then the
            scheduler is stepped by that clock, not by a thread).
    """

    def __init__(
        self,
        network: canopen.Network,
        node_id: int,
        eds: str | Path | None = None,
        *,
        counts_per_unit: float | Sequence[float] = 1.0,
        tau_s: float = DEFAULT_TAU_S,
        encoder_noise: float = 0.0,
        slip: float = 0.0,
        frame_loss: float = 0.0,
        max_mapping_entries: int | None = None,
        remappable: bool = True,
        accept_unmappable: bool = False,
        initial_position: float | Sequence[float] = 0.0,
        counts_per_m: float | Sequence[float] = DEFAULT_COUNTS_PER_M,
        signals: Mapping[Key, tuple[str, int, float]] | None = None,
        estop_input: EstopInput | None = None,
        scheduler: SimScheduler | None = None,
        boot: bool = True,
        seed: int | None = None,
        clock: Clock = REAL_TIME,
        program: bool | SimProgram = True,
    ) -> None:
        if not 1 <= node_id <= 127:
            raise ValueError(f"node_id must be 1-127, got {node_id}")
        self.network = network
        self.node_id = node_id
        self.clock = clock
        self.eds = Path(eds) if eds is not None else WHEEL_EDS
        self.node = canopen.LocalNode(node_id, parse_eds(self.eds, node_id))
        self.dictionary: od.ObjectDictionary = self.node.object_dictionary
        self.slip = slip
        self.lock = threading.RLock()
        rng = random.Random(seed)  # one stream: encoder noise and frame loss

        self.device = Device(
            self.node, self.eds.name, counts_per_unit=counts_per_unit,
            initial_position=initial_position, counts_per_m=counts_per_m, tau_s=tau_s,
            encoder_noise=encoder_noise, rng=rng, signals=signals, estop_input=estop_input,
            clock=clock)
        device = self.device
        self.num_axes = device.num_axes
        self.groups, self.axes, self.stages = device.groups, device.axes, device.stages
        self.motion, self.health = device.motion, device.health
        # Written objects the drive acts on: (index, subindex) -> writer (may refuse).
        self._writers = device.writers
        self.comm = SimNode(
            network, self.node, device, readers=device.readers, lock=self.lock, clock=clock,
            rng=rng, defaults=device.defaults(), frame_loss=frame_loss,
            max_mapping_entries=max_mapping_entries, remappable=remappable,
            accept_unmappable=accept_unmappable)
        device.attach(self.comm)
        #: the program download objects (None: the drive has none)
        self.program: SimProgram | None = None
        if program is not False:
            if isinstance(program, SimProgram):  # another drive's flash: its power cycled
                program.power_cycle()
            self.program = program if isinstance(program, SimProgram) else SimProgram(
                self._driving)
            self.program.busy = self._driving
            attach_program(self.node, self.comm.readers, self._writers, self.comm.block.sinks,
                           self.program)
            self.comm.on_boot.append(self.program.booted)

        self._own_scheduler = scheduler is None
        self.scheduler = scheduler if scheduler is not None else SimScheduler(clock=clock)
        self.comm.prefill_defaults()
        self.motion.load_window()
        if boot:
            self.comm.boot(reset_node=False)
        self.scheduler.add(self.tick)
        if self._own_scheduler:
            self.scheduler.start()

    # ------------------------------------------------------------- properties

    @property
    def nmt_state(self) -> str:
        return self.comm.nmt_state

    def state(self, axis: int = 0) -> State:
        return self.axes[axis].group.stage.state

    def _driving(self) -> bool:
        """A power stage is OPERATION ENABLED (the program is not stopped then)."""
        return any(stage.state is State.OPERATION_ENABLED for stage in self.stages)

    @property
    def frozen(self) -> bool:
        return self.comm.frozen

    @property
    def frame_loss(self) -> float:
        return self.comm.frame_loss

    @frame_loss.setter
    def frame_loss(self, value: float) -> None:
        self.comm.frame_loss = value

    @property
    def tau_s(self) -> float:
        return self.motion.tau_s

    @property
    def encoder_noise(self) -> float:
        return self.motion.encoder_noise

    # ------------------------------------------------------- the wheel, read

    def physical_counts(self, axis: int = 0, now: float | None = None) -> float:
        """Encoder counts the wheel really turned since power-up (never reset or wrapped),
        at ``now`` (default: the present)."""
        with self.lock:
            self.advance(self.clock.now() if now is None else now)
            return self.axes[axis].state.position

    def velocity_counts(self, axis: int = 0) -> float:
        with self.lock:
            self.advance(self.clock.now())
            return self.axes[axis].state.velocity

    def ground_counts(self, axis: int = 0, now: float | None = None) -> float:
        """Encoder counts the wheel rolled on the ground since power-up (what moved the
        base), at ``now`` (default: the present)."""
        with self.lock:
            self.advance(self.clock.now() if now is None else now)
            return self.axes[axis].ground_position

    def current_a(self, axis: int = 0) -> float:
        """The motor current of ``axis`` now (A)."""
        with self.lock:
            self.advance(self.clock.now())
            return self.health.current_a(self.axes[axis])

    def read(self, index: int, subindex: int = 0) -> bytes:
        """Current raw value of an object, as an SDO upload would return it."""
        with self.lock:
            self.advance(self.clock.now())
            return bytes(self.node.get_data(index, subindex))

    # ------------------------------------------------------------ housekeeping

    def advance(self, now: float) -> None:
        """Bring the motors and the power stages up to ``now``."""
        self.device.advance(now)

    def tick(self, now: float) -> None:
        """Housekeeping (called by the scheduler). The motors are brought up to date at
        least once a housekeeping period: SYNCs, SDO requests and controlwords do it in
        between (a drive on a running bus moves its motors once a SYNC, not twice)."""
        with self.lock:
            if self.comm.closed:
                return
            if now - self.motion.last_advance >= self.scheduler.period_s:
                self.device.advance(now)
            self.comm.tick(now)

    # ------------------------------------------------------------ lifecycle

    def close(self) -> None:
        """Detach from the network and stop the housekeeping (idempotent)."""
        with self.lock:
            if self.comm.closed:
                return
            self.comm.closed = True  # nothing is sent from here on
        self.scheduler.remove(self.tick)
        if self._own_scheduler:
            self.scheduler.close()
        self.comm.detach()

    def __enter__(self) -> SimulatedDrive:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<SimulatedDrive node {self.node_id} {self.eds.name} {self.nmt_state}>"
