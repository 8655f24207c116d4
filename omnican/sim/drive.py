"""A simulated CiA 402 wheel drive on a canopen network.

Four parts, each in modules of its own, put together here:

- :mod:`omnican.sim.node`: the CiA 301 side on :class:`canopen.LocalNode` (NMT, the
  SDO server, SYNC, EMCY), with the PDOs at run time in
  :mod:`omnican.sim.process_data` and the heartbeats in :mod:`omnican.sim.heartbeat`;
- :mod:`omnican.sim.stage`: the CiA 402 power stage of each controlword, pure;
- :mod:`omnican.sim.axis`: the motors (modes, ramps, counters), advanced lazily;
- :mod:`omnican.sim.health`: what the drive reports of itself (current, torque, DC
  link, temperature, following error, the e-stop input), from
  :mod:`omnican.sim.electrical`.

:class:`SimulatedDrive` wires them: it gives the node side the dynamic objects
(statusword, counters, error code) and the writers of controlword and mode, turns the
power stage's reactions into EMCY frames and motor commands, and adds fault injection
(faults, silence, reboots; a jammed, pushed or lifted wheel, a following error, the
supply voltage, the e-stop).

Multi-axis drives work in both layouts omnican supports (see :mod:`omnican.protocol.object_map`):
axes at 0x800 offsets have a power stage each; sub-indexed axes share one.

Threads: frames are handled on the network's Notifier thread; a
:class:`SimScheduler` tick covers time-driven work. One lock per drive.
"""

from __future__ import annotations

import math
import random
import threading
from collections.abc import Callable, Mapping, Sequence
from functools import partial
from pathlib import Path

import canopen
from canopen import objectdictionary as od
from canopen.objectdictionary import SIGNED_TYPES
from canopen.sdo.exceptions import SdoAbortedError

from omnican.clock import REAL_TIME, Clock
from omnican.config import WHEEL_EDS
from omnican.protocol import cia402
from omnican.protocol.cia301 import (
    DEVICE_TYPE,
    EMCY_NO_ERROR,
    ERROR_REGISTER,
    ERROR_REGISTER_COMMUNICATION,
    ERROR_REGISTER_CURRENT,
    ERROR_REGISTER_GENERIC,
    ERROR_REGISTER_TEMPERATURE,
    ERROR_REGISTER_VOLTAGE,
    SDO_ABORT_VALUE_RANGE,
)
from omnican.protocol.cia402 import State
from omnican.protocol.object_map import AxisObjects, Obj
from omnican.sim.axis import DEFAULT_TAU_S, AxisGroup, Motion, group_axes, supported_modes
from omnican.sim.health import DEFAULT_COUNTS_PER_M, DriveHealth, EstopInput
from omnican.sim.node import SimNode
from omnican.sim.scheduler import SimScheduler
from omnican.sim.stage import DEFAULT_QUICK_STOP_OPTION, PowerStage, Reaction

CIA402_SERVO_DRIVE = 0x00020192  # 1000h: device profile 402, servo drive
# Error register (1001h) bits by EMCY class.
_ERROR_REGISTER_BITS = {0x2: ERROR_REGISTER_CURRENT, 0x3: ERROR_REGISTER_VOLTAGE,
                        0x4: ERROR_REGISTER_TEMPERATURE, 0x8: ERROR_REGISTER_COMMUNICATION}

Key = tuple[int, int]
_NO_REACTION = Reaction.NONE  # a plain name: Reaction.X is a descriptor call on Python 3.11


