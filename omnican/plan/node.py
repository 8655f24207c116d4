"""What each node of a config looks like on the wire, worked out offline from its EDS:
its mode, the objects of each wheel, its CiA 402 state machines and its PDO plan.

Used by the drive layer to configure the nodes, and by the tools that need the same
picture without a bus (check-config, monitor, plot, calibrate).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, replace

from canopen import objectdictionary as od

from omnican.config import ChassisConfig, ChassisSettings, EstopSettings, WheelConfig
from omnican.errors import ConfigError
from omnican.plan.health import estop_entry, node_reads, plan_health
from omnican.plan.pdo import NodePlan, frame_bits, pdo_slots, plan_node
from omnican.plan.vendor import overwrite_problem, vendor_writes
from omnican.protocol import cia402, eds_check
from omnican.protocol.cia301 import (
    CONSUMER_HEARTBEAT_TIME,
    MAX_PDOS,
    PDO_COB_ID,
    PRODUCER_HEARTBEAT_TIME,
    RPDO_COMM,
    TPDO_COMM,
    TPDO_MAP,
)
from omnican.protocol.cia402 import Mode
from omnican.protocol.object_map import (
    AxisObjects,
    Entry,
    Obj,
    declared_types,
    load_dictionary,
    obj_name,
    variable_at,
)

#: A position counter must not move half its span in this many control cycles (so
#: samples lost on the way still leave a wrap told from a step back).
COUNTER_CYCLES = 4


@dataclass(frozen=True)
class StageLayout:
    """One CiA 402 state machine: the objects of one controlword/statusword pair."""

    controlword: Entry
    statusword: Entry
    mode: Entry | None
    mode_display: Entry | None
    error_code: Entry | None


@dataclass(frozen=True)
class AxisLayout:
    """One wheel: an axis of the node."""

    wheel_index: int
    wheel: WheelConfig
    objs: AxisObjects
    target: Entry
    position: Entry
    stage: int  # index into NodeLayout.stages


class NodeLayout:
    """One node of the base and the wheels (axes) it drives."""

    def __init__(self, node_id: int, wheels: list[tuple[int, WheelConfig]],
                 settings: ChassisSettings, estop: EstopSettings | None = None) -> None:
        self.node_id = node_id
        self.settings = settings
        eds = wheels[0][1].eds
        if any(w.eds != eds for _, w in wheels):
            raise ConfigError(f"node {node_id}: its wheels name different EDS files")
        self.eds = eds
        self.dictionary = load_dictionary(eds, node_id)
        self.mode = self._choose_mode(wheels)
        self.stages: list[StageLayout] = []
        self.axes: list[AxisLayout] = []
        by_cw: dict[tuple[int, int], int] = {}
        for wheel_index, wheel in wheels:
            objs = AxisObjects(self.dictionary, wheel.axis)
            cw, sw = objs[Obj.CONTROLWORD], objs[Obj.STATUSWORD]
            key = (cw.index, cw.subindex)
            if key not in by_cw:
                by_cw[key] = len(self.stages)
                self.stages.append(StageLayout(cw, sw, objs.get(Obj.MODE),
                                               objs.get(Obj.MODE_DISPLAY),
                                               objs.get(Obj.ERROR_CODE)))
            target = objs[Obj.VL_TARGET if self.mode is Mode.VELOCITY else Obj.TARGET_VELOCITY]
            self.axes.append(AxisLayout(wheel_index, wheel, objs, target,
                                        objs[Obj.POSITION_ACTUAL], by_cw[key]))
        self.has_consumer = isinstance(self.dictionary.get(CONSUMER_HEARTBEAT_TIME),
                                       (od.ODArray, od.ODRecord))
        problems = self._object_problems()
        problems += self._loop_problems(any(w.mode is not None for _, w in wheels))
        if problems:
            raise ConfigError(f"node {node_id}: EDS {eds}: {eds_check.one_line(problems)}")
        plan = self._plan()
        try:
            reads = node_reads(self.dictionary, node_id, wheels, estop)
        except ConfigError as exc:
            raise ConfigError(f"node {node_id}: EDS {eds.name}: {exc}") from None
        spare = [s for s in pdo_slots(self.dictionary, node_id, tx=True)
                 if s.number in plan.unused_tpdos]
        #: what the drive reports of its health, and how it is read (omnican.plan.health)
        self.health = plan_health(node_id, self.dictionary, reads, spare, settings.rate_hz,
                                  settings.health_rate_hz)
        used = {p.number for p in self.health.pdos}
        self.plan = replace(plan, unused_tpdos=tuple(n for n in plan.unused_tpdos
                                                     if n not in used))
        self.estop = estop if estop is not None and estop.node_id in (None, node_id) else None
        #: the e-stop's object on this node (None: not here, or a default object it lacks)
        self.estop_entry = (estop_entry(self.dictionary, self.estop, wheels[0][1].axis)
                            if self.estop is not None else None)
        #: [[wheel.sdo]] of its wheels, resolved and checked against the EDS
        try:
            self.sdo_writes = vendor_writes(self.dictionary, wheels)
        except ConfigError as exc:
            raise ConfigError(f"node {node_id}: EDS {eds.name}: {exc}") from None
        overwrite = overwrite_problem(self.sdo_writes, self.configured_by_omnican)
        if overwrite is not None:
            raise ConfigError(f"node {node_id}: {overwrite}")

    def configured_by_omnican(self, index: int, subindex: int) -> str | None:
        """What omnican sets ``index:subindex`` for at each configuration (None: it does
        not): PDO parameters, heartbeats, each axis's mode, ramps, abort option and cyclic
        objects."""
        if RPDO_COMM <= index < TPDO_MAP + MAX_PDOS:
            return "the PDO configuration"
        if (index, subindex) == (PRODUCER_HEARTBEAT_TIME, 0):
            return "the heartbeat producer, chassis.heartbeat_ms"
        if (index, subindex) == (CONSUMER_HEARTBEAT_TIME, 1) and self.has_consumer:
            return "the heartbeat consumer watching the host"
        for ax in self.axes:
            stage = self.stages[ax.stage]
            named = [(ax.target, "the wheel's target"), (stage.controlword, "the controlword"),
                     (stage.mode, "the mode of operation")]
            objs = ax.objs
            if self.has_consumer:
                named.append((objs.get(Obj.ABORT_OPTION), "what a lost host stops with"))
            if self.mode is not Mode.VELOCITY:
                for obj in (Obj.PROFILE_ACCEL, Obj.PROFILE_DECEL, Obj.QUICK_STOP_DECEL):
                    named.append((objs.get(obj), f"{obj_name(obj)}, from the chassis limits"))
            for entry, why in named:
                if entry is not None and (entry.index, entry.subindex) == (index, subindex):
                    return why
            for rec in (Obj.VL_ACCEL, Obj.VL_DECEL):
                if objs.record(rec) == index and self.mode is Mode.VELOCITY:
                    return f"{obj_name(rec)}, from the chassis limits"
        return None

    def _object_problems(self) -> list[str]:
        """The CiA 402 objects the drive layer will map, write or read, each an integer
        of a type omnican can encode (the node-wide objects were checked on loading)."""
        declared = declared_types(self.eds)
        # (index, sub): name, bits (a fixed width), min_bits (at least)
        used: dict[tuple[int, int], tuple[str, int | None, int | None]] = {}
        for ax in self.axes:
            objs = ax.objs
            ramps = ((Obj.PROFILE_ACCEL, Obj.PROFILE_DECEL, Obj.QUICK_STOP_DECEL)
                     if self.mode is not Mode.VELOCITY else ())
            optional = (Obj.MODE, Obj.MODE_DISPLAY, Obj.ERROR_CODE, Obj.ABORT_OPTION, *ramps)
            for word in (objs[Obj.CONTROLWORD], objs[Obj.STATUSWORD]):  # bits up to 15
                used.setdefault((word.index, word.subindex), (word.name, None, 16))
            for entry in (ax.target, ax.position,
                          *(e for e in map(objs.get, optional) if e is not None)):
                used.setdefault((entry.index, entry.subindex), (entry.name, None, None))
            if self.mode is Mode.VELOCITY:  # delta speed written as 32 bits, delta time as 16
                for rec in (Obj.VL_ACCEL, Obj.VL_DECEL):
                    index = objs.record(rec)
                    if index is not None:
                        for sub, width in ((1, 32), (2, 16)):
                            used[(index, sub)] = (f"{obj_name(rec)} sub {sub}", width, None)
        problems = []
        for (index, sub), (name, bits, min_bits) in used.items():
            var = variable_at(self.dictionary, index, sub)
            if var is None:
                problems.append(f"0x{index:04X} {name} has no sub-index {sub}")
                continue
            problem = eds_check.variable_problem(var, name, declared, bits, min_bits)
            if problem:
                problems.append(problem)
        return problems

    def _loop_problems(self, mode_configured: bool) -> list[str]:
        """What the control loop needs of the objects it uses, beyond their types: wide
        enough for the configured speed and travel, the access it uses them with, the
        chosen mode among the supported ones (6502h, where the EDS gives its value)."""
        s = self.settings
        problems: list[str] = []

        def add(problem: str | None) -> None:
            if problem is not None and problem not in problems:
                problems.append(problem)

        def access(entry: Entry | None, write: bool, why: str) -> None:
            var = None if entry is None else variable_at(self.dictionary, entry.index,
                                                         entry.subindex)
            if entry is not None and var is not None:
                add(eds_check.access_problem(var, f"{entry.address} {entry.name}", write, why))

        velocity = {int(m): m.short for m in Mode}
        for ax in self.axes:
            w, i = ax.wheel, ax.wheel_index
            top = f"wheel {i} at max_wheel_speed {s.max_wheel_speed:g} m/s"
            add(eds_check.width_problem(
                f"{ax.target.address} {ax.target.name}", ax.target.bits, ax.target.signed,
                s.max_wheel_speed * abs(w.velocity_scale),
                f"{top} x velocity_scale {w.velocity_scale:g}"))
            add(eds_check.counter_problem(
                f"{ax.position.address} {ax.position.name}", ax.position.bits,
                s.max_wheel_speed * abs(w.position_scale) / s.rate_hz, COUNTER_CYCLES,
                f"{top} x position_scale {w.position_scale:g} at rate_hz {s.rate_hz:g}"))
            stage = self.stages[ax.stage]
            access(ax.target, True, "the wheel's target, every cycle")
            access(ax.position, False, "the wheel's travel, every cycle")
            access(stage.controlword, True, "the controlword")
            access(stage.statusword, False, "the statusword")
            access(stage.mode, True, f"the mode of operation, {self.mode.short}")
            access(stage.mode_display, False, "to confirm the mode")
            supported = ax.objs.get(Obj.SUPPORTED_MODES)
            var = None if supported is None else variable_at(self.dictionary, supported.index,
                                                             supported.subindex)
            if supported is not None and var is not None and isinstance(var.default, int):
                add(eds_check.modes_problem(
                    f"{supported.address} {supported.name} (0x{var.default:X})",
                    cia402.supported_modes(var.default), int(self.mode), self.mode.short,
                    velocity, mode_configured))
        for index, sub, why in ((PRODUCER_HEARTBEAT_TIME, 0, "the drive's heartbeat"),
                                *([(CONSUMER_HEARTBEAT_TIME, 1, "to watch the host's "
                                    "heartbeat")] if self.has_consumer else []),
                                *((base + n, PDO_COB_ID, "it enables or disables each PDO")
                                  for base in (RPDO_COMM, TPDO_COMM) for n in range(MAX_PDOS))):
            var = variable_at(self.dictionary, index, sub)
            if var is not None:
                add(eds_check.access_problem(var, f"0x{index:04X}:{sub:02X} {var.name}", True, why))
        return problems

    def _choose_mode(self, wheels: list[tuple[int, WheelConfig]]) -> Mode:
        """The configured mode, else the first of pv, csv, vl that 6502h offers, else pv."""
        modes = {w.mode for _, w in wheels if w.mode is not None}
        if len(modes) > 1:
            raise ConfigError(f"node {self.node_id}: its wheels ask for different modes")
        if modes:
            return modes.pop()
        supported = self.dictionary.get(int(Obj.SUPPORTED_MODES))
        if isinstance(supported, od.ODVariable) and isinstance(supported.default, int):
            offered = cia402.supported_modes(supported.default)
            for mode in (Mode.PROFILE_VELOCITY, Mode.CYCLIC_SYNC_VELOCITY, Mode.VELOCITY):
                if int(mode) in offered:
                    return mode
        return Mode.PROFILE_VELOCITY

    def _plan(self, mapping: str | None = None) -> NodePlan:
        optional = [e for s in self.stages for e in (s.mode_display, s.error_code) if e]
        return plan_node(
            self.node_id,
            self.dictionary,
            cyclic_rx=[a.target for a in self.axes],
            event_rx=[s.controlword for s in self.stages],
            cyclic_tx=[a.position for a in self.axes],
            event_tx=[s.statusword for s in self.stages],
            optional_tx=optional,
            inhibit_ms=2.0,
            event_timer_ms=max(50, self.settings.heartbeat_ms),
            mapping=mapping or self.settings.pdo_mapping,
            event_rx_every_cycle=self.settings.cyclic_controlword,
        )

    @property
    def refused_plan(self) -> NodePlan | None:
        """If the plan maps objects the EDS marks not PDO-mappable: the bus the drive needs
        in the worst case, when it refuses them and its own mapping lacks them too (they go
        by SDO every cycle). None when nothing is tried."""
        return self._plan("eds") if self.plan.tried else None


def node_layouts(cfg: ChassisConfig) -> list[NodeLayout]:
    """One layout per node of ``cfg``, in order of first appearance."""
    return [NodeLayout(node_id, [(cfg.wheels.index(w), w) for w in wheels], cfg.chassis,
                       cfg.estop)
            for node_id, wheels in cfg.nodes().items()]


def cycle_bits(plans: Iterable[NodePlan]) -> int:
    """Worst-case bits per control cycle: every node's cyclic PDOs plus the SYNC."""
    return sum(plan.cyclic_bits() for plan in plans) + frame_bits(0)


def max_rate_hz(bits_per_cycle: int, other_bits_per_s: float, bitrate: float,
                max_load: float) -> float:
    """Highest control rate at which ``bits_per_cycle`` plus ``other_bits_per_s``
    (heartbeats) stay within ``max_load`` (a fraction) of ``bitrate``."""
    room = max_load * bitrate - other_bits_per_s
    return max(0.0, room / bits_per_cycle)


def heartbeat_bits_per_s(cfg: ChassisConfig) -> float:
    """Heartbeats of the host and every node, worst-case bits per second."""
    return (len(cfg.nodes()) + 1) * frame_bits(1) / (cfg.chassis.heartbeat_ms / 1000.0)
