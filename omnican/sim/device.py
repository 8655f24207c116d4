"""The CiA 402 device behind a simulated drive's node: power stages, motors, health.

:class:`Device` is what :class:`~omnican.sim.node.SimNode` calls the
:class:`~omnican.sim.node.Application`: it gives the node side the dynamic objects
(statusword, counters, error code, the health values) and the writers of controlword and
mode, brings the motors and the power stages up to a frame's time, and turns the power
stages' reactions into EMCY frames and motor commands. Its parts live in modules of their
own: the power stage (:mod:`omnican.sim.stage`), the motors (:mod:`omnican.sim.axis`),
what the drive reports of itself (:mod:`omnican.sim.health`).

Multi-axis drives work in both layouts omnican supports (see
:mod:`omnican.protocol.object_map`): axes at 0x800 offsets have a power stage each;
sub-indexed axes share one.

Threads: called under the drive's lock (by the node's frame handlers, the
housekeeping tick and :class:`~omnican.sim.drive.SimulatedDrive`'s methods).
"""

from __future__ import annotations

import random
from collections.abc import Callable, Mapping, Sequence
from functools import partial

import canopen
from canopen import objectdictionary as od
from canopen.objectdictionary import SIGNED_TYPES
from canopen.sdo.exceptions import SdoAbortedError

from omnican.clock import Clock
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
from omnican.protocol.object_map import AxisObjects, Obj
from omnican.sim.axis import AxisGroup, Motion, group_axes, supported_modes
from omnican.sim.health import DriveHealth, EstopInput
from omnican.sim.node import SimNode
from omnican.sim.stage import DEFAULT_QUICK_STOP_OPTION, PowerStage, Reaction

CIA402_SERVO_DRIVE = 0x00020192  # 1000h: device profile 402, servo drive
# Error register (1001h) bits by EMCY class.
_ERROR_REGISTER_BITS = {0x2: ERROR_REGISTER_CURRENT, 0x3: ERROR_REGISTER_VOLTAGE,
                        0x4: ERROR_REGISTER_TEMPERATURE, 0x8: ERROR_REGISTER_COMMUNICATION}

Key = tuple[int, int]
_RATED_CURRENT = int(Obj.RATED_CURRENT)  # 6075h: the drive health reads it once until written
_NO_REACTION = Reaction.NONE  # a plain name: Reaction.X is a descriptor call on Python 3.11


