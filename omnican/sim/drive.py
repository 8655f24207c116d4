"""A simulated CiA 402 wheel drive on a canopen network.

Built on :class:`canopen.LocalNode` (object dictionary from an EDS, SDO server,
EMCY producer) and adding what it lacks for a drive: NMT with boot-up
frames and resets, PDOs as the master configured them, the CiA 402 state machine,
a motor model per axis, heartbeat producer and consumer, and fault injection.

Multi-axis drives work in both layouts omnican supports (see :mod:`omnican.odmap`):
axes at 0x800 offsets have a state machine each; sub-indexed axes share one.

Threads: frames are handled on the network's Notifier thread; a
:class:`SimScheduler` tick covers time-driven work. One lock per drive.
"""

from __future__ import annotations

import logging
import math
import random
import struct
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import can
import canopen
from canopen import objectdictionary as od
from canopen.objectdictionary import SIGNED_TYPES
from canopen.sdo.exceptions import SdoAbortedError

from omnican import cia402
from omnican.cia301 import (
    COB_ID_MASK,
    COMMUNICATION_PROFILE,
    CONSUMER_HEARTBEAT_TIME,
    DEVICE_TYPE,
    EMCY_BASE,
    EMCY_HEARTBEAT,
    EMCY_NO_ERROR,
    EMCY_PDO_LENGTH,
    ERROR_REGISTER,
    ERROR_REGISTER_COMMUNICATION,
    ERROR_REGISTER_CURRENT,
    ERROR_REGISTER_GENERIC,
    ERROR_REGISTER_TEMPERATURE,
    ERROR_REGISTER_VOLTAGE,
    HEARTBEAT_BASE,
    IDENTITY,
    MAX_NODE_ID,
    MAX_PDOS,
    NMT_COB_ID,
    NMT_STATE_NAMES,
    PRODUCER_HEARTBEAT_TIME,
    RPDO_COMM,
    RPDO_MAP,
    SDO_ABORT_READ_ONLY,
    SDO_ABORT_VALUE_RANGE,
    SYNC_COB_ID,
    SYNC_COB_ID_OBJECT,
    TPDO_COMM,
    TPDO_MAP,
    NmtCommand,
    NmtState,
)
from omnican.cia402 import Mode, State
from omnican.clock import REAL_TIME, Clock
from omnican.config import WHEEL_EDS
from omnican.odmap import AxisObjects, Entry, Obj
from omnican.sim import motor
from omnican.sim.pdo import (
    MappedObject,
    PdoConfig,
    check_mapping_write,
    read_pdos,
)
from omnican.sim.scheduler import SimScheduler

logger = logging.getLogger(__name__)

# Error register (1001h) bits by EMCY class.
_ERROR_REGISTER_BITS = {0x2: ERROR_REGISTER_CURRENT, 0x3: ERROR_REGISTER_VOLTAGE,
                        0x4: ERROR_REGISTER_TEMPERATURE, 0x8: ERROR_REGISTER_COMMUNICATION}

_STATE_BITS: dict[State, int] = {s: cia402.state_bits(s) for s in State if s is not State.UNKNOWN}

SEND_WARNING_EVERY_S = 5.0  # a refused send is logged at most this often
COAST_TAU_S = 0.1  # a disabled motor spins down with this time constant
DEFAULT_TAU_S = 0.01  # velocity loop lag of an enabled motor
STANDSTILL_UNITS = 1.0  # below this many velocity units the drive reports speed zero


def _default_modes(d: od.ObjectDictionary) -> frozenset[int]:
    modes = set()
    if int(Obj.TARGET_VELOCITY) in d:
        modes |= {3, 9}
    if int(Obj.VL_TARGET) in d:
        modes.add(2)
    mode_obj = d.get(int(Obj.MODE))
    if isinstance(mode_obj, od.ODVariable) and mode_obj.max is not None:
        lo = mode_obj.min if mode_obj.min is not None else -128
        modes = {m for m in modes if lo <= m <= mode_obj.max}
    return frozenset(modes)


@dataclass
class _Axis:
    """One motor of the drive."""

    number: int
    objs: AxisObjects
    stage: _PowerStage
    counts_per_unit: float
    state: motor.MotorState = field(default_factory=motor.MotorState)
    counter_offset: float = 0.0  # physical counts at the last encoder reset
    internal_limit: bool = False
    target_units: float = 0.0
    command: tuple[float, float, float, float] | None = None  # cached motion command
    # Cached (mode, quick stop, accel, decel in counts/s^2, limit, target entry): what
    # only changes when the drive is configured, not with each cycle's target.
    params: tuple[int, float, float, float, int, Entry | None] | None = None


