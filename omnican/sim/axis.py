"""Axis motion of a simulated drive: what each motor does with the objects it reads.

Per axis: the mode of operation picks the target object and the ramps (vl: 6042h with
the 6048h/6049h/604Ah records; pv: 60FFh with 6083h/6084h; csv: 60FFh, no ramp), the
power stage's state and the halt bit pick what is applied (the target, a stop on a
ramp, or a coast), and :mod:`omnican.sim.motor` integrates it exactly over any time
step. Out come the counters (6064h, which wraps like an encoder and restarts at a
reboot; 606Ch, 6043h, 6044h) and the mode-specific statusword bits (10-13).

An axis can be held still (jammed: its drive's demand goes on, the wheel does not),
turned from outside at a speed (pushed), or lifted off the ground (it turns, but its
ground travel, what moves the simulated base, stops).

Motion advances lazily, when something reads or changes it (a SYNC, an SDO, a
public call), so its commands are cached per axis until an object that shapes them
is written or a stage changes state (:meth:`Motion.invalidate`).

No I/O: it reads the drive's object dictionary through the store and getter it is
given.
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from canopen import objectdictionary as od

from omnican.protocol import cia402
from omnican.protocol.cia402 import Mode, State
from omnican.protocol.object_map import AxisObjects, Entry, Obj
from omnican.sim import motor
from omnican.sim.pdo import Getter, read_uint
from omnican.sim.stage import PowerStage

COAST_TAU_S = 0.1  # a disabled motor spins down with this time constant
DEFAULT_TAU_S = 0.01  # velocity loop lag of an enabled motor
STANDSTILL_UNITS = 1.0  # below this many velocity units the drive reports speed zero
VELOCITY_WINDOW = 0x606D  # pv: |actual - target| within this many units is "target reached"

# What an axis applies: (target counts/s, accel, decel (counts/s^2, inf: no ramp), tau s).
Command = tuple[float, float, float, float]
# What only changes when the drive is configured, not with each cycle's target:
# (mode, quick stop decel, accel, decel in counts/s^2, max profile velocity, target entry).
Params = tuple[int, float, float, float, int, Entry | None]
Key = tuple[int, int]
Store = dict[int, dict[int, bytes]]

_VELOCITY_MODES = (Mode.VELOCITY, Mode.PROFILE_VELOCITY, Mode.CYCLIC_SYNC_VELOCITY)
# Plain names for what every statusword and command reads: an Enum member read as a class
# attribute (State.X) is a descriptor call on Python 3.11, several times a plain name's cost.
_ENABLED, _QUICK_STOP = State.OPERATION_ENABLED, State.QUICK_STOP_ACTIVE
_STOPPING = (State.QUICK_STOP_ACTIVE, State.FAULT_REACTION_ACTIVE)
_PV, _CSV = int(Mode.PROFILE_VELOCITY), int(Mode.CYCLIC_SYNC_VELOCITY)
_TARGETS = (Obj.TARGET_VELOCITY, Obj.VL_TARGET)
_SHAPING = (*_TARGETS, Obj.PROFILE_ACCEL, Obj.PROFILE_DECEL, Obj.QUICK_STOP_DECEL,
            Obj.MAX_PROFILE_VELOCITY)
_SHAPING_RECORDS = (Obj.VL_ACCEL, Obj.VL_DECEL, Obj.VL_QUICK_STOP)


def supported_modes(dictionary: od.ObjectDictionary) -> frozenset[int]:
    """Modes of operation the drive runs: its 6502h, else the velocity modes whose
    objects it has (within the range 6060h allows)."""
    obj = dictionary.get(int(Obj.SUPPORTED_MODES))
    if isinstance(obj, od.ODVariable) and obj.default is not None:
        return cia402.supported_modes(int(obj.default))
    modes = set()
    if int(Obj.TARGET_VELOCITY) in dictionary:
        modes |= {3, 9}
    if int(Obj.VL_TARGET) in dictionary:
        modes.add(2)
    mode_obj = dictionary.get(int(Obj.MODE))
    if isinstance(mode_obj, od.ODVariable) and mode_obj.max is not None:
        lo = mode_obj.min if mode_obj.min is not None else -128
        modes = {m for m in modes if lo <= m <= mode_obj.max}
    return frozenset(modes)


@dataclass(eq=False)
class AxisGroup:
    """The axes one controlword commands: one on most drives, all of them on a drive
    that holds its axes as sub-indices (ZLAC8015D). One power stage, one mode."""

    stage: PowerStage
    controlword: Entry
    statusword: Entry
    mode_entry: Entry | None  # 6060h; None: the drive runs profile velocity only
    axes: list[Axis] = field(default_factory=list)
    mode: int | None = None  # 6060h as last written; None: read it from the dictionary


@dataclass(eq=False)
class Axis:
    """One motor of the drive."""

    number: int
    objs: AxisObjects
    group: AxisGroup
    counts_per_unit: float  # encoder counts/s per unit of the velocity objects
    state: motor.MotorState = field(default_factory=motor.MotorState)
    counter_offset: float = 0.0  # physical counts at the last encoder reset
    internal_limit: bool = False  # the target is beyond the max profile velocity
    target_units: float = 0.0  # the target applied, velocity units
    command: Command | None = None  # cached; None: recompute
    params: Params | None = None  # cached; None: recompute
    # Injected conditions (see SimulatedDrive.jam, lift, push): a jammed wheel stands
    # still whatever its drive does; a wheel off the ground turns without moving the
    # base; a pushed one turns at the speed it is pushed at.
    jammed: bool = False
    grounded: bool = True
    pushed_counts_s: float | None = None
    ground_position: float = 0.0  # counts rolled on the ground: what moved the base


def group_axes(dictionary: od.ObjectDictionary, counts_per_unit: Sequence[float],
               initial_position: Sequence[float], new_stage: Callable[[], PowerStage],
               name: str) -> tuple[list[AxisGroup], list[Axis]]:
    """The axes of a drive (EDS ``name``), grouped by the controlword that commands
    them; each group gets a power stage from ``new_stage``."""
    groups: dict[Key, AxisGroup] = {}
    axes: list[Axis] = []
    for k, (cpu, init) in enumerate(zip(counts_per_unit, initial_position, strict=True)):
        objs = AxisObjects(dictionary, k)
        cw, sw = objs.get(Obj.CONTROLWORD), objs.get(Obj.STATUSWORD)
        if cw is None or sw is None:
            raise ValueError(f"{name}: axis {k} has no controlword/statusword")
        key = (cw.index, cw.subindex)
        if key not in groups:
            groups[key] = AxisGroup(new_stage(), cw, sw, objs.get(Obj.MODE))
        ax = Axis(k, objs, groups[key], cpu, counter_offset=-init)
        groups[key].axes.append(ax)
        axes.append(ax)
    return list(groups.values()), axes


class Motion:
    """The motors of one drive, advanced together in time.

    Args:
        dictionary: the drive's object dictionary.
        groups: the drive's axis groups (their axes are the ones moved).
        store: the object dictionary's written values (``LocalNode.data_store``).
        get_data: reads an object as an SDO upload would (written value or default).
        tau_s: velocity lag time constant of an enabled motor.
        encoder_noise: standard deviation (counts) added to reported positions.
        rng: source of the noise (shared with the drive's frame loss, one seed).
        initial_position: encoder counts at power-up, per axis.
        start: the time the motion starts at (s, on the drive's clock).
    """

    def __init__(self, dictionary: od.ObjectDictionary, groups: Sequence[AxisGroup],
                 store: Store, get_data: Getter, *,
                 tau_s: float, encoder_noise: float, rng: random.Random,
                 initial_position: Sequence[float], start: float) -> None:
        self.groups = list(groups)
        self.axes = sorted((ax for g in self.groups for ax in g.axes), key=lambda a: a.number)
        self._dictionary = dictionary
        self._store = store
        self._get = get_data
        self.tau_s = tau_s
        self.encoder_noise = encoder_noise
        self._rng = rng
        self._initial_position = list(initial_position)
        self.last_advance = start
        self.window = 1.0  # 606Dh, velocity units
        #: counts every change of what the statusword's motion bits and the mode are made
        #: of (a velocity, a command, the window, a mode dropped): unchanged, they are too
        #: (the event TPDOs' check, :meth:`omnican.sim.device.Device.event_stamp`)
        self.changes = 0
        self._shaping, self._targets = self._shaping_objects()

    # ------------------------------------------------------------ objects

    def readers(self) -> dict[Key, Callable[[], int]]:
        """The objects the motion produces (counters, velocities), as raw values."""
        out: dict[Key, Callable[[], int]] = {}
        for ax in self.axes:
            for obj, quantity in ((Obj.POSITION_ACTUAL, "position"),
                                  (Obj.VELOCITY_ACTUAL, "velocity"),
                                  (Obj.VL_ACTUAL, "velocity"), (Obj.VL_DEMAND, "demand")):
                entry = ax.objs.get(obj)
                if entry is not None:
                    out[(entry.index, entry.subindex)] = self._reader(ax, quantity, entry)
        return out

    def _reader(self, ax: Axis, quantity: str, entry: Entry) -> Callable[[], int]:
        """6064h (counts since the last encoder reset, with the encoder's noise), 606Ch or
        6044h (:meth:`velocity`) or 6043h (the ramp's output, velocity units) as the
        object's raw integer: wrapped to its width like an encoder counter, two's
        complement for an unsigned type. One closure each (TPDOs read them every SYNC)."""
        half, full = 1 << (entry.bits - 1), 1 << entry.bits
        signed = entry.declared_signed

        if quantity == "position":
            def read() -> int:
                counts = ax.state.position - ax.counter_offset
                if self.encoder_noise:
                    counts += self._rng.gauss(0.0, self.encoder_noise)
                value = (round(counts) + half) % full - half
                return value if signed else value % full
        elif quantity == "velocity":
            def read() -> int:
                value = (round(ax.state.velocity / ax.counts_per_unit) + half) % full - half
                return value if signed else value % full
        else:
            def read() -> int:
                value = (round(ax.state.demand / ax.counts_per_unit) + half) % full - half
                return value if signed else value % full
        return read

    def _shaping_objects(self) -> tuple[set[Key], dict[Key, Axis]]:
        """(every object that shapes the motion, the target objects and their axis)."""
        shaping: set[Key] = set()
        targets: dict[Key, Axis] = {}
        for ax in self.axes:
            for obj in _SHAPING:
                entry = ax.objs.get(obj)
                if entry is not None:
                    shaping.add((entry.index, entry.subindex))
                    if obj in _TARGETS:
                        targets[(entry.index, entry.subindex)] = ax
            for rec in _SHAPING_RECORDS:
                index = ax.objs.record(rec)
                if index is not None:
                    shaping.update({(index, 1), (index, 2)})
        return shaping, targets

    def shapes(self, key: Key) -> bool:
        """The object shapes the motion: a new value applies from the moment it is
        written (advance to that moment first)."""
        return key in self._shaping

    def written(self, index: int, subindex: int) -> None:
        """An object took a new value: a new target drops only its axis's command (the
        parameters still hold); anything else may change them all."""
        target_of = self._targets.get((index, subindex))
        if target_of is not None:
            target_of.command = None
            self.changes += 1
        else:
            self.invalidate()
        if index == VELOCITY_WINDOW:
            self.load_window()

    def load_window(self) -> None:
        """Take the velocity window (606Dh, at least one unit) from the dictionary."""
        window = 1.0
        if isinstance(self._dictionary.get(VELOCITY_WINDOW), od.ODVariable):
            raw = read_uint(self._get, VELOCITY_WINDOW, 0, "<I", 1)
            window = max(window, float(raw & 0xFFFF))
        self.window = window
        self.changes += 1

    def mode(self, group: AxisGroup) -> int:
        """The group's mode of operation (6060h)."""
        entry = group.mode_entry
        if entry is None:
            return int(Mode.PROFILE_VELOCITY)
        if group.mode is None:
            group.mode = entry.decode(self._get(entry.index, entry.subindex))
        return group.mode

    # ------------------------------------------------------------ events

    def invalidate(self) -> None:
        """Something that shapes the motion changed: recompute the commands lazily."""
        for ax in self.axes:
            ax.command = None
            ax.params = None
        self.changes += 1

    def restart_ramps(self, group: AxisGroup) -> None:
        """Operation enabled: the ramps start from where the wheels are, not from an
        old demand."""
        for ax in group.axes:
            ax.state = motor.MotorState(ax.state.position, ax.state.velocity, ax.state.velocity)
        self.changes += 1

    def power_up(self) -> None:
        """A reboot: the counters restart at their power-up value (the wheels coast on),
        the modes are read from the dictionary again."""
        for ax in self.axes:
            ax.counter_offset = ax.state.position - self._initial_position[ax.number]
            ax.internal_limit = False
        for group in self.groups:
            group.mode = None
        self.changes += 1

    def advance(self, now: float) -> bool:
        """Move every motor on to ``now``; False when no time passed."""
        dt = now - self.last_advance
        if dt <= 0:
            return False
        self.last_advance = now
        for ax in self.axes:
            if ax.command is None:
                ax.command = self._command(ax)
            target, accel, decel, tau = ax.command
            old = ax.state
            new = motor.advance(old, dt, target, accel, decel, tau)
            if ax.jammed:  # the drive's demand goes on; the wheel does not
                new = motor.MotorState(old.position, 0.0, new.demand)
            elif ax.pushed_counts_s is not None:
                pushed = ax.pushed_counts_s
                new = motor.MotorState(old.position + pushed * dt, pushed, new.demand)
            if ax.grounded:
                ax.ground_position += new.position - old.position
            if new.velocity != old.velocity:
                self.changes += 1
            ax.state = new
        return True

    # ------------------------------------------------------------ what it shows

    def velocity(self, ax: Axis) -> int:
        """606Ch / 6044h, velocity units."""
        return round(ax.state.velocity / ax.counts_per_unit)

    def standstill(self, group: AxisGroup) -> bool:
        """Every axis below one velocity unit: the drive's "speed = 0"."""
        for ax in group.axes:
            if not abs(ax.state.velocity / ax.counts_per_unit) < STANDSTILL_UNITS:
                return False
        return True

    def status_bits(self, group: AxisGroup) -> int:
        """The mode-specific statusword bits: internal limit (11), target reached (10),
        pv "speed is zero" and csv "following the command value" (12)."""
        # Read with every event check and SYNC: loops, not generators.
        axes = group.axes
        sw = 0
        for ax in axes:
            if ax.internal_limit:
                sw = cia402.SW_INTERNAL_LIMIT
                break
        stage = group.stage
        state = stage.state
        if state is _ENABLED:
            mode = self.mode(group)
            if mode == _CSV:
                sw |= cia402.SW_OMS_12
            else:  # target reached, and pv's speed zero, in one pass over the axes
                halted = stage.controlword & cia402.CW_HALT
                window = self.window
                reached = still = True
                for ax in axes:
                    if ax.command is None:
                        ax.command = self._command(ax)  # refreshes target_units
                    units = ax.state.velocity / ax.counts_per_unit
                    if abs(units - (0.0 if halted else ax.target_units)) > window:
                        reached = False
                    if not abs(units) < STANDSTILL_UNITS:
                        still = False
                if reached:
                    sw |= cia402.SW_TARGET_REACHED
                if still and mode == _PV:
                    sw |= cia402.SW_OMS_12
        elif state is _QUICK_STOP and self.standstill(group):
            sw |= cia402.SW_TARGET_REACHED
        return sw

    # ------------------------------------------------------------ commands

    def _raw(self, entry: Entry | None, default: int = 0) -> int:
        if entry is None:
            return default
        data = self._store.get(entry.index, {}).get(entry.subindex)
        if data is None:  # never written: the EDS default
            data = self._get(entry.index, entry.subindex)
        return entry.decode(data)

    def _record_rate(self, index: int | None) -> float | None:
        """vl ramp (delta speed / delta time in s) in units/s^2, or None."""
        if index is None:
            return None
        speed = read_uint(self._get, index, 1, "<I")
        seconds = read_uint(self._get, index, 2, "<H")
        if speed == 0 or seconds == 0:
            return None
        return speed / seconds

    def _params(self, ax: Axis) -> Params:
        inf = math.inf
        cpu = abs(ax.counts_per_unit)
        quick = self._raw(ax.objs.get(Obj.QUICK_STOP_DECEL)) * cpu
        mode = self.mode(ax.group)
        target: Entry | None = None
        accel_c = decel_c = inf
        if mode == Mode.VELOCITY:
            vl_quick = self._record_rate(ax.objs.record(Obj.VL_QUICK_STOP))
            quick = vl_quick * cpu if vl_quick else quick
            target = ax.objs.get(Obj.VL_TARGET)
            accel = self._record_rate(ax.objs.record(Obj.VL_ACCEL))
            decel = self._record_rate(ax.objs.record(Obj.VL_DECEL))
            accel_c = accel * cpu if accel else inf
            decel_c = decel * cpu if decel else inf
        elif mode in (Mode.PROFILE_VELOCITY, Mode.CYCLIC_SYNC_VELOCITY):
            target = ax.objs.get(Obj.TARGET_VELOCITY)
            if mode == Mode.PROFILE_VELOCITY:
                accel_c = self._raw(ax.objs.get(Obj.PROFILE_ACCEL)) * cpu or inf
                decel_c = self._raw(ax.objs.get(Obj.PROFILE_DECEL)) * cpu or accel_c
        quick = quick if quick > 0 else inf
        limit = self._raw(ax.objs.get(Obj.MAX_PROFILE_VELOCITY))
        return mode, quick, accel_c, decel_c, limit, target

    def _command(self, ax: Axis) -> Command:
        """What the axis applies in its stage's present state."""
        self.changes += 1  # target_units and internal_limit are set anew
        params = ax.params
        if params is None:
            params = ax.params = self._params(ax)
        mode, quick, accel_c, decel_c, limit, target_entry = params
        stage = ax.group.stage
        state = stage.state
        if state in _STOPPING:
            ax.target_units = 0.0
            return 0.0, quick, quick, self.tau_s
        if state is not _ENABLED:
            ax.target_units = 0.0
            return 0.0, math.inf, math.inf, COAST_TAU_S
        if mode not in _VELOCITY_MODES or not stage.running:
            ax.target_units = 0.0
            return 0.0, quick, quick, self.tau_s  # no velocity mode (or not started): still
        target = self._raw(target_entry)
        ax.internal_limit = bool(limit) and abs(target) > limit
        if ax.internal_limit:
            target = int(math.copysign(limit, target))
        ax.target_units = float(target)
        if stage.halted and mode != _CSV:
            return 0.0, decel_c, decel_c, self.tau_s
        return target * ax.counts_per_unit, accel_c, decel_c, self.tau_s
