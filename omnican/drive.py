"""One CANopen node driving one or more wheels (axes): configuration, units, PDO I/O.

* :meth:`DriveNode.configure` (SDO, blocking, bounded): NMT reset communication and
  boot-up, mode, ramps, heartbeat producer and consumer, 6007h, the PDO plan of
  :mod:`omnican.pdoplan` (or, for a drive that refuses remapping, its own mapping
  read back), then NMT OPERATIONAL.
* Frame handlers run on the Notifier thread and only copy values.
* The control loop calls :meth:`DriveNode.cyclic_frames` (targets), and
  :class:`StageDriver` walks each CiA 402 state machine with controlword bit masks.

Units: m/s at the rim <-> drive velocity units (``velocity_scale``); encoder counts
-> continuous metres of travel across counter wrap-around and drive reboots.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import canopen
from canopen.emcy import EmcyError
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from omnican import cia402
from omnican.cia301 import (
    COB_ID_INVALID,
    COB_ID_MASK,
    CONSUMER_HEARTBEAT_TIME,
    HEARTBEAT_BASE,
    NMT_COB_ID,
    NMT_STATE_MASK,
    PRODUCER_HEARTBEAT_TIME,
    TPDO_COMM,
    TRANS_EVENT,
    TRANS_SYNC,
    NmtCommand,
    abort_text,
)
from omnican.cia402 import Command, Mode, State
from omnican.config import WheelConfig
from omnican.encoder import fold_counter
from omnican.errors import DriveError
from omnican.layout import NodeLayout
from omnican.odmap import AxisObjects, Entry, Obj, entry_at, obj_name
from omnican.pdoplan import NodePlan, PlannedPdo

logger = logging.getLogger(__name__)

class EpochSource(Protocol):
    """Numbers the SYNCs, so samples taken for the same SYNC can be grouped."""

    sync_epoch: int


TpdoHandler = Callable[[int, bytearray, float], None]


@dataclass
class AxisIO:
    """One wheel: an axis of the node."""

    wheel_index: int
    wheel: WheelConfig
    objs: AxisObjects
    target: Entry
    position: Entry
    stage: StageDriver
    # Position samples (written on the Notifier thread, read by the loop).
    raw: int | None = None
    epoch: int = -1
    # Continuous travel (loop thread only).
    counts: float = 0.0
    last_raw: int | None = None

    def travel_from_sample(self, raw: int) -> float:
        """Fold a raw counter value into continuous counts; returns travel in m."""
        self.counts = fold_counter(self.counts, self.last_raw, raw, self.position.bits)
        self.last_raw = raw
        return self.counts / self.wheel.position_scale

    def reseed(self) -> None:
        """After a reboot the counter restarts: the next sample continues the travel."""
        self.last_raw = None


@dataclass
class StageDriver:
    """Walks one CiA 402 state machine (one controlword) towards a goal.

    Keeps every bit it does not own (halt, mode bits); a fault reset is a clean
    rising edge of bit 7 over two cycles; a transition that does not happen within
    ``timeout_s`` is reported with its name."""

    node_id: int
    controlword: Entry
    statusword: Entry
    mode: Entry | None
    mode_display: Entry | None
    error_code: Entry | None
    timeout_s: float
    resend_s: float = 0.1
    goal: State = State.SWITCH_ON_DISABLED
    allow_fault_reset: bool = False
    cw: int = 0
    statusword_value: int | None = None  # Notifier thread writes, loop reads
    mode_value: int | None = None
    error_value: int | None = None
    _sent_cw: int | None = None
    _sent_at: float = -1e9
    _reset_phase: int = 0
    _waiting_since: float | None = None
    _waiting_state: State | None = None
    error: str | None = None
    _decoded: tuple[int | None, State] = (None, State.UNKNOWN)

    @property
    def state(self) -> State:
        sw = self.statusword_value
        if sw != self._decoded[0]:
            self._decoded = (sw, cia402.decode_state(sw))
        return self._decoded[1]

    def set_goal(self, goal: State, allow_fault_reset: bool = False) -> None:
        if goal is not self.goal or allow_fault_reset != self.allow_fault_reset:
            self.goal, self.allow_fault_reset = goal, allow_fault_reset
            self._waiting_since, self.error, self._reset_phase = None, None, 0

    def forget(self) -> None:
        """The drive rebooted: its state and controlword are unknown again."""
        self.statusword_value, self.mode_value, self.error_value = None, None, None
        self._sent_cw, self.cw, self._reset_phase = None, 0, 0
        self._waiting_since = None

    def step(self, now: float) -> int | None:
        """The controlword to send this cycle, or None."""
        state = self.state
        if state is self.goal or state is State.UNKNOWN:
            self._waiting_since = None
            if state is self.goal and self._sent_cw != self.cw:
                return self._emit(now)  # e.g. the enable bits after a reboot
            return None
        if state is State.FAULT and (self.goal is State.SWITCH_ON_DISABLED or
                                     not self.allow_fault_reset):
            self._waiting_since = None
            return None
        if state is not self._waiting_state or self._waiting_since is None:
            self._waiting_state, self._waiting_since = state, now
        elif now - self._waiting_since > self.timeout_s and self.error is None:
            cmd = cia402.command_towards(state, self.goal)
            what = "fault reset" if cmd is Command.FAULT_RESET else (
                cmd.name.lower().replace("_", " ") if cmd else "waiting")
            self.error = (f"node {self.node_id}: stuck in {state} on the way to {self.goal}: "
                          f"{what} not accepted within {self.timeout_s:g} s")
            logger.warning("%s", self.error)
        cmd = cia402.command_towards(state, self.goal)
        if cmd is None:
            return None
        if cmd is Command.FAULT_RESET:
            low, high = cia402.fault_reset_sequence(self.cw)
            if self._reset_phase == 0 or now - self._sent_at > self.resend_s * 2:
                self.cw, self._reset_phase = low, 1
            else:
                self.cw, self._reset_phase = high, 0
            return self._emit(now)
        self.cw = cia402.apply_command(self.cw, cmd)
        if self.cw != self._sent_cw or now - self._sent_at > self.resend_s:
            return self._emit(now)
        return None

    def _emit(self, now: float) -> int:
        self._sent_cw, self._sent_at = self.cw, now
        return self.cw

    def set_halt(self, halt: bool) -> None:
        self.cw = (self.cw | cia402.CW_HALT) if halt else (self.cw & ~cia402.CW_HALT)


@dataclass
class _RpdoIO:
    pdo: PlannedPdo
    frame: bytearray
    slots: list[tuple[int, Entry, object]] = field(default_factory=list)  # offset, entry, owner


class DriveNode:
    """One node of the base, with the wheels (axes) it drives, on a live network."""

    def __init__(self, network: canopen.Network, layout: NodeLayout,
                 epoch_source: EpochSource) -> None:
        self.layout = layout
        self.node_id = node_id = layout.node_id
        self.settings = settings = layout.settings
        self.network = network
        self._epoch_source = epoch_source
        self.dictionary = layout.dictionary
        self.eds_name = layout.eds.name
        self.mode = layout.mode
        self.has_consumer = layout.has_consumer
        self.plan = layout.plan
        self.remote = canopen.RemoteNode(node_id, self.dictionary)
        self.remote.sdo.RESPONSE_TIMEOUT = settings.sdo_timeout_s
        self.remote.sdo.MAX_RETRIES = 1
        network.add_node(self.remote)
        self.stages = [StageDriver(node_id, s.controlword, s.statusword, s.mode, s.mode_display,
                                   s.error_code, settings.enable_timeout_s)
                       for s in layout.stages]
        self.axes = [AxisIO(a.wheel_index, a.wheel, a.objs, a.target, a.position,
                            self.stages[a.stage]) for a in layout.axes]
        self._rpdo_io: list[_RpdoIO] = []
        self._cw_io: dict[int, tuple[_RpdoIO, int]] = {}  # id(stage) -> (pdo, offset)
        self._subscribed: list[tuple[int, TpdoHandler]] = []
        self._build_io(self.plan)
        # Liveness and events (Notifier thread writes; loop reads).
        self.last_heartbeat: float | None = None
        self.nmt_state: int | None = None
        self.booted = threading.Event()
        self.rebooted = False
        self.emcy: EmcyError | None = None
        self.fault_text: str | None = None
        self._hb_period = settings.heartbeat_ms / 1000.0
        network.subscribe(HEARTBEAT_BASE + node_id, self._on_heartbeat)
        self.remote.emcy.add_callback(self._on_emcy)

    def _build_io(self, plan: NodePlan) -> None:
        for cob, handler in self._subscribed:
            self.network.unsubscribe(cob, handler)
        self._subscribed = []
        self._rpdo_io, self._cw_io = [], {}
        for pdo in plan.rpdos:
            io = _RpdoIO(pdo, bytearray(pdo.data_bytes))
            offset = 0
            for entry in pdo.entries:
                owner: object = None
                for ax in self.axes:
                    if (ax.target.index, ax.target.subindex) == (entry.index, entry.subindex):
                        owner = ax
                for stage in self.stages:
                    key = (stage.controlword.index, stage.controlword.subindex)
                    if key == (entry.index, entry.subindex):
                        owner = stage
                        self._cw_io[id(stage)] = (io, offset)
                io.slots.append((offset, entry, owner))
                offset += entry.bits // 8
            self._rpdo_io.append(io)
        for pdo in plan.tpdos:
            decoders: list[tuple[int, Entry, str, object]] = []
            offset = 0
            for entry in pdo.entries:
                key = (entry.index, entry.subindex)
                for ax in self.axes:
                    if key == (ax.position.index, ax.position.subindex):
                        decoders.append((offset, entry, "position", ax))
                for stage in self.stages:
                    for role, e in (("statusword", stage.statusword), ("mode", stage.mode_display),
                                    ("error", stage.error_code)):
                        if e is not None and key == (e.index, e.subindex):
                            decoders.append((offset, entry, role, stage))
                offset += entry.bits // 8
            handler = self._make_tpdo_handler(pdo.data_bytes, decoders)
            self.network.subscribe(pdo.cob_id, handler)
            self._subscribed.append((pdo.cob_id, handler))

    def _make_tpdo_handler(self, length: int,
                           decoders: list[tuple[int, Entry, str, object]]) -> TpdoHandler:
        source = self._epoch_source

        def on_tpdo(can_id: int, data: bytearray, timestamp: float) -> None:
            if len(data) < length:
                return  # not our frame (or a broken one): ignore
            epoch = source.sync_epoch
            for offset, entry, role, owner in decoders:
                value = entry.decode(data[offset : offset + entry.bits // 8])
                if role == "position":
                    owner.raw, owner.epoch = value, epoch  # type: ignore[attr-defined]
                elif role == "statusword":
                    owner.statusword_value = value & 0xFFFF  # type: ignore[attr-defined]
                elif role == "mode":
                    owner.mode_value = value  # type: ignore[attr-defined]
                else:
                    owner.error_value = value  # type: ignore[attr-defined]

        return on_tpdo

    # ------------------------------------------------------------ events

    def _on_heartbeat(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if not data:
            return
        state = data[0] & NMT_STATE_MASK
        self.last_heartbeat = time.monotonic()
        self.nmt_state = state
        if state == 0:
            self.booted.set()
            self.rebooted = True

    def _on_emcy(self, error: EmcyError) -> None:
        if error.code == 0:
            self.fault_text = None
        else:
            self.emcy = error
            self.fault_text = cia402.describe_emcy(error.code)
            logger.warning("node %d EMCY %s", self.node_id, self.fault_text)

    def heartbeat_lost(self, now: float) -> bool:
        if self.last_heartbeat is None:
            return False
        return now - self.last_heartbeat > self._hb_period * self.settings.heartbeat_timeout_factor

    # ------------------------------------------------------------ SDO configuration

    @contextlib.contextmanager
    def _sdo_errors(self, doing: str) -> Iterator[None]:
        """SDO failures as one DriveError naming the node, what it was doing and why."""
        try:
            yield
        except SdoAbortedError as exc:
            raise DriveError(f"node {self.node_id}: {doing} refused: {abort_text(exc.code)}"
                             ) from None
        except SdoCommunicationError as exc:
            raise DriveError(f"node {self.node_id}: no SDO answer {doing}: {exc}") from None

    def _sdo_write(self, entry_or_index: Entry | int, subindex: int, data: bytes,
                   what: str) -> None:
        index = entry_or_index.index if isinstance(entry_or_index, Entry) else entry_or_index
        with self._sdo_errors(f"writing {what} (0x{index:04X}:{subindex:02X})"):
            self.remote.sdo.download(index, subindex, data)

    def _write_value(self, entry: Entry, value: int, what: str) -> None:
        if entry.writable:
            self._sdo_write(entry, entry.subindex, entry.encode(value), what)

    def configure(self, warn: list[str] | None = None) -> None:
        """Reset communication, configure in PRE-OPERATIONAL, start. Blocking, bounded."""
        s = self.settings
        self.booted.clear()
        self.network.send_message(NMT_COB_ID, bytes([NmtCommand.RESET_COMMUNICATION, self.node_id]))
        if not self.booted.wait(s.boot_timeout_s):
            raise DriveError(f"node {self.node_id}: no boot-up within {s.boot_timeout_s:g} s "
                             "after NMT reset communication (powered? node id? bitrate?)")
        self.rebooted = False
        for stage in self.stages:
            stage.forget()
            if stage.mode is not None:
                self._write_value(stage.mode, int(self.mode), f"mode {self.mode.short}")
        self._configure_ramps()
        self._sdo_write(PRODUCER_HEARTBEAT_TIME, 0, s.heartbeat_ms.to_bytes(2, "little"),
                        "heartbeat producer")
        if self.has_consumer:
            ms = round(s.heartbeat_ms * s.heartbeat_timeout_factor)
            value = (s.host_node_id << 16) | min(ms, 0xFFFF)
            self._sdo_write(CONSUMER_HEARTBEAT_TIME, 1, value.to_bytes(4, "little"),
                            "heartbeat consumer")
            abort = self.axes[0].objs.get(Obj.ABORT_OPTION)
            if abort is not None:
                self._write_value(abort, cia402.ABORT_QUICK_STOP, "abort connection option")
        elif warn is not None:
            warn.append(f"node {self.node_id} ({self.eds_name}) has no heartbeat consumer (1016h):"
                        " it will not stop by itself if this host dies")
        self._configure_pdos(warn)
        for ax in self.axes:
            ax.reseed()
            ax.raw, ax.epoch = None, -1
        self.network.send_message(NMT_COB_ID, bytes([NmtCommand.START, self.node_id]))

    def _configure_ramps(self) -> None:
        """Drive ramps a little steeper than omnican's own limits, so they never lag them."""
        s = self.settings
        radius = 0.5  # m; generous for a spin's share of a wheel's acceleration
        wheel_accel = 2.0 * (s.max_accel + radius * s.max_angular_accel)
        wheel_stop = 2.0 * (s.stop_decel + radius * s.stop_angular_decel)
        for ax in self.axes:
            scale = abs(ax.wheel.velocity_scale)
            if self.mode is Mode.VELOCITY:
                for rec, rate in ((Obj.VL_ACCEL, wheel_accel), (Obj.VL_DECEL, wheel_stop)):
                    index = ax.objs.record(rec)
                    if index is not None:
                        self._sdo_write(index, 1, round(rate * scale).to_bytes(4, "little"),
                                        "vl ramp delta speed")
                        self._sdo_write(index, 2, (1).to_bytes(2, "little"), "vl ramp delta time")
                continue
            for obj, rate in ((Obj.PROFILE_ACCEL, wheel_accel), (Obj.PROFILE_DECEL, wheel_stop),
                              (Obj.QUICK_STOP_DECEL, wheel_stop)):
                entry = ax.objs.get(obj)
                if entry is not None:
                    self._write_value(entry, round(rate * scale), obj_name(obj))

    def _configure_pdos(self, warn: list[str] | None) -> None:
        try:
            self._save_plan(self.plan)
        except DriveError as exc:
            if "refused" not in str(exc):
                raise
            logger.info("node %d refuses the PDO plan (%s); using its own mapping", self.node_id,
                        exc)
            self.plan = self._adopt_existing_mapping(str(exc))
            self._build_io(self.plan)
            if warn is not None:
                warn.append(f"node {self.node_id} refuses remapping; using its own PDO mapping")

    def _save_plan(self, plan: NodePlan) -> None:
        for number in plan.unused_rpdos:
            self._disable_pdo(self.remote.rpdo[number])
        for number in plan.unused_tpdos:
            self._disable_pdo(self.remote.tpdo[number])
        for planned, maps in ((plan.rpdos, self.remote.rpdo), (plan.tpdos, self.remote.tpdo)):
            for p in planned:
                m = maps[p.number]
                m.clear()
                for entry in p.entries:
                    m.add_variable(entry.index, entry.subindex, entry.bits)
                m.cob_id, m.trans_type, m.enabled = p.cob_id, p.trans_type, True
                m.inhibit_time, m.event_timer = p.inhibit_100us, p.event_timer_ms
                self._save_map(m)

    def _disable_pdo(self, m: canopen.pdo.PdoMap) -> None:
        cob = (m.predefined_cob_id or (m.com_record.od[1].default or 0)) & COB_ID_MASK
        self._sdo_write(m.com_record.od.index, 1, (cob | COB_ID_INVALID).to_bytes(4, "little"),
                        "PDO COB-ID (disable)")

    def _save_map(self, m: canopen.pdo.PdoMap) -> None:
        with self._sdo_errors(f"configuring PDO 0x{m.com_record.od.index:04X}"):
            m.save()

    def _adopt_existing_mapping(self, reason: str) -> NodePlan:
        """Find the objects we need in the drive's fixed mapping; enable those PDOs."""
        with self._sdo_errors("reading its PDO mapping"):
            self.remote.rpdo.read()
            self.remote.tpdo.read()

        def keys(m: canopen.pdo.PdoMap) -> list[tuple[int, int]]:
            return [(v.index, v.subindex) for v in m]

        def pick(maps: canopen.pdo.PdoBase, wanted: list[Entry]) -> list[tuple[int, list[Entry]]]:
            chosen: list[tuple[int, list[Entry]]] = []
            missing = list(wanted)
            for number, m in sorted((maps.map or {}).items()):
                present = [e for e in missing if (e.index, e.subindex) in keys(m)]
                if present:
                    chosen.append((number, present))
                    missing = [e for e in missing if e not in present]
            if missing:
                names = ", ".join(f"{e.name} ({e.address})" for e in missing)
                raise DriveError(f"node {self.node_id}: refuses remapping ({reason}) and its own "
                                 f"mapping lacks {names}")
            return chosen

        rx_wanted = [a.target for a in self.axes] + [s.controlword for s in self.stages]
        tx_wanted = [a.position for a in self.axes] + [s.statusword for s in self.stages]
        rpdos: list[PlannedPdo] = []
        tpdos: list[PlannedPdo] = []
        for maps, wanted, out, tx in ((self.remote.rpdo, rx_wanted, rpdos, False),
                                      (self.remote.tpdo, tx_wanted, tpdos, True)):
            for number, _present in pick(maps, wanted):
                m = maps[number]
                entries = []
                for v in m:
                    entry = self._entry_for(v.index, v.subindex)
                    entries.append(entry)
                cyclic = tx and any(e in [a.position for a in self.axes] for e in entries)
                cyclic = cyclic or (not tx and any(e in [a.target for a in self.axes]
                                                   for e in entries))
                trans = TRANS_SYNC if cyclic else TRANS_EVENT
                cob = (m.cob_id or m.predefined_cob_id or 0) & COB_ID_MASK
                self._save_comm_only(m, cob, trans)
                out.append(PlannedPdo(number, cob, trans, tuple(entries)))
        return NodePlan(self.node_id, tuple(rpdos), tuple(tpdos),
                        notes=("fixed mapping (drive refuses remapping)",))

    def _entry_for(self, index: int, subindex: int) -> Entry:
        for ax in self.axes:
            for obj in (Obj.TARGET_VELOCITY, Obj.VL_TARGET, Obj.POSITION_ACTUAL, Obj.CONTROLWORD,
                        Obj.STATUSWORD, Obj.MODE, Obj.MODE_DISPLAY, Obj.ERROR_CODE,
                        Obj.VELOCITY_ACTUAL):
                e = ax.objs.get(obj)
                if e is not None and (e.index, e.subindex) == (index, subindex):
                    return e
        return entry_at(self.dictionary, index, subindex)  # an object we do not own: sent as 0

    def _save_comm_only(self, m: canopen.pdo.PdoMap, cob: int, trans: int) -> None:
        """Enable a PDO with its fixed mapping: COB-ID and transmission type only."""
        index = m.com_record.od.index
        self._sdo_write(index, 1, (cob | COB_ID_INVALID).to_bytes(4, "little"), "PDO COB-ID")
        if m.com_record.od[2].writable:
            self._sdo_write(index, 2, bytes([trans]), "PDO transmission type")
        if index >= TPDO_COMM and trans == TRANS_EVENT and 3 in m.com_record.od.subindices:
            self._sdo_write(index, 3, (20).to_bytes(2, "little"), "PDO inhibit time")
        self._sdo_write(index, 1, cob.to_bytes(4, "little"), "PDO COB-ID")

    # ------------------------------------------------------------ cyclic I/O

    def cyclic_frames(self, speeds: Sequence[float]) -> list[tuple[int, bytes]]:
        """SYNC-applied RPDO frames with the targets of ``speeds`` (m/s by wheel index)."""
        frames = []
        for io in self._rpdo_io:
            if not io.pdo.cyclic:
                continue
            for offset, entry, owner in io.slots:
                if isinstance(owner, AxisIO):
                    units = speeds[owner.wheel_index] * owner.wheel.velocity_scale
                    io.frame[offset : offset + entry.bits // 8] = entry.encode(round(units))
                elif isinstance(owner, StageDriver):
                    io.frame[offset : offset + entry.bits // 8] = entry.encode(owner.cw)
            frames.append((io.pdo.cob_id, bytes(io.frame)))
        return frames

    def controlword_frame(self, stage: StageDriver) -> tuple[int, bytes] | None:
        """The frame that carries ``stage``'s controlword now (None if it rides on SYNC)."""
        io, _ = self._cw_io[id(stage)]
        if io.pdo.cyclic:
            return None
        for off, entry, owner in io.slots:
            if isinstance(owner, StageDriver):
                io.frame[off : off + entry.bits // 8] = entry.encode(owner.cw)
        return io.pdo.cob_id, bytes(io.frame)

    def stop(self) -> None:
        """Stop watching the host (consumer off) and leave OPERATIONAL; best effort."""
        if self.has_consumer and self.booted.is_set():  # a node never heard has no consumer on
            try:
                self.remote.sdo.download(CONSUMER_HEARTBEAT_TIME, 1, b"\x00\x00\x00\x00")
            except (SdoAbortedError, SdoCommunicationError) as exc:
                logger.debug("node %d: clearing the heartbeat consumer failed: %s", self.node_id,
                             exc)
        self.network.send_message(NMT_COB_ID,
                                  bytes([NmtCommand.ENTER_PRE_OPERATIONAL, self.node_id]))

    def detach(self) -> None:
        for cob, handler in self._subscribed:
            if handler in self.network.subscribers.get(cob, []):
                self.network.unsubscribe(cob, handler)
        self._subscribed = []
        if self._on_heartbeat in self.network.subscribers.get(HEARTBEAT_BASE + self.node_id, []):
            self.network.unsubscribe(HEARTBEAT_BASE + self.node_id, self._on_heartbeat)
        if self.node_id in self.network.nodes:
            del self.network[self.node_id]