@dataclass
class _PowerStage:
    """A CiA 402 device state machine (one per controlword)."""

    controlword: Entry
    statusword: Entry
    mode: Entry | None
    axes: list[_Axis] = field(default_factory=list)
    state: State = State.SWITCH_ON_DISABLED
    last_cw: int = 0
    warning: bool = False
    fault_code: int = 0
    mode_cache: int | None = None
    fault_persists: bool = False  # its cause is still there: a fault reset does not clear it
    enable_held: bool = False  # no power for the motor (DC link off, safe torque off)


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
        self.tau_s = tau_s
        self.encoder_noise = encoder_noise
        self.slip = slip
        self.frame_loss = frame_loss
        self.max_mapping_entries = max_mapping_entries
        self.remappable = remappable
        self.accept_unmappable = accept_unmappable
        self._rng = random.Random(seed)
        self.lock = threading.RLock()

        probe = AxisObjects(self.dictionary, 0)
        self.num_axes = max(1, probe.num_axes)
        cpu = list(counts_per_unit) if isinstance(counts_per_unit, Sequence) else [
            float(counts_per_unit)] * self.num_axes
        init = list(initial_position) if isinstance(initial_position, Sequence) else [
            float(initial_position)] * self.num_axes
        if len(cpu) != self.num_axes or len(init) != self.num_axes:
            raise ValueError(f"{self.eds.name} has {self.num_axes} axes: give one value per axis")
        self._initial_position = init
        self.axes: list[_Axis] = []
        self.stages: list[_PowerStage] = []
        stage_by_cw: dict[tuple[int, int], _PowerStage] = {}
        for k in range(self.num_axes):
            objs = AxisObjects(self.dictionary, k)
            cw, sw = objs.get(Obj.CONTROLWORD), objs.get(Obj.STATUSWORD)
            if cw is None or sw is None:
                raise ValueError(f"{self.eds.name}: axis {k} has no controlword/statusword")
            key = (cw.index, cw.subindex)
            if key not in stage_by_cw:
                stage_by_cw[key] = _PowerStage(cw, sw, objs.get(Obj.MODE))
                self.stages.append(stage_by_cw[key])
            stage = stage_by_cw[key]
            ax = _Axis(k, objs, stage, cpu[k], counter_offset=-init[k])
            stage.axes.append(ax)
            self.axes.append(ax)
        self._supported_modes = self._find_supported_modes()

        # Dynamic objects: (index, subindex) -> reader.
        self._readers: dict[tuple[int, int], Callable[[], int]] = {}
        self._writers: dict[tuple[int, int], Callable[[int], None]] = {}
        self._motion_objects: set[tuple[int, int]] = set()
        self._target_objects: dict[tuple[int, int], _Axis] = {}
        self._build_object_hooks()

        self._nmt = NmtState.BOOT_UP
        self._frozen = False
        self._heartbeat_enabled = True
        self._heartbeat_period = 0.0
        self._last_heartbeat = -1e9
        self._consumers: dict[int, float] = {}  # producer node id -> timeout s
        self._consumer_seen: dict[int, float] = {}
        self._consumer_lost: set[int] = set()
        self._subscribed_hb: set[int] = set()
        self._tpdos: list[PdoConfig] = []
        self._rpdos: dict[int, PdoConfig] = {}
        self._pending: dict[int, bytes] = {}
        self._last_advance = clock.now()
        self._window = 1.0
        self._closed = False
        self._send_failures = 0
        self._send_warned_at = -math.inf

        # LocalNode produces its heartbeat from a 1017h write callback; we do it ourselves.
        self.node._write_callbacks.remove(self.node.nmt.on_write)
        self.node.add_read_callback(self._on_read)
        self.node.add_write_callback(self._on_write)
        network.add_node(self.node)
        # Replace LocalNode's NMT and SDO handlers with ones that honour freeze/NMT state.
        network.unsubscribe(NMT_COB_ID, self.node.nmt.on_command)
        network.unsubscribe(self.node.sdo.rx_cobid, self.node.sdo.on_request)
        network.subscribe(NMT_COB_ID, self._on_nmt)
        network.subscribe(self.node.sdo.rx_cobid, self._on_sdo)
        self._sync_cob = self._u32(SYNC_COB_ID_OBJECT, 0, SYNC_COB_ID) & COB_ID_MASK
        network.subscribe(self._sync_cob, self._on_sync)

        self._own_scheduler = scheduler is None
        self.scheduler = scheduler if scheduler is not None else SimScheduler(clock=clock)
        self._prefill_defaults()
        self._window = self._velocity_window()
        if boot:
            self._boot(reset_node=False)
        self.scheduler.add(self.tick)
        if self._own_scheduler:
            self.scheduler.start()

    # ------------------------------------------------------------------ setup

    def _find_supported_modes(self) -> frozenset[int]:
        obj = self.dictionary.get(int(Obj.SUPPORTED_MODES))
        if isinstance(obj, od.ODVariable) and obj.default is not None:
            return cia402.supported_modes(int(obj.default))
        return _default_modes(self.dictionary)

    def _prefill_defaults(self) -> None:
        """Give every numeric object without a default a value, as a drive would: its
        identity from the EDS's [DeviceInfo], CiA 402 as device type, else 0."""
        store = self.node.data_store
        info = self.dictionary.device_information
        known = {
            (DEVICE_TYPE, 0): 0x00020192,  # CiA 402, servo drive
            (IDENTITY, 1): info.vendor_number or 0,
            (IDENTITY, 2): info.product_number or 0,
            (IDENTITY, 3): info.revision_number or 0,
            (int(Obj.SUPPORTED_MODES), 0): cia402.modes_to_bits(set(self._supported_modes)),
        }
        for obj in self.dictionary.values():
            variables = [obj] if isinstance(obj, od.ODVariable) else list(obj.values())
            for var in variables:
                if var.value is None and var.default is None and var.data_type in od.NUMBER_TYPES:
                    value = known.get((var.index, var.subindex), 0)
                    if var.min is not None and var.min > value:
                        value = var.min
                    store.setdefault(var.index, {})[var.subindex] = var.encode_raw(value)

    def _build_object_hooks(self) -> None:
        for stage in self.stages:
            sw, cw = stage.statusword, stage.controlword
            self._readers[(sw.index, sw.subindex)] = partial(self._statusword, stage)
            self._writers[(cw.index, cw.subindex)] = partial(self._on_controlword, stage)
            if stage.mode is not None:
                m = stage.mode
                self._writers[(m.index, m.subindex)] = partial(self._on_mode, stage)
            display = stage.axes[0].objs.get(Obj.MODE_DISPLAY)
            if display is not None:
                self._readers[(display.index, display.subindex)] = partial(self._mode, stage)
        for ax in self.axes:
            readers: tuple[tuple[Obj, Callable[[], int]], ...] = (
                (Obj.POSITION_ACTUAL, partial(self._position, ax)),
                (Obj.VELOCITY_ACTUAL, partial(self._velocity_rounded, ax)),
                (Obj.VL_ACTUAL, partial(self._velocity_rounded, ax)),
                (Obj.VL_DEMAND, partial(self._demand_rounded, ax)),
            )
            for obj, reader in readers:
                entry = ax.objs.get(obj)
                if entry is not None:
                    self._readers[(entry.index, entry.subindex)] = self._wrap_for(entry, reader)
            for obj in (Obj.TARGET_VELOCITY, Obj.VL_TARGET, Obj.PROFILE_ACCEL, Obj.PROFILE_DECEL,
                        Obj.QUICK_STOP_DECEL, Obj.MAX_PROFILE_VELOCITY):
                entry = ax.objs.get(obj)
                if entry is not None:
                    self._motion_objects.add((entry.index, entry.subindex))
                    if obj in (Obj.TARGET_VELOCITY, Obj.VL_TARGET):
                        self._target_objects[(entry.index, entry.subindex)] = ax
            for rec in (Obj.VL_ACCEL, Obj.VL_DECEL, Obj.VL_QUICK_STOP):
                index = ax.objs.record(rec)
                if index is not None:
                    self._motion_objects.update({(index, 1), (index, 2)})
        err = self.axes[0].objs.get(Obj.ERROR_CODE)
        if err is not None:
            self._readers[(err.index, err.subindex)] = lambda: self.stages[0].fault_code
        if ERROR_REGISTER in self.dictionary:
            self._readers[(ERROR_REGISTER, 0)] = self._error_register

    @staticmethod
    def _wrap_for(entry: Entry, reader: Callable[[], int]) -> Callable[[], int]:
        """Raw integer as the OD type stores it (two's complement for unsigned types)."""
        bits = entry.bits
        half, full = 1 << (bits - 1), 1 << bits

        def wrapped() -> int:
            value = (int(reader()) + half) % full - half  # wrap like an encoder counter
            return value if entry.declared_signed else value % full

        return wrapped

    # ------------------------------------------------------------- properties

    @property
    def nmt_state(self) -> str:
        return NMT_STATE_NAMES.get(self._nmt, hex(self._nmt))

    def state(self, axis: int = 0) -> State:
        return self.axes[axis].stage.state

    @property
    def frozen(self) -> bool:
        return self._frozen

    def physical_counts(self, axis: int = 0, now: float | None = None) -> float:
        """Encoder counts the wheel really turned since power-up (never reset or wrapped),
        at ``now`` (default: the present)."""
        with self.lock:
            self._advance(self.clock.now() if now is None else now)
            return self.axes[axis].state.position

    def velocity_counts(self, axis: int = 0) -> float:
        with self.lock:
            self._advance(self.clock.now())
            return self.axes[axis].state.velocity

    def read(self, index: int, subindex: int = 0) -> bytes:
        """Current raw value of an object, as an SDO upload would return it."""
        with self.lock:
            self._advance(self.clock.now())
            return bytes(self.node.get_data(index, subindex))

    # ------------------------------------------------------------- injection

    def inject_fault(self, code: int = 0x2310, axis: int = 0, persistent: bool = False) -> None:
        """Trip a fault: EMCY with ``code``, then FAULT REACTION ACTIVE -> FAULT.
        ``persistent``: its cause stays (a motor that has not cooled down): fault resets
        are refused until :meth:`clear_fault`."""
        with self.lock:
            self._advance(self.clock.now())
            stage = self.axes[axis].stage
            stage.fault_persists = persistent
            self._fault(stage, code)

    def clear_fault(self, axis: int = 0) -> None:
        """The cause of a persistent fault is gone: the next fault reset clears it."""
        with self.lock:
            self.axes[axis].stage.fault_persists = False

    def hold_switched_on(self, held: bool = True, axis: int = 0) -> None:
        """The power stage cannot enable (no DC link voltage, safe torque off): enable
        operation is ignored, the drive stays SWITCHED ON."""
        with self.lock:
            self.axes[axis].stage.enable_held = held

    def stop_heartbeat(self) -> None:
        """Stop producing heartbeats (the drive keeps working otherwise)."""
        with self.lock:
            self._heartbeat_enabled = False

    def start_heartbeat(self) -> None:
        with self.lock:
            self._heartbeat_enabled = True

    def reboot(self) -> None:
        """Power-cycle: boot-up frame, OD defaults, position counters at their power-up value."""
        with self.lock:
            self._advance(self.clock.now())
            self._boot(reset_node=True)

    def freeze(self) -> None:
        """Go silent: answer nothing, send nothing (a hung node). The motor keeps its demand."""
        with self.lock:
            self._frozen = True

    def thaw(self) -> None:
        with self.lock:
            self._frozen = False
            self._last_heartbeat = -1e9

    # ---------------------------------------------------------------- NMT

    def _boot(self, reset_node: bool) -> None:
        self._invalidate()
        self._nmt = NmtState.BOOT_UP
        self._tpdos, self._rpdos, self._pending = [], {}, {}
        if reset_node:
            self.node.data_store.clear()
            self._prefill_defaults()
            for ax in self.axes:
                # The power stage drops out: the wheel coasts; the counter restarts.
                ax.counter_offset = ax.state.position - self._initial_position[ax.number]
                ax.internal_limit = False
            for stage in self.stages:
                stage.state, stage.last_cw, stage.fault_code, stage.warning = (
                    State.SWITCH_ON_DISABLED, 0, 0, False)
                stage.mode_cache, stage.fault_persists = None, False
        else:
            self._reset_comm_objects()
        self._window = self._velocity_window()
        self._heartbeat_enabled = True
        self._send(HEARTBEAT_BASE + self.node_id, bytes([NmtState.BOOT_UP]), droppable=False)
        self._nmt = NmtState.PRE_OPERATIONAL
        self._restart_consumers()
        self._load_heartbeat_config()
        self._last_heartbeat = self.clock.now()

    def _reset_comm_objects(self) -> None:
        for index in [i for i in self.node.data_store if i in COMMUNICATION_PROFILE]:
            del self.node.data_store[index]
        self._prefill_defaults()
        self._invalidate()

    def _load_heartbeat_config(self) -> None:
        self._heartbeat_period = self._u16(PRODUCER_HEARTBEAT_TIME, 0) / 1000.0
        self._consumers = {}
        obj = self.dictionary.get(CONSUMER_HEARTBEAT_TIME)
        if isinstance(obj, (od.ODArray, od.ODRecord)):
            for sub in obj.subindices:
                if sub == 0:
                    continue
                raw = self._u32(CONSUMER_HEARTBEAT_TIME, sub)
                producer, ms = (raw >> 16) & MAX_NODE_ID, raw & 0xFFFF
                if producer and ms:
                    self._consumers[producer] = ms / 1000.0
        for producer in self._consumers:
            if producer not in self._subscribed_hb:
                self.network.subscribe(HEARTBEAT_BASE + producer, self._on_heartbeat)
                self._subscribed_hb.add(producer)
        self._consumer_seen = {p: t for p, t in self._consumer_seen.items() if p in self._consumers}
        self._consumer_lost &= set(self._consumers)

    def _restart_consumers(self) -> None:
        """After a boot a consumer watches from the next heartbeat it receives, not from
        one it heard before (a host that ran earlier)."""
        self._consumer_seen, self._consumer_lost = {}, set()

    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if len(data) < 2 or data[1] not in (0, self.node_id):
            return
        with self.lock:
            if self._frozen:
                return
            cmd = data[0]
            now = self.clock.now()
            self._advance(now)
            if cmd == NmtCommand.START:
                self._enter_operational()
            elif cmd == NmtCommand.STOP:
                self._abort_connection()
                self._nmt, self._tpdos, self._rpdos = NmtState.STOPPED, [], {}
            elif cmd == NmtCommand.ENTER_PRE_OPERATIONAL:
                self._nmt, self._tpdos, self._rpdos = NmtState.PRE_OPERATIONAL, [], {}
            elif cmd == NmtCommand.RESET_NODE:
                self._boot(reset_node=True)
            elif cmd == NmtCommand.RESET_COMMUNICATION:
                self._abort_connection()
                self._boot(reset_node=False)
            self._send_heartbeat(now)  # heartbeats show a new state at once

    def _enter_operational(self) -> None:
        getter = self.node.get_data
        self._tpdos = read_pdos(self.dictionary, getter, TPDO_COMM, TPDO_MAP)
        self._rpdos = {p.cob_id: p for p in read_pdos(self.dictionary, getter, RPDO_COMM, RPDO_MAP)}
        self._pending = {}
        for cob in self._rpdos:
            self.network.subscribe(cob, self._on_rpdo)
        self._nmt = NmtState.OPERATIONAL
        for tpdo in self._tpdos:
            tpdo.last_data = None
            tpdo.pending_change = tpdo.event_driven  # first event TPDO goes out at once

    # -------------------------------------------------------- frame handlers

    def _on_sdo(self, can_id: int, data: bytearray, timestamp: float) -> None:
        with self.lock:
            if self._frozen or self._nmt in (NmtState.STOPPED, NmtState.BOOT_UP):
                return
            self._advance(self.clock.now())
            self.node.sdo.on_request(can_id, data, timestamp)

    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        with self.lock:
            if self._frozen or self._nmt != NmtState.OPERATIONAL or self._lost():
                return
            now = self._frame_time(timestamp)
            self._advance(now)
            pending, self._pending = self._pending, {}
            for cob, payload in pending.items():
                rpdo = self._rpdos.get(cob)
                if rpdo is not None:
                    self._apply_rpdo(rpdo, payload)
            for tpdo in self._tpdos:
                if tpdo.trans_type == 0:
                    if tpdo.pending_change or self._frame(tpdo) != tpdo.last_data:
                        self._send_tpdo(tpdo, now)
                elif tpdo.synchronous:
                    tpdo.sync_count += 1
                    if tpdo.sync_count >= tpdo.trans_type:
                        tpdo.sync_count = 0
                        self._send_tpdo(tpdo, now)

    def _frame_time(self, timestamp: float) -> float:
        """When a frame reached the bus, on the monotonic clock: every drive acts on a
        SYNC at the instant it was sent, not when its handler got to run."""
        clock = self.clock
        if clock.lockstep:
            return clock.now()  # delivered the instant it was sent
        age = clock.wall() - timestamp if timestamp else 0.0
        return max(self._last_advance, clock.now() - min(max(age, 0.0), 0.05))

    def _on_rpdo(self, can_id: int, data: bytearray, timestamp: float) -> None:
        with self.lock:
            rpdo = self._rpdos.get(can_id)
            if rpdo is None or self._frozen or self._nmt != NmtState.OPERATIONAL or self._lost():
                return
            if len(data) < rpdo.length:
                self._emcy(EMCY_PDO_LENGTH, ERROR_REGISTER_COMMUNICATION)
                return
            if rpdo.synchronous:
                self._pending[can_id] = bytes(data)
            else:
                now = self._frame_time(timestamp)
                self._advance(now)
                self._apply_rpdo(rpdo, bytes(data))
                self._event_tpdos(now)

    def _apply_rpdo(self, rpdo: PdoConfig, payload: bytes) -> None:
        offset = 0
        for entry in rpdo.entries:
            chunk = payload[offset : offset + entry.nbytes]
            offset += entry.nbytes
            try:
                self.node.set_data(entry.index, entry.subindex, self._fit(entry, chunk))
            except SdoAbortedError as exc:  # e.g. an unsupported mode: ignored, as on a drive
                logger.debug("node %d: RPDO write to 0x%04X refused: %s", self.node_id,
                             entry.index, exc)

    def _fit(self, entry: MappedObject, chunk: bytes) -> bytes:
        var = self.node._find_object(entry.index, entry.subindex)
        size = len(var) // 8
        return chunk[:size].ljust(size, b"\x00")

    def _on_heartbeat(self, can_id: int, data: bytearray, timestamp: float) -> None:
        producer = can_id - HEARTBEAT_BASE
        with self.lock:
            if self._frozen or producer not in self._consumers:
                return
            self._consumer_seen[producer] = self.clock.now()
            if producer in self._consumer_lost:
                self._consumer_lost.discard(producer)
                for stage in self.stages:
                    stage.warning = False

    # --------------------------------------------------------- OD callbacks

    def _on_read(self, index: int, subindex: int, od: od.ODVariable) -> int | None:
        reader = self._readers.get((index, subindex))
        return None if reader is None else reader()

    def _on_write(self, index: int, subindex: int, od: od.ODVariable, data: bytes) -> None:
        key = (index, subindex)
        if RPDO_MAP <= index < RPDO_MAP + MAX_PDOS or TPDO_MAP <= index < TPDO_MAP + MAX_PDOS:
            if not self.remappable:
                raise SdoAbortedError(SDO_ABORT_READ_ONLY)
            check_mapping_write(self.dictionary, self.node.get_data, index, subindex, data,
                                self.max_mapping_entries, self.accept_unmappable)
            return
        store = self.node.data_store.setdefault(index, {})
        data = bytes(data)
        unchanged = store.get(subindex) == data
        if key in self._motion_objects and not unchanged:
            self._advance(self.clock.now())  # the old value applied until now
        writer = self._writers.get(key)
        if writer is not None:  # may refuse the value (SDO abort): then nothing is stored
            value = int.from_bytes(data, "little", signed=od.data_type in SIGNED_TYPES)
            writer(value)
        # Store now (LocalNode stores again after us) so what follows reads the new value.
        store[subindex] = data
        if unchanged:
            return  # the same value again (a cyclic controlword): nothing to recompute
        target_of = self._target_objects.get(key)
        if target_of is not None:
            target_of.command = None  # a new target: the axis's parameters still hold
        else:
            self._invalidate()
        if index in (CONSUMER_HEARTBEAT_TIME, PRODUCER_HEARTBEAT_TIME):
            self._load_heartbeat_config()
        elif index == 0x606D:
            self._window = self._velocity_window()

    # ----------------------------------------------------------- CiA 402

    def _invalidate(self) -> None:
        """Something that shapes the motion changed: recompute the commands lazily."""
        for ax in self.axes:
            ax.command = None
            ax.params = None

    def _set_state(self, stage: _PowerStage, state: State) -> None:
        if stage.state is not state:
            stage.state = state
            self._invalidate()

    def _on_mode(self, stage: _PowerStage, value: int) -> None:
        if value not in self._supported_modes and value != 0:
            raise SdoAbortedError(SDO_ABORT_VALUE_RANGE)
        stage.mode_cache = value

    def _mode(self, stage: _PowerStage) -> int:
        if stage.mode is None:
            return int(Mode.PROFILE_VELOCITY)
        if stage.mode_cache is None:
            stage.mode_cache = stage.mode.decode(
                self.node.get_data(stage.mode.index, stage.mode.subindex))
        return stage.mode_cache

    def _on_controlword(self, stage: _PowerStage, value: int) -> None:
        self._advance(self.clock.now())
        previous, stage.last_cw = stage.last_cw, value & 0xFFFF
        rising_reset = value & cia402.CW_FAULT_RESET and not previous & cia402.CW_FAULT_RESET
        if stage.state is State.FAULT:
            if rising_reset and not stage.fault_persists:
                stage.fault_code = 0
                self._set_state(stage, State.SWITCH_ON_DISABLED)
                self._emcy(EMCY_NO_ERROR, 0)  # error reset
            return
        if stage.state is State.FAULT_REACTION_ACTIVE:
            return
        command = cia402.decode_command(value)
        if command is None:
            return
        transition = cia402.DEVICE_TRANSITIONS.get((stage.state, command))
        if transition is None:
            return
        if transition.number == 16 and self._quick_stop_option() not in (5, 6, 7, 8):
            return
        if transition.target is State.OPERATION_ENABLED:
            if stage.enable_held:
                return
            for ax in stage.axes:  # start from where the wheel is, not from an old demand
                ax.state = motor.MotorState(ax.state.position, ax.state.velocity,
                                            ax.state.velocity)
        self._set_state(stage, transition.target)

    def _quick_stop_option(self) -> int:
        entry = self.axes[0].objs.get(Obj.QUICK_STOP_OPTION)
        if entry is None:
            return 2
        return entry.decode(self.node.get_data(entry.index, entry.subindex))

    def _fault(self, stage: _PowerStage, code: int) -> None:
        if stage.state in (State.FAULT, State.FAULT_REACTION_ACTIVE):
            return
        stage.fault_code = code
        powered = stage.state in (State.OPERATION_ENABLED, State.QUICK_STOP_ACTIVE)
        self._set_state(stage, State.FAULT_REACTION_ACTIVE if powered else State.FAULT)
        self._emcy(code, self._error_register())
        self._event_tpdos(self.clock.now())

    def _error_register(self) -> int:
        reg = 0
        for stage in self.stages:
            if stage.fault_code:
                reg |= ERROR_REGISTER_GENERIC | _ERROR_REGISTER_BITS.get(stage.fault_code >> 12, 0)
        return reg

    def _abort_connection(self) -> None:
        """React to a lost master per 6007h (quick stop by default)."""
        entry = self.axes[0].objs.get(Obj.ABORT_OPTION)
        option = cia402.ABORT_QUICK_STOP
        if entry is not None:
            option = entry.decode(self.node.get_data(entry.index, entry.subindex))
        for stage in self.stages:
            if stage.state not in (State.OPERATION_ENABLED, State.QUICK_STOP_ACTIVE):
                if option == cia402.ABORT_NO_ACTION:
                    stage.warning = True
                continue
            if option == cia402.ABORT_FAULT:
                self._fault(stage, EMCY_HEARTBEAT)
            elif option == cia402.ABORT_DISABLE_VOLTAGE:
                self._set_state(stage, State.SWITCH_ON_DISABLED)
            elif option == cia402.ABORT_NO_ACTION:
                stage.warning = True
            elif stage.state is State.OPERATION_ENABLED:
                self._set_state(stage, State.QUICK_STOP_ACTIVE)

    def _statusword(self, stage: _PowerStage) -> int:
        sw = _STATE_BITS[stage.state] | cia402.SW_REMOTE
        if stage.warning:
            sw |= cia402.SW_WARNING
        if any(ax.internal_limit for ax in stage.axes):
            sw |= cia402.SW_INTERNAL_LIMIT
        if stage.state is State.OPERATION_ENABLED:
            mode = self._mode(stage)
            if mode == Mode.CYCLIC_SYNC_VELOCITY:
                sw |= cia402.SW_OMS_12  # drive follows the command value
            elif all(self._reached(ax, stage) for ax in stage.axes):
                sw |= cia402.SW_TARGET_REACHED
            if mode == Mode.PROFILE_VELOCITY and self._standstill(stage):
                sw |= cia402.SW_OMS_12  # speed is zero
        elif stage.state is State.QUICK_STOP_ACTIVE and self._standstill(stage):
            sw |= cia402.SW_TARGET_REACHED
        return sw

    def _standstill(self, stage: _PowerStage) -> bool:
        """Every axis below one velocity unit: the drive's "speed = 0"."""
        return all(abs(self._velocity_units(ax)) < STANDSTILL_UNITS for ax in stage.axes)

    def _reached(self, ax: _Axis, stage: _PowerStage) -> bool:
        if ax.command is None:
            ax.command = self._motion_command(ax)  # refreshes target_units
        halted = bool(stage.last_cw & cia402.CW_HALT)
        target = 0.0 if halted else ax.target_units
        return abs(self._velocity_units(ax) - target) <= self._window

    def _velocity_window(self) -> float:
        window = 1.0
        if isinstance(self.dictionary.get(0x606D), od.ODVariable):
            window = max(window, float(self._u32(0x606D, 0, 1) & 0xFFFF))
        return window

    # ------------------------------------------------------------ motion

    def _axis_raw(self, entry: Entry | None, default: int = 0) -> int:
        if entry is None:
            return default
        data = self.node.data_store.get(entry.index, {}).get(entry.subindex)
        if data is None:  # never written: the EDS default
            data = self.node.get_data(entry.index, entry.subindex)
        return entry.decode(data)

    def _record_rate(self, index: int | None) -> float | None:
        """vl ramp (delta speed / delta time in s) in units/s^2, or None."""
        if index is None:
            return None
        speed = self._u32(index, 1)
        seconds = self._u16(index, 2)
        if speed == 0 or seconds == 0:
            return None
        return speed / seconds

    def _motion_params(self, ax: _Axis) -> tuple[int, float, float, float, int, Entry | None]:
        """(mode, quick stop decel, accel, decel (counts/s^2, inf: none), max profile
        velocity, the target object of the mode or None) from the dictionary."""
        inf = math.inf
        cpu = abs(ax.counts_per_unit)
        quick = self._axis_raw(ax.objs.get(Obj.QUICK_STOP_DECEL)) * cpu
        mode = self._mode(ax.stage)
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
                accel_c = self._axis_raw(ax.objs.get(Obj.PROFILE_ACCEL)) * cpu or inf
                decel_c = self._axis_raw(ax.objs.get(Obj.PROFILE_DECEL)) * cpu or accel_c
        quick = quick if quick > 0 else inf
        limit = self._axis_raw(ax.objs.get(Obj.MAX_PROFILE_VELOCITY))
        return mode, quick, accel_c, decel_c, limit, target

    def _motion_command(self, ax: _Axis) -> tuple[float, float, float, float]:
        """(target counts/s, accel, decel, tau) for the axis in its current state."""
        stage = ax.stage
        params = ax.params
        if params is None:
            params = ax.params = self._motion_params(ax)
        mode, quick, accel_c, decel_c, limit, target_entry = params
        state = stage.state
        if state in (State.QUICK_STOP_ACTIVE, State.FAULT_REACTION_ACTIVE):
            ax.target_units = 0.0
            return 0.0, quick, quick, self.tau_s
        if state is not State.OPERATION_ENABLED:
            ax.target_units = 0.0
            return 0.0, math.inf, math.inf, COAST_TAU_S
        if mode not in (Mode.VELOCITY, Mode.PROFILE_VELOCITY, Mode.CYCLIC_SYNC_VELOCITY):
            ax.target_units = 0.0
            return 0.0, quick, quick, self.tau_s  # no velocity mode: hold still
        halted = bool(stage.last_cw & cia402.CW_HALT)
        target = self._axis_raw(target_entry)
        ax.internal_limit = bool(limit) and abs(target) > limit
        if ax.internal_limit:
            target = int(math.copysign(limit, target))
        ax.target_units = float(target)
        if halted and mode != Mode.CYCLIC_SYNC_VELOCITY:
            return 0.0, decel_c, decel_c, self.tau_s
        return target * ax.counts_per_unit, accel_c, decel_c, self.tau_s

    def _advance(self, now: float) -> None:
        dt = now - self._last_advance
        if dt <= 0:
            return
        self._last_advance = now
        for ax in self.axes:
            if ax.command is None:
                ax.command = self._motion_command(ax)
            target, accel, decel, tau = ax.command
            ax.state = motor.advance(ax.state, dt, target, accel, decel, tau)
        for stage in self.stages:
            stopped = self._standstill(stage)
            if stage.state is State.FAULT_REACTION_ACTIVE and stopped:
                self._set_state(stage, State.FAULT)
            elif stage.state is State.QUICK_STOP_ACTIVE and stopped and (
                self._quick_stop_option() not in (5, 6, 7, 8)
            ):
                self._set_state(stage, State.SWITCH_ON_DISABLED)

    def _position(self, ax: _Axis) -> int:
        counts = ax.state.position - ax.counter_offset
        if self.encoder_noise:
            counts += self._rng.gauss(0.0, self.encoder_noise)
        return round(counts)

    def _velocity_units(self, ax: _Axis) -> float:
        return ax.state.velocity / ax.counts_per_unit

    def _velocity_rounded(self, ax: _Axis) -> int:
        return round(self._velocity_units(ax))

    def _demand_rounded(self, ax: _Axis) -> int:
        return round(ax.state.demand / ax.counts_per_unit)

    # ------------------------------------------------------------- output

    def _lost(self) -> bool:
        return self.frame_loss > 0 and self._rng.random() < self.frame_loss

    def _send(self, cob_id: int, data: bytes, droppable: bool = True) -> None:
        if self._frozen or self._closed or (droppable and self._lost()):
            return
        bus = self.network.bus
        if bus is None:
            return
        try:
            with self.network.send_lock:
                bus.send(can.Message(arbitration_id=cob_id, data=data, is_extended_id=False))
        except (can.CanError, OSError, RuntimeError) as exc:
            # A link that is down refuses every frame: say so once, then now and then.
            self._send_failures += 1
            now = self.clock.now()
            if now - self._send_warned_at >= SEND_WARNING_EVERY_S:
                self._send_warned_at = now
                logger.warning("simulated node %d could not send 0x%03X (%d frames refused "
                               "so far): %s", self.node_id, cob_id, self._send_failures, exc)

    def _emcy(self, code: int, register: int) -> None:
        self._send(EMCY_BASE + self.node_id, struct.pack("<HB5s", code, register, b""),
                   droppable=False)

    def _frame(self, tpdo: PdoConfig) -> bytes:
        out = bytearray()
        for entry in tpdo.entries:
            key = (entry.index, entry.subindex)
            reader = self._readers.get(key)
            if reader is not None:  # dynamic object: skip the OD machinery
                width = entry.nbytes * 8
                out += (reader() % (1 << width)).to_bytes(entry.nbytes, "little")
            else:
                out += self.node.get_data(entry.index, entry.subindex)[: entry.nbytes]
        return bytes(out)

    def _send_tpdo(self, tpdo: PdoConfig, now: float) -> None:
        data = self._frame(tpdo)
        tpdo.last_data, tpdo.last_sent, tpdo.pending_change = data, now, False
        self._send(tpdo.cob_id, data)

    def _event_tpdos(self, now: float) -> None:
        if self._nmt != NmtState.OPERATIONAL:
            return
        for tpdo in self._tpdos:
            if not tpdo.event_driven:
                continue
            data = self._frame(tpdo)
            if data != tpdo.last_data:
                tpdo.pending_change = True
            due = tpdo.pending_change or (tpdo.event_s and now - tpdo.last_sent >= tpdo.event_s)
            if due and now - tpdo.last_sent >= tpdo.inhibit_s:
                self._send_tpdo(tpdo, now)

    def _send_heartbeat(self, now: float) -> None:
        if self._heartbeat_enabled and self._heartbeat_period > 0:
            self._last_heartbeat = now
            self._send(HEARTBEAT_BASE + self.node_id, bytes([self._nmt]))

    def tick(self, now: float) -> None:
        """Housekeeping (called by the scheduler)."""
        with self.lock:
            if self._closed:
                return
            self._advance(now)
            if self._frozen:
                return
            if self._heartbeat_period > 0 and now - self._last_heartbeat >= self._heartbeat_period:
                self._send_heartbeat(now)
            for producer, timeout in self._consumers.items():
                seen = self._consumer_seen.get(producer)
                if seen is None or producer in self._consumer_lost:
                    continue  # consumer starts at the first heartbeat received
                if now - seen > timeout:
                    self._consumer_lost.add(producer)
                    logger.info("simulated node %d lost the heartbeat of node %d", self.node_id,
                                producer)
                    self._emcy(EMCY_HEARTBEAT,
                               ERROR_REGISTER_GENERIC | ERROR_REGISTER_COMMUNICATION)
                    self._abort_connection()
            self._event_tpdos(now)

    # ------------------------------------------------------------ helpers

    def _u32(self, index: int, sub: int, default: int = 0) -> int:
        try:
            return int.from_bytes(self.node.get_data(index, sub)[:4], "little")
        except (SdoAbortedError, KeyError):
            return default

    def _u16(self, index: int, sub: int, default: int = 0) -> int:
        try:
            return int.from_bytes(self.node.get_data(index, sub)[:2], "little")
        except (SdoAbortedError, KeyError):
            return default

    # ------------------------------------------------------------ lifecycle

    def close(self) -> None:
        """Detach from the network and stop the housekeeping (idempotent)."""
        with self.lock:
            if self._closed:
                return
            self._closed = True
        self.scheduler.remove(self.tick)
        if self._own_scheduler:
            self.scheduler.close()
        net = self.network
        for cob, handler in [(NMT_COB_ID, self._on_nmt), (self.node.sdo.rx_cobid, self._on_sdo),
                             (self._sync_cob, self._on_sync)]:
            _unsubscribe(net, cob, handler)
        for cob in list(self._rpdos):
            _unsubscribe(net, cob, self._on_rpdo)
        for producer in self._subscribed_hb:
            _unsubscribe(net, HEARTBEAT_BASE + producer, self._on_heartbeat)
        if self.node_id in net.nodes and net.nodes[self.node_id] is self.node:
            # LocalNode.remove_network would unsubscribe handlers we already replaced.
            del net.nodes[self.node_id]

    def __enter__(self) -> SimulatedDrive:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<SimulatedDrive node {self.node_id} {self.eds.name} {self.nmt_state}>"


def _unsubscribe(net: canopen.Network, cob: int, handler: Any) -> None:
    if handler in net.subscribers.get(cob, []):
        net.unsubscribe(cob, handler)