class SimulatedDrive:
    """A simulated CiA 402 drive attached to a connected ``canopen.Network``.

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
    ) -> None:
        if not 1 <= node_id <= 127:
            raise ValueError(f"node_id must be 1-127, got {node_id}")
        self.network = network
        self.node_id = node_id
        self.clock = clock
        self.eds = Path(eds) if eds is not None else WHEEL_EDS
        self.node = canopen.LocalNode(node_id, str(self.eds))
        self.dictionary: od.ObjectDictionary = self.node.object_dictionary
        self.slip = slip
        self.lock = threading.RLock()
        rng = random.Random(seed)  # one stream: encoder noise and frame loss

        self.num_axes = max(1, AxisObjects(self.dictionary, 0).num_axes)
        cpu = _per_axis(counts_per_unit, self.num_axes)
        init = _per_axis(initial_position, self.num_axes)
        if len(cpu) != self.num_axes or len(init) != self.num_axes:
            raise ValueError(f"{self.eds.name} has {self.num_axes} axes: give one value per axis")
        self.groups, self.axes = group_axes(
            self.dictionary, cpu, init, lambda: PowerStage(self._quick_stop_option),
            self.eds.name)
        self.stages: list[PowerStage] = [g.stage for g in self.groups]
        self._supported_modes = supported_modes(self.dictionary)
        self.motion = Motion(self.dictionary, self.groups, self.node.data_store,
                             self.node.get_data, tau_s=tau_s, encoder_noise=encoder_noise,
                             rng=rng, initial_position=init, start=clock.now())
        per_m = _per_axis(counts_per_m, self.num_axes)
        if len(per_m) != self.num_axes:
            raise ValueError(f"{self.eds.name} has {self.num_axes} axes: give one value per axis")
        self.health = DriveHealth(self.dictionary, self.axes, self.node.get_data,
                                  counts_per_m=per_m, signals=signals, estop=estop_input,
                                  start=clock.now())
        # Written objects the drive acts on: (index, subindex) -> writer (may refuse).
        self._writers: dict[Key, Callable[[int], None]] = {}
        readers = self._build_object_hooks()
        self.comm = SimNode(
            network, self.node, self, readers=readers, lock=self.lock, clock=clock, rng=rng,
            defaults={(DEVICE_TYPE, 0): CIA402_SERVO_DRIVE, (int(Obj.SUPPORTED_MODES), 0):
                      cia402.modes_to_bits(set(self._supported_modes))},
            frame_loss=frame_loss, max_mapping_entries=max_mapping_entries,
            remappable=remappable, accept_unmappable=accept_unmappable)

        self._own_scheduler = scheduler is None
        self.scheduler = scheduler if scheduler is not None else SimScheduler(clock=clock)
        self.comm.prefill_defaults()
        self.motion.load_window()
        if boot:
            self.comm.boot(reset_node=False)
        self.scheduler.add(self.tick)
        if self._own_scheduler:
            self.scheduler.start()

    # ------------------------------------------------------------------ setup

    def _build_object_hooks(self) -> dict[Key, Callable[[], int]]:
        """The dynamic objects' readers; the writers go to ``self._writers``."""
        readers = {**self.motion.readers(), **self.health.readers()}
        for group in self.groups:
            sw, cw = group.statusword, group.controlword
            readers[(sw.index, sw.subindex)] = self._statusword_of(group)
            self._writers[(cw.index, cw.subindex)] = partial(self._on_controlword, group)
            if group.mode_entry is not None:
                m = group.mode_entry
                self._writers[(m.index, m.subindex)] = partial(self._on_mode, group)
            display = group.axes[0].objs.get(Obj.MODE_DISPLAY)
            if display is not None:
                readers[(display.index, display.subindex)] = partial(self.motion.mode, group)
        err = self.axes[0].objs.get(Obj.ERROR_CODE)
        if err is not None:
            readers[(err.index, err.subindex)] = lambda: self.stages[0].fault_code
        if ERROR_REGISTER in self.dictionary:
            readers[(ERROR_REGISTER, 0)] = self._error_register
        return readers

    # ------------------------------------------------------------- properties

    @property
    def nmt_state(self) -> str:
        return self.comm.nmt_state

    def state(self, axis: int = 0) -> State:
        return self.axes[axis].group.stage.state

    @property
    def frozen(self) -> bool:
        return self.comm.frozen

    @property
    def frame_loss(self) -> float:
        return self.comm.frame_loss

    @frame_loss.setter
    def frame_loss(self, value: float) -> None:
        self.comm.frame_loss = value

    def slow_boot(self, seconds: float) -> None:
        """Answer an NMT reset with the boot-up ``seconds`` later (0: at once), answering
        SDOs meanwhile; a reset during that time starts the wait again."""
        if not (math.isfinite(seconds) and seconds >= 0):
            raise ValueError(f"a boot delay is 0 s or more, got {seconds}")
        with self.lock:
            self.comm.boot_delay_s = seconds

    def slow_sdo(self, seconds: float) -> None:
        """Answer each SDO request ``seconds`` after it came (0: at once)."""
        if not (math.isfinite(seconds) and seconds >= 0):
            raise ValueError(f"an SDO delay is 0 s or more, got {seconds}")
        with self.lock:
            self.comm.sdo_delay_s = seconds

    @property
    def tau_s(self) -> float:
        return self.motion.tau_s

    @property
    def encoder_noise(self) -> float:
        return self.motion.encoder_noise

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

    def read(self, index: int, subindex: int = 0) -> bytes:
        """Current raw value of an object, as an SDO upload would return it."""
        with self.lock:
            self.advance(self.clock.now())
            return bytes(self.node.get_data(index, subindex))

    # ------------------------------------------------------------- injection

    def inject_fault(self, code: int = 0x2310, axis: int = 0, persistent: bool = False) -> None:
        """Trip a fault: EMCY with ``code``, then FAULT REACTION ACTIVE -> FAULT.
        ``persistent``: its cause stays (a motor that has not cooled down): fault resets
        are refused until :meth:`clear_fault`."""
        with self.lock:
            self.advance(self.clock.now())
            group = self.axes[axis].group
            group.stage.fault_persists = persistent
            self._follow(group, group.stage.trip(code))

    def clear_fault(self, axis: int = 0) -> None:
        """The cause of a persistent fault is gone: the next fault reset clears it."""
        with self.lock:
            self.axes[axis].group.stage.fault_persists = False

    def hold_switched_on(self, held: bool = True, axis: int = 0) -> None:
        """The power stage cannot enable (no DC link voltage, safe torque off): enable
        operation is ignored, the drive stays SWITCHED ON."""
        with self.lock:
            self.axes[axis].group.stage.enable_held = held

    def stop_heartbeat(self) -> None:
        """Stop producing heartbeats (the drive keeps working otherwise)."""
        with self.lock:
            self.comm.heartbeat.enabled = False

    def start_heartbeat(self) -> None:
        with self.lock:
            self.comm.heartbeat.enabled = True

    def reboot(self) -> None:
        """Power-cycle: boot-up frame, OD defaults, position counters at their power-up value."""
        with self.lock:
            self.advance(self.clock.now())
            self.comm.boot(reset_node=True)

    def freeze(self) -> None:
        """Go silent: answer nothing, send nothing (a hung node). The motor keeps its demand."""
        with self.lock:
            self.comm.frozen = True

    def thaw(self) -> None:
        with self.lock:
            self.comm.frozen = False
            self.comm.heartbeat.last_sent = -1e9

    def _condition(self, axis: int, **values: object) -> None:
        """Change what holds an axis (from now on: the motion up to now is as it was)."""
        with self.lock:
            self.advance(self.clock.now())
            ax = self.axes[axis]
            for name, value in values.items():
                setattr(ax, name, value)
            self.motion.invalidate()

    def jam(self, axis: int = 0) -> None:
        """The wheel cannot turn (a jammed roller, a wheel against a wall): it stands
        still while its drive pushes at its current limit."""
        self._condition(axis, jammed=True)

    def free(self, axis: int = 0) -> None:
        """The wheel turns again (no longer jammed, nor pushed)."""
        self._condition(axis, jammed=False, pushed_counts_s=None)

    def push(self, speed_m_s: float, axis: int = 0) -> None:
        """Something turns the wheel at ``speed_m_s`` at the rim whatever its drive does
        (a push, a runaway drive); :meth:`free` ends it."""
        self._condition(axis, pushed_counts_s=speed_m_s * self._counts_per_m(axis))

    def lift(self, axis: int = 0) -> None:
        """The wheel is off the ground: it turns as its drive says, on much less
        current, and no longer moves the base."""
        self._condition(axis, grounded=False)

    def land(self, axis: int = 0) -> None:
        """The wheel is back on the ground."""
        self._condition(axis, grounded=True)

    def inject_following_error(self, counts: int = 5000, axis: int = 0) -> None:
        """The drive reports a following error: 60F4h reads ``counts`` and statusword
        bit 13 is set, until :meth:`clear_following_error`."""
        with self.lock:
            self.health.following_error[axis] = int(counts)

    def clear_following_error(self, axis: int = 0) -> None:
        with self.lock:
            self.health.following_error[axis] = None

    def set_supply(self, volts: float) -> None:
        """The supply (battery) voltage feeding the drive's DC link."""
        with self.lock:
            self.advance(self.clock.now())
            self.health.supply_v = float(volts)

    def estop(self, pressed: bool) -> None:
        """The e-stop: its input shows it (60FDh bit 16 by default) and, pressed, it
        takes the torque away (safe torque off): every power stage drops to SWITCH ON
        DISABLED and cannot be enabled until it is released."""
        with self.lock:
            self.advance(self.clock.now())
            self.health.estop_pressed = pressed
            for group in self.groups:
                self._follow(group, group.stage.safe_torque_off(pressed))
            self.comm.event_tpdos(self.clock.now())

    def current_a(self, axis: int = 0) -> float:
        """The motor current of ``axis`` now (A)."""
        with self.lock:
            self.advance(self.clock.now())
            return self.health.current_a(self.axes[axis])

    def ground_counts(self, axis: int = 0, now: float | None = None) -> float:
        """Encoder counts the wheel rolled on the ground since power-up (what moved the
        base), at ``now`` (default: the present)."""
        with self.lock:
            self.advance(self.clock.now() if now is None else now)
            return self.axes[axis].ground_position

    def _counts_per_m(self, axis: int) -> float:
        return self.health.counts_per_m[axis]

    # ------------------------- what the node side calls (node.Application)

    @property
    def last_advance(self) -> float:
        return self.motion.last_advance

    def advance(self, now: float) -> None:
        """Bring the motors and the power stages up to ``now``."""
        if self.motion.advance(now):
            for group in self.groups:
                if group.stage.settling and self.motion.standstill(group):
                    self._follow(group, group.stage.settle())
            self.health.warm(now)

    def write_hook(self, index: int, subindex: int,
                   var: od.ODVariable) -> Callable[[bytes, bool], None] | None:
        """Before an object is written: a new value of one that shapes the motion applies
        from now (the motors are advanced to now first), and the objects the drive acts
        on go to their writer, which may refuse the value (SDO abort: nothing stored)."""
        key = (index, subindex)
        shapes = self.motion.shapes(key)
        writer = self._writers.get(key)
        if not shapes and writer is None:
            return None
        signed = var.data_type in SIGNED_TYPES
        clock = self.clock

        def hook(data: bytes, changed: bool) -> None:
            if changed and shapes:
                self.advance(clock.now())  # the old value applied until now
            if writer is not None:
                writer(int.from_bytes(data, "little", signed=signed))

        return hook

    def written(self, index: int, subindex: int) -> None:
        self.motion.written(index, subindex)

    def booted(self, reset_node: bool) -> None:
        self.motion.invalidate()
        if reset_node:  # the power stages drop out: the wheels coast, the counters restart
            self.motion.power_up()
            for stage in self.stages:
                stage.power_up()
        self.motion.load_window()

    def abort_connection(self) -> None:
        """React to a lost master per 6007h (quick stop by default)."""
        option = self._option(Obj.ABORT_OPTION, cia402.ABORT_QUICK_STOP)
        for group in self.groups:
            self._follow(group, group.stage.abort_connection(option))

    def connection_restored(self) -> None:
        for stage in self.stages:
            stage.connection_restored()

    def tick(self, now: float) -> None:
        """Housekeeping (called by the scheduler). The motors are brought up to date at
        least once a housekeeping period: SYNCs, SDO requests and controlwords do it in
        between (a drive on a running bus moves its motors once a SYNC, not twice)."""
        with self.lock:
            if self.comm.closed:
                return
            if now - self.motion.last_advance >= self.scheduler.period_s:
                self.advance(now)
            self.comm.tick(now)

    # ----------------------------------------------------------- CiA 402

    def _follow(self, group: AxisGroup, reaction: Reaction) -> None:
        """Carry out what the power stage's reaction asks of the motors and the bus."""
        if reaction is Reaction.NONE:
            return
        if reaction is Reaction.ENABLED:
            self.motion.restart_ramps(group)
        self.motion.invalidate()
        if reaction is Reaction.FAULT:
            self.comm.emcy(group.stage.fault_code, self._error_register())
            self.comm.event_tpdos(self.clock.now())
        elif reaction is Reaction.RESET:
            self.comm.emcy(EMCY_NO_ERROR, 0)  # error reset

    def _on_controlword(self, group: AxisGroup, value: int) -> None:
        self.advance(self.clock.now())
        reaction = group.stage.write_controlword(value)
        if reaction is not _NO_REACTION:
            self._follow(group, reaction)

    def _on_mode(self, group: AxisGroup, value: int) -> None:
        if value not in self._supported_modes and value != 0:
            raise SdoAbortedError(SDO_ABORT_VALUE_RANGE)
        group.mode = value

    def _statusword_of(self, group: AxisGroup) -> Callable[[], int]:
        """The group's statusword (6041h), as the stage, the motors and the drive's health
        make it up (read with every event check: one closure, no lookups)."""
        stage, status_bits, health_bits = group.stage, self.motion.status_bits, \
            self.health.statusword_bits

        def statusword() -> int:
            return stage.statusword() | status_bits(group) | health_bits(group)

        return statusword

    def _error_register(self) -> int:
        reg = 0
        for stage in self.stages:
            if stage.fault_code:
                reg |= ERROR_REGISTER_GENERIC | _ERROR_REGISTER_BITS.get(stage.fault_code >> 12, 0)
        return reg

    def _option(self, obj: Obj, default: int) -> int:
        """An option code (605Ah, 6007h) as the drive's first axis has it."""
        entry = self.axes[0].objs.get(obj)
        if entry is None:
            return default
        return entry.decode(self.node.get_data(entry.index, entry.subindex))

    def _quick_stop_option(self) -> int:
        return self._option(Obj.QUICK_STOP_OPTION, DEFAULT_QUICK_STOP_OPTION)

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


def _per_axis(value: float | Sequence[float], n: int) -> list[float]:
    return list(value) if isinstance(value, Sequence) else [float(value)] * n