class Device:
    """The CiA 402 side of one simulated drive (see the module docstring).

    Args:
        node: the LocalNode holding the drive's object dictionary.
        eds_name: the EDS's file name, for messages.
        counts_per_unit, initial_position, counts_per_m: one value per axis, or one
            for all (see :class:`~omnican.sim.drive.SimulatedDrive`).
        tau_s, encoder_noise, signals, estop_input: see
            :class:`~omnican.sim.drive.SimulatedDrive`.
        rng: random source of the encoder noise.
        clock: the drive's clock.

    :meth:`attach` gives it the node side, which it sends EMCY and event TPDOs with.
    """

    comm: SimNode  # the node side, from attach()

    def __init__(self, node: canopen.LocalNode, eds_name: str, *,
                 counts_per_unit: float | Sequence[float],
                 initial_position: float | Sequence[float],
                 counts_per_m: float | Sequence[float], tau_s: float, encoder_noise: float,
                 rng: random.Random, signals: Mapping[Key, tuple[str, int, float]] | None,
                 estop_input: EstopInput | None, clock: Clock) -> None:
        self.node = node
        self.clock = clock
        self.dictionary: od.ObjectDictionary = node.object_dictionary
        self.num_axes = max(1, AxisObjects(self.dictionary, 0).num_axes)
        cpu = _per_axis(counts_per_unit, self.num_axes)
        init = _per_axis(initial_position, self.num_axes)
        if len(cpu) != self.num_axes or len(init) != self.num_axes:
            raise ValueError(f"{eds_name} has {self.num_axes} axes: give one value per axis")
        self.groups, self.axes = group_axes(
            self.dictionary, cpu, init, lambda: PowerStage(self.quick_stop_option), eds_name)
        self.stages: list[PowerStage] = [g.stage for g in self.groups]
        self.supported_modes = supported_modes(self.dictionary)
        self.motion = Motion(self.dictionary, self.groups, node.data_store, node.get_data,
                             tau_s=tau_s, encoder_noise=encoder_noise, rng=rng,
                             initial_position=init, start=clock.now())
        per_m = _per_axis(counts_per_m, self.num_axes)
        if len(per_m) != self.num_axes:
            raise ValueError(f"{eds_name} has {self.num_axes} axes: give one value per axis")
        self.health = DriveHealth(self.dictionary, self.axes, node.get_data,
                                  counts_per_m=per_m, signals=signals, estop=estop_input,
                                  start=clock.now())
        # Written objects the drive acts on: (index, subindex) -> writer (may refuse).
        self.writers: dict[Key, Callable[[int], None]] = {}
        #: the readers of the objects :meth:`event_stamp` covers (statusword, mode
        #: display, error code, error register), filled with the readers
        self.stamped: dict[Key, Callable[[], int]] = {}
        #: the dynamic objects' readers, (index, subindex) -> raw value
        self.readers = self._build_object_hooks()
        self.event_stamp = self._event_stamp()

    def attach(self, comm: SimNode) -> None:
        """The node side this device sends its EMCY frames and event TPDOs with."""
        self.comm = comm

    def defaults(self) -> dict[Key, int]:
        """Values of the objects a CiA 402 drive fills in when its EDS gives none."""
        return {(DEVICE_TYPE, 0): CIA402_SERVO_DRIVE, (int(Obj.SUPPORTED_MODES), 0):
                cia402.modes_to_bits(set(self.supported_modes))}

    def _build_object_hooks(self) -> dict[Key, Callable[[], int]]:
        """The dynamic objects' readers; the writers go to ``self.writers``."""
        readers = {**self.motion.readers(), **self.health.readers()}
        for group in self.groups:
            sw, cw = group.statusword, group.controlword
            readers[(sw.index, sw.subindex)] = self._statusword_of(group)
            self.writers[(cw.index, cw.subindex)] = partial(self._on_controlword, group)
            if group.mode_entry is not None:
                m = group.mode_entry
                self.writers[(m.index, m.subindex)] = partial(self._on_mode, group)
            display = group.axes[0].objs.get(Obj.MODE_DISPLAY)
            if display is not None:
                readers[(display.index, display.subindex)] = partial(self.motion.mode, group)
        err = self.axes[0].objs.get(Obj.ERROR_CODE)
        if err is not None:
            readers[(err.index, err.subindex)] = lambda: self.stages[0].fault_code
        if ERROR_REGISTER in self.dictionary:
            readers[(ERROR_REGISTER, 0)] = self.error_register
        for group in self.groups:
            keys = [(group.statusword.index, group.statusword.subindex)]
            display = group.axes[0].objs.get(Obj.MODE_DISPLAY)
            if display is not None:
                keys.append((display.index, display.subindex))
            for key in keys:
                self.stamped[key] = readers[key]
        for key in [(err.index, err.subindex)] if err is not None else []:
            self.stamped[key] = readers[key]
        if ERROR_REGISTER in self.dictionary:
            self.stamped[(ERROR_REGISTER, 0)] = readers[(ERROR_REGISTER, 0)]
        return readers

    def _event_stamp(self) -> Callable[[], object]:
        """What the objects in :attr:`stamped` are made of, in one value that is equal
        between two calls only if each of those objects reads the same in both: the
        power stages' state, controlword, warning and fault code, the groups' modes,
        the e-stop and the following errors, as they are, and a count of the motion's
        changes (:attr:`omnican.sim.axis.Motion.changes`: velocities, commands, the
        window). The event TPDOs' check makes a TPDO of only such objects again only
        when this changed (one call, not the objects' own)."""
        motion, health = self.motion, self.health
        if len(self.groups) == 1 and len(self.axes) == 1:  # nearly every drive
            group, stage, number = self.groups[0], self.stages[0], self.axes[0].number

            def stamp() -> object:
                return (motion.changes, stage.state, stage.controlword, stage.warning,
                        stage.fault_code, group.mode, health.estop_pressed,
                        health.following_error[number])

            return stamp
        groups, stages = self.groups, self.stages

        def stamp_all() -> object:
            return (motion.changes, health.estop_pressed, tuple(health.following_error),
                    tuple((s.state, s.controlword, s.warning, s.fault_code) for s in stages),
                    tuple(g.mode for g in groups))

        return stamp_all

    # ------------------------------------ what the node side calls (node.Application)

    @property
    def last_advance(self) -> float:
        return self.motion.last_advance

    def advance(self, now: float) -> None:
        """Bring the motors and the power stages up to ``now``."""
        if self.motion.advance(now):
            for group in self.groups:
                if group.stage.settling and self.motion.standstill(group):
                    self.follow(group, group.stage.settle())
            self.health.warm(now)

    def write_hook(self, index: int, subindex: int,
                   var: od.ODVariable) -> Callable[[bytes, bool], None] | None:
        """Before an object is written: a new value of one that shapes the motion applies
        from now (the motors are advanced to now first), and the objects the drive acts
        on go to their writer, which may refuse the value (SDO abort: nothing stored)."""
        key = (index, subindex)
        shapes = self.motion.shapes(key)
        writer = self.writers.get(key)
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
        if index == _RATED_CURRENT:
            self.health.forget_rated()

    def booted(self, reset_node: bool) -> None:
        self.motion.invalidate()
        self.health.forget_rated()  # its dictionary restored
        if reset_node:  # the power stages drop out: the wheels coast, the counters restart
            self.motion.power_up()
            for stage in self.stages:
                stage.power_up()
        self.motion.load_window()

    def abort_connection(self) -> None:
        """React to a lost master per 6007h (quick stop by default)."""
        option = self.option(Obj.ABORT_OPTION, cia402.ABORT_QUICK_STOP)
        for group in self.groups:
            self.follow(group, group.stage.abort_connection(option))

    def connection_restored(self) -> None:
        for stage in self.stages:
            stage.connection_restored()

    # ----------------------------------------------------------- CiA 402

    def follow(self, group: AxisGroup, reaction: Reaction) -> None:
        """Carry out what the power stage's reaction asks of the motors and the bus."""
        if reaction is Reaction.NONE:
            return
        if reaction is Reaction.ENABLED:
            self.motion.restart_ramps(group)
        self.motion.invalidate()
        if reaction is Reaction.FAULT:
            self.comm.emcy(group.stage.fault_code, self.error_register())
            self.comm.event_tpdos(self.clock.now())
        elif reaction is Reaction.RESET:
            self.comm.emcy(EMCY_NO_ERROR, 0)  # error reset

    def _on_controlword(self, group: AxisGroup, value: int) -> None:
        stage = group.stage
        if stage.idle(value):
            return  # the same word again, nothing changed since: a master writing it each cycle
        self.advance(self.clock.now())
        reaction = stage.write_controlword(value)
        if reaction is not _NO_REACTION:
            self.follow(group, reaction)

    def _on_mode(self, group: AxisGroup, value: int) -> None:
        if value not in self.supported_modes and value != 0:
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

    def error_register(self) -> int:
        """1001h, from the power stages' faults."""
        reg = 0
        for stage in self.stages:
            if stage.fault_code:
                reg |= ERROR_REGISTER_GENERIC | _ERROR_REGISTER_BITS.get(stage.fault_code >> 12, 0)
        return reg

    def option(self, obj: Obj, default: int) -> int:
        """An option code (605Ah, 6007h) as the drive's first axis has it."""
        entry = self.axes[0].objs.get(obj)
        if entry is None:
            return default
        return entry.decode(self.node.get_data(entry.index, entry.subindex))

    def quick_stop_option(self) -> int:
        return self.option(Obj.QUICK_STOP_OPTION, DEFAULT_QUICK_STOP_OPTION)


def _per_axis(value: float | Sequence[float], n: int) -> list[float]:
    return list(value) if isinstance(value, Sequence) else [float(value)] * n
