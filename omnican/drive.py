"""One CANopen node driving one or more wheels (axes): configuration, units, PDO I/O.

* :meth:`DriveNode.configure` (SDO, blocking, bounded): NMT reset communication and
  boot-up, the PDO plan of :mod:`omnican.pdoplan` (or, for a drive that refuses it,
  its own mapping, restored by another reset communication; objects that mapping
  lacks go by expedited SDO every cycle), mode, ramps, heartbeat producer and
  consumer, 6007h, then NMT OPERATIONAL.
* Frame handlers run on the Notifier thread and only copy values.
* The control loop calls :meth:`DriveNode.cyclic_frames` (targets, and the requests
  of objects moved by SDO), and :class:`StageDriver` walks each CiA 402 state
  machine with controlword bit masks.

Units: m/s at the rim <-> drive velocity units (``velocity_scale``); encoder counts
-> continuous metres of travel across counter wrap-around and drive reboots.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import threading
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import can
import canopen
from canopen.emcy import EmcyError
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from omnican import cia402, heartbeat
from omnican.bus import prepared_message
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
    NmtState,
    abort_text,
)
from omnican.cia402 import Command, Mode, State
from omnican.clock import REAL_TIME, Clock
from omnican.config import WheelConfig
from omnican.errors import DriveError
from omnican.layout import NodeLayout
from omnican.logthrottle import Throttle
from omnican.odmap import AxisObjects, Entry, Obj, entry_at, obj_name
from omnican.pdoplan import NodePlan, PlannedPdo, SdoTransfer, frame_bits
from omnican.sdocycle import (
    SDO_REQUEST_BASE,
    AnswerKind,
    download_request,
    parse_answer,
    upload_request,
)
from omnican.wire import PdoCodec

logger = logging.getLogger(__name__)

_UNKNOWN = State.UNKNOWN  # a plain name: State.X is a descriptor call on Python 3.11
# Power stages with no torque: nothing to disable on the way out.
_OFF_STATES = frozenset({State.SWITCH_ON_DISABLED, State.NOT_READY_TO_SWITCH_ON, State.FAULT})
_MAX_PENDING = 8  # unanswered per-cycle SDO requests kept (a silent drive must not grow them)
_EMCY_KEPT = 32  # EMCYs canopen keeps per node (its log and active list), newest last
BOOT_RESETS = 4  # NMT resets sent (within boot_timeout_s) before a node counts as absent
LOCKSTEP_SDO_WAIT_S = 0.001  # lock-step: an answer is in the queue when its request was sent


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
    _half_span: int = field(init=False, repr=False, default=0)

    def travel_from_sample(self, raw: int) -> float:
        """Fold a raw counter value into continuous counts; returns travel in m.
        :func:`fold_counter`, written out (each cycle, each wheel)."""
        last = self.last_raw
        self.last_raw = raw
        if last is not None:
            half = self._half_span
            self.counts += (raw - last + half) % (half << 1) - half
        return self.counts / self.wheel.position_scale

    def __post_init__(self) -> None:
        self._half_span = 1 << (self.position.bits - 1)

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
        if state is self.goal or state is _UNKNOWN:
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
            # Said once, by whoever waits for the goal (open(), recover()): not here too.
            logger.info("%s", self.error)
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
    """One RPDO: its codec, the frame sent every time (made once), and what fills each
    field: a wheel's target (its scale), a stage's controlword, or 0 (an object of a
    drive's fixed mapping that omnican does not own)."""

    pdo: PlannedPdo
    codec: PdoCodec
    msg: can.Message
    bits: int
    sources: list[tuple[AxisIO | None, float, StageDriver | None]] = field(
        default_factory=list)
    _fields: tuple[tuple[tuple[AxisIO | None, float, StageDriver | None],
                         tuple[int, int]], ...] = ()
    _pack: Callable[..., bytes] = bytes

    def values(self, speeds: Sequence[float]) -> list[int]:
        """Field values for ``speeds`` (m/s by wheel index; empty: targets 0)."""
        if not speeds:
            return [stage.cw if stage is not None else 0 for _, _, stage in self.sources]
        return [round(speeds[ax.wheel_index] * scale) if ax is not None else
                stage.cw if stage is not None else 0
                for ax, scale, stage in self.sources]

    def fill(self, speeds: Sequence[float]) -> None:
        """Refill the frame for ``speeds``: ``codec.pack(values(speeds))`` in one call
        (each cycle, for each RPDO): values clamped as they are made, the compiled
        struct called directly."""
        if not speeds:
            self.msg.data = self.codec.pack(self.values(speeds))  # type: ignore[assignment]
            return
        out = []
        for (ax, scale, stage), (lo, hi) in self._fields:
            v = (round(speeds[ax.wheel_index] * scale) if ax is not None else
                 stage.cw if stage is not None else 0)
            out.append(lo if v < lo else hi if v > hi else v)
        self.msg.data = self._pack(*out)  # type: ignore[assignment]

    def seal(self) -> None:
        """Compile :meth:`fill` once ``sources`` is complete."""
        self._fields = tuple(zip(self.sources, self.codec.ranges, strict=True))
        self._pack = self.codec.packer()


@dataclass
class _SdoIO:
    """One object moved by expedited SDO.

    ``pending`` holds (sent at, SYNC epoch) of each unanswered request, oldest first:
    the loop appends, the Notifier thread pops (deque operations are atomic). A server
    answers in order, so an answer belongs to the oldest request not yet given up."""

    transfer: SdoTransfer
    role: str  # "target", "controlword", "position" or "statusword"
    owner: AxisIO | StageDriver
    pending: collections.deque[tuple[float, int]] = field(
        default_factory=lambda: collections.deque(maxlen=_MAX_PENDING))


@dataclass
class SdoCounts:
    """Per-cycle SDO transfers of one node since it was configured."""

    requests: int = 0  # loop thread
    answers: int = 0  # Notifier thread
    aborts: int = 0  # Notifier thread
    last_abort: str | None = None  # e.g. "Target velocity (0x60FF:00): 0x06090030 ..."


class DriveNode:
    """One node of the base, with the wheels (axes) it drives, on a live network."""

    def __init__(self, network: canopen.Network, layout: NodeLayout,
                 epoch_source: EpochSource, clock: Clock = REAL_TIME) -> None:
        self.layout = layout
        self.clock = clock
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
        # canopen's MAX_RETRIES counts attempts, not retries. In lock-step an answer arrives
        # inside its request's send, or never: nothing to wait for.
        self.remote.sdo.RESPONSE_TIMEOUT = (LOCKSTEP_SDO_WAIT_S if clock.lockstep
                                            else settings.sdo_timeout_s)
        self.remote.sdo.MAX_RETRIES = settings.sdo_retries + 1
        network.add_node(self.remote)
        self.stages = [StageDriver(node_id, s.controlword, s.statusword, s.mode, s.mode_display,
                                   s.error_code, settings.enable_timeout_s)
                       for s in layout.stages]
        self.axes = [AxisIO(a.wheel_index, a.wheel, a.objs, a.target, a.position,
                            self.stages[a.stage]) for a in layout.axes]
        self._rpdo_io: list[_RpdoIO] = []
        self._cyclic_io: list[_RpdoIO] = []
        self._cyclic_frames: list[tuple[can.Message, int]] = []
        self._cw_io: dict[int, _RpdoIO] = {}  # id(stage) -> the RPDO carrying its controlword
        self._subscribed: list[tuple[int, TpdoHandler]] = []
        self._sdo_io: dict[tuple[int, int], _SdoIO] = {}  # (index, subindex) -> transfer
        self._sdo_cyclic: list[_SdoIO] = []
        self._sdo_cw: dict[int, _SdoIO] = {}  # id(stage) -> controlword by SDO
        self.sdo_counts = SdoCounts()
        self._aborts_logged = 0
        self._refusal: str | None = None  # why the drive refused the plan (then: its own)
        self._build_io(self.plan)
        # Liveness and events (Notifier thread writes; loop reads).
        self.last_heartbeat: float | None = None
        self.nmt_state: int | None = None
        # Heard OPERATIONAL since its configuration: a node that then reports another
        # state left OPERATIONAL (another master, its own doing); one that never did may
        # only have missed its start.
        self.seen_operational = False
        self.twins = False  # two devices answer as this node: never configured, never talked to
        # Boot-ups seen (only the Notifier thread writes it) and the one the present
        # configuration followed (only the configuring thread writes it): a drive that
        # booted since it was configured has lost its configuration.
        self.boot_count = 0
        self.configured_boot = 0
        self._boot_seen = threading.Condition()
        self.emcy: EmcyError | None = None
        self._emcy_log = Throttle(logger, clock=clock.now)
        self.fault_text: str | None = None
        self._hb_timeout = heartbeat.timeout_s(settings.heartbeat_ms / 1000.0,
                                               settings.heartbeat_timeout_factor)
        network.subscribe(HEARTBEAT_BASE + node_id, self._on_heartbeat)
        self.remote.emcy.add_callback(self._on_emcy)

    def _build_io(self, plan: NodePlan) -> None:
        for cob, handler in self._subscribed:
            self.network.unsubscribe(cob, handler)
        self._subscribed = []
        rpdo_io: list[_RpdoIO] = []
        cw_io: dict[int, _RpdoIO] = {}
        for pdo in plan.rpdos:
            codec = PdoCodec(pdo)
            io = _RpdoIO(pdo, codec, prepared_message(pdo.cob_id, bytes(codec.length)),
                         frame_bits(codec.length))
            for f in codec.fields:
                key = (f.entry.index, f.entry.subindex)
                axis = next((ax for ax in self.axes
                             if (ax.target.index, ax.target.subindex) == key), None)
                stage = next((st for st in self.stages
                              if (st.controlword.index, st.controlword.subindex) == key), None)
                if stage is not None:
                    cw_io[id(stage)] = io
                scale = axis.wheel.velocity_scale if axis is not None else 0.0
                io.sources.append((axis, scale, stage))
            io.seal()
            rpdo_io.append(io)
        # Swapped whole: the loop may be sending from the old ones meanwhile.
        self._rpdo_io, self._cw_io = rpdo_io, cw_io
        self._cyclic_io = [io for io in rpdo_io if io.pdo.cyclic]
        self._cyclic_frames = [(io.msg, io.bits) for io in self._cyclic_io]
        for pdo in plan.tpdos:
            codec = PdoCodec(pdo)
            roles: list[tuple[int, str, object]] = []
            for i, f in enumerate(codec.fields):
                key = (f.entry.index, f.entry.subindex)
                for ax in self.axes:
                    if key == (ax.position.index, ax.position.subindex):
                        roles.append((i, "position", ax))
                for stage in self.stages:
                    for role, e in (("statusword", stage.statusword), ("mode", stage.mode_display),
                                    ("error", stage.error_code)):
                        if e is not None and key == (e.index, e.subindex):
                            roles.append((i, role, stage))
            handler = self._make_tpdo_handler(codec, roles)
            self.network.subscribe(pdo.cob_id, handler)
            self._subscribed.append((pdo.cob_id, handler))
        sdo_io = {}
        for transfer in plan.sdo:
            role, owner = self._owner_of(transfer.entry)
            sdo_io[(transfer.entry.index, transfer.entry.subindex)] = _SdoIO(transfer, role, owner)
        self._sdo_cyclic = [io for io in sdo_io.values() if io.transfer.cyclic]
        self._sdo_cw = {id(io.owner): io for io in sdo_io.values() if io.role == "controlword"}
        self._sdo_io = sdo_io
        self.sdo_counts, self._aborts_logged = SdoCounts(), 0
        self._route_sdo_answers(bool(sdo_io))

    def _owner_of(self, entry: Entry) -> tuple[str, AxisIO | StageDriver]:
        key = (entry.index, entry.subindex)
        for ax in self.axes:
            for role, e in (("target", ax.target), ("position", ax.position)):
                if key == (e.index, e.subindex):
                    return role, ax
        for stage in self.stages:
            for role, e in (("controlword", stage.controlword), ("statusword", stage.statusword)):
                if key == (e.index, e.subindex):
                    return role, stage
        raise ValueError(f"node {self.node_id}: {entry.name} ({entry.address}) is no object "
                         "omnican moves by SDO")

    def _route_sdo_answers(self, on: bool) -> None:
        """While objects go by SDO every cycle, their answers must not reach canopen's SDO
        client of this node: its queue would grow without end, and a configuration SDO
        could take a cycle's answer for its own (canopen does not check the index of a
        download answer). One handler then takes the node's 0x580 frames and hands the
        client only the rest."""
        cob, client = self.remote.sdo.tx_cobid, self.remote.sdo.on_response
        subscribed = self.network.subscribers.get(cob, [])
        if on and self._on_sdo_answer not in subscribed:
            self.network.subscribe(cob, self._on_sdo_answer)
            if client in subscribed:
                self.network.unsubscribe(cob, client)
        elif not on and self._on_sdo_answer in subscribed:
            self.network.subscribe(cob, client)
            self.network.unsubscribe(cob, self._on_sdo_answer)

    def _on_sdo_answer(self, can_id: int, data: bytearray, timestamp: float) -> None:
        answer = parse_answer(data)
        io = None if answer is None else self._sdo_io.get((answer.index, answer.subindex))
        if answer is None or io is None or not io.pending or answer.kind not in (
                AnswerKind.ABORTED,
                AnswerKind.DOWNLOADED if io.transfer.write else AnswerKind.UPLOADED):
            self.remote.sdo.on_response(can_id, data, timestamp)  # a configuration SDO's
            return
        given_up = self.clock.now() - self.settings.sdo_timeout_s
        while len(io.pending) > 1 and io.pending[0][0] < given_up:
            io.pending.popleft()  # its answer was lost: do not take this one for it
        try:
            _sent_at, epoch = io.pending.popleft()
        except IndexError:  # pragma: no cover - only the loop's maxlen drop races with this
            return
        counts = self.sdo_counts
        if answer.kind is AnswerKind.ABORTED:
            counts.aborts += 1
            entry = io.transfer.entry
            counts.last_abort = f"{entry.name} ({entry.address}): {abort_text(answer.abort_code)}"
            return
        counts.answers += 1
        if answer.kind is AnswerKind.UPLOADED:
            entry = io.transfer.entry
            value = entry.decode(answer.data.ljust(entry.bits // 8, b"\x00"))
            if io.role == "position":
                io.owner.raw, io.owner.epoch = value, epoch  # type: ignore[union-attr]
            elif io.role == "statusword":
                io.owner.statusword_value = value & 0xFFFF  # type: ignore[union-attr]

    def _make_tpdo_handler(self, codec: PdoCodec,
                           roles: list[tuple[int, str, object]]) -> TpdoHandler:
        """A handler that unpacks the whole TPDO in one call and copies the values."""
        source = self._epoch_source
        unpack = codec.unpacker()
        length = codec.length
        positions = tuple((i, o) for i, r, o in roles if r == "position")
        others = tuple((i, r, o) for i, r, o in roles if r != "position")

        def on_tpdo(can_id: int, data: bytearray, timestamp: float) -> None:
            if len(data) < length:
                return  # not our frame (or a broken one): ignore
            values = unpack(data)
            if values is None:
                return
            epoch = source.sync_epoch
            for i, ax in positions:
                ax.raw, ax.epoch = values[i], epoch  # type: ignore[attr-defined]
            for i, role, owner in others:
                if role == "statusword":
                    owner.statusword_value = values[i] & 0xFFFF  # type: ignore[attr-defined]
                elif role == "mode":
                    owner.mode_value = values[i]  # type: ignore[attr-defined]
                else:
                    owner.error_value = values[i]  # type: ignore[attr-defined]

        return on_tpdo

    # ------------------------------------------------------------ events

    def _on_heartbeat(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if not data:
            return
        state = data[0] & NMT_STATE_MASK
        self.last_heartbeat = self.clock.now()
        self.nmt_state = state
        if state == NmtState.OPERATIONAL:
            self.seen_operational = True
        if state == 0:
            with self._boot_seen:
                self.boot_count += 1
                self._boot_seen.notify_all()

    @property
    def rebooted(self) -> bool:
        """The drive booted since its configuration (so it lost that configuration)."""
        return self.boot_count != self.configured_boot

    def _on_emcy(self, error: EmcyError) -> None:
        emcy = self.remote.emcy  # canopen keeps every EMCY: a storm would fill the memory
        with emcy.emcy_received:
            for kept in (emcy.log, emcy.active):
                if len(kept) > _EMCY_KEPT:
                    del kept[:-_EMCY_KEPT]
        if error.code == 0:
            self.fault_text = None
        else:
            self.emcy = error
            self.fault_text = cia402.describe_emcy(error.code)
            # A drive in an EMCY storm (or a device imitating one) gets a line every few
            # seconds per code, with a count, not one per frame.
            self._emcy_log.warning(error.code, "node %d EMCY %s", self.node_id, self.fault_text)

    def heartbeat_lost(self, now: float) -> bool:
        if self.last_heartbeat is None:
            return False
        return now - self.last_heartbeat > self._hb_timeout

    # ------------------------------------------------------------ SDO configuration

    @contextlib.contextmanager
    def _sdo_errors(self, doing: str) -> Iterator[None]:
        """SDO failures as one DriveError naming the node, what it was doing and why."""
        try:
            yield
        except SdoAbortedError as exc:
            raise DriveError(f"node {self.node_id}: {doing} refused: {abort_text(exc.code)}"
                             ) from None
        except SdoCommunicationError:
            sdo = self.remote.sdo
            wait = self.settings.sdo_timeout_s if not self.clock.lockstep else 0.0
            raise DriveError(f"node {self.node_id}: no SDO answer {doing} ({sdo.MAX_RETRIES} "
                             f"attempts{f', {wait:g} s each' if wait else ''})") from None

    def _sdo_write(self, entry_or_index: Entry | int, subindex: int, data: bytes,
                   what: str) -> None:
        index = entry_or_index.index if isinstance(entry_or_index, Entry) else entry_or_index
        with self._sdo_errors(f"writing {what} (0x{index:04X}:{subindex:02X})"):
            self.remote.sdo.download(index, subindex, data)

    def _write_value(self, entry: Entry, value: int, what: str) -> None:
        if entry.writable:
            self._sdo_write(entry, entry.subindex, entry.encode(value), what)

    def configure(self, warn: list[str] | None = None) -> None:
        """Reset communication, configure in PRE-OPERATIONAL, start. Blocking, bounded.

        Raises DriveError naming the node and what it was doing; also when two devices
        answer as this node (each boot-up and SDO answer comes twice), before it starts."""
        with self._counting_sdo_answers():
            self._configure(warn)
        self.network.send_message(NMT_COB_ID, bytes([NmtCommand.START, self.node_id]))

    def _configure(self, warn: list[str] | None) -> None:
        s = self.settings
        self.seen_operational = False
        self._reset_communication()
        # PDOs first: a drive that refuses the plan is reset once more to get its own
        # mapping back, which also resets what is set below in 1000h-1FFFh (1016h, 1017h).
        self._configure_pdos(warn)
        for stage in self.stages:
            stage.forget()
            if stage.mode is not None:
                self._write_value(stage.mode, int(self.mode), f"mode {self.mode.short}")
        self._configure_ramps()
        self._sdo_write(PRODUCER_HEARTBEAT_TIME, 0, s.heartbeat_ms.to_bytes(2, "little"),
                        "heartbeat producer")
        if self.has_consumer:
            ms = heartbeat.consumer_time_ms(s.heartbeat_ms, s.heartbeat_timeout_factor)
            value = (s.host_node_id << 16) | ms
            self._sdo_write(CONSUMER_HEARTBEAT_TIME, 1, value.to_bytes(4, "little"),
                            "heartbeat consumer")
            abort = self.axes[0].objs.get(Obj.ABORT_OPTION)
            if abort is not None:
                self._write_value(abort, cia402.ABORT_QUICK_STOP, "abort connection option")
        elif warn is not None:
            warn.append(f"node {self.node_id} ({self.eds_name}) has no heartbeat consumer (1016h):"
                        " it will not stop by itself if this host dies")
        for ax in self.axes:
            ax.reseed()
            ax.raw, ax.epoch = None, -1
        self._drop_canopen_pdo_handlers()

    def _drop_canopen_pdo_handlers(self) -> None:
        """canopen's PdoMap subscribes its own decoder to each PDO it saves or reads;
        omnican decodes the frames itself, so that work (every frame, every cycle) goes."""
        for maps in (self.remote.rpdo, self.remote.tpdo):
            for m in (maps.map or {}).values():
                cob = m.cob_id
                if cob is not None and m.on_message in self.network.subscribers.get(cob, []):
                    self.network.unsubscribe(cob, m.on_message)

    def _reset_communication(self) -> None:
        """NMT reset communication and wait for the boot-up: the drive's 1000h-1FFFh
        (PDOs, heartbeat) are back at their power-on values. A reset or a boot-up lost on
        the way is asked for again, up to ``BOOT_RESETS`` times within boot_timeout_s."""
        s = self.settings
        wait = 0.0 if self.clock.lockstep else s.boot_timeout_s / BOOT_RESETS
        with self._boot_seen:
            before = self.boot_count
        booted = resets = 0
        while not booted and resets < BOOT_RESETS:
            resets += 1
            self.network.send_message(NMT_COB_ID,
                                      bytes([NmtCommand.RESET_COMMUNICATION, self.node_id]))
            with self._boot_seen:
                if self._boot_seen.wait_for(lambda: self.boot_count != before, wait):
                    booted = self.boot_count - before
        if not booted:
            within = f" within {s.boot_timeout_s:g} s" if wait else ""
            raise DriveError(f"node {self.node_id}: no boot-up{within} after NMT reset "
                             f"communication (sent {BOOT_RESETS} times; powered? node id? "
                             "bitrate?)")
        if resets == 1 and booted > 1:  # one reset, two boot-ups
            self.twins = True
            raise DriveError(self._twins(f"{booted} boot-ups answered one NMT reset"))
        with self._boot_seen:
            self.configured_boot = self.boot_count

    def _twins(self, evidence: str) -> str:
        return (f"node {self.node_id}: two devices answer as node {self.node_id} ({evidence}): "
                "a cloned drive? give each its own node id")

    @contextlib.contextmanager
    def _counting_sdo_answers(self) -> Iterator[None]:
        """Count this node's SDO answers against the requests sent meanwhile: a second
        device on the same id answers every request too."""
        answers = [0]

        def count(can_id: int, data: bytearray, timestamp: float) -> None:
            answers[0] += 1

        requests: dict[int, int] = getattr(self.network, "sdo_requests", {})
        asked = requests.get(self.node_id, 0)
        cob = self.remote.sdo.tx_cobid

        def twins() -> str | None:
            sent = requests.get(self.node_id, 0) - asked
            if sent and answers[0] >= 3 + 1.5 * sent:
                self.twins = True
                return self._twins(f"{answers[0]} SDO answers to {sent} requests")
            return None

        self.network.subscribe(cob, count)
        try:
            yield
        except DriveError:
            found = twins()  # what failed may be the second device's doing
            if found is not None:
                raise DriveError(found) from None
            raise
        finally:
            self.network.unsubscribe(cob, count)
        found = twins()
        if found is not None:
            raise DriveError(found)

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
        """The plan; else (the drive refuses it) the drive's own mapping; what neither
        carries goes by expedited SDO every cycle."""
        planned = self.layout.plan
        if planned.tried and self._refusal is None:
            names = ", ".join(f"{e.name} ({e.address})" for e in planned.tried)
            _tell(warn, f"node {self.node_id} ({self.eds_name}): its EDS marks {names} not "
                  "PDO-mappable; mapping anyway (chassis.pdo_mapping = \"try\")")
        plan = planned
        if self._refusal is None:
            try:
                self._save_plan(planned)
            except DriveError as exc:
                if "refused" not in str(exc):
                    raise
                self._refusal = str(exc)
                logger.info("node %d refuses the PDO plan (%s); using its own mapping",
                            self.node_id, exc)
                self._reset_communication()  # undoes what was written: its own mapping again
        if self._refusal is not None:  # also after a reboot: not worth another refusal
            plan = self._adopt_existing_mapping(self._refusal)
            why = self._refusal.rpartition("refused: ")[2]
            _tell(warn, f"node {self.node_id} refuses remapping ({why}); using its own PDO mapping")
        if plan.sdo:
            names = ", ".join(f"{t.entry.name} ({t.entry.address})" for t in plan.sdo)
            _tell(warn, f"node {self.node_id}: {names} by expedited SDO every cycle "
                  f"(+{plan.sdo_bits()} bits per cycle)")
        self.plan = plan
        self._build_io(plan)

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

        def pick(maps: canopen.pdo.PdoBase,
                 wanted: list[Entry]) -> tuple[list[tuple[int, list[Entry]]], list[Entry]]:
            chosen: list[tuple[int, list[Entry]]] = []
            missing = list(wanted)
            for number, m in sorted((maps.map or {}).items()):
                present = [e for e in missing if (e.index, e.subindex) in keys(m)]
                if present:
                    chosen.append((number, present))
                    missing = [e for e in missing if e not in present]
            return chosen, missing

        targets = [a.target for a in self.axes]
        rx_wanted = targets + [s.controlword for s in self.stages]
        tx_wanted = [a.position for a in self.axes] + [s.statusword for s in self.stages]
        rpdos: list[PlannedPdo] = []
        tpdos: list[PlannedPdo] = []
        sdo: list[SdoTransfer] = []
        for maps, wanted, out, tx in ((self.remote.rpdo, rx_wanted, rpdos, False),
                                      (self.remote.tpdo, tx_wanted, tpdos, True)):
            chosen, missing = pick(maps, wanted)
            # Last resort: targets and controlwords written, positions and statuswords
            # read, by SDO (every cycle; controlwords when they change).
            sdo += [SdoTransfer(e, write=not tx, cyclic=tx or e in targets) for e in missing]
            for number, _present in chosen:
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
        logger.debug("node %d: own mapping adopted (%s)", self.node_id, reason)
        return NodePlan(self.node_id, tuple(rpdos), tuple(tpdos),
                        notes=("fixed mapping (drive refuses remapping)",), sdo=tuple(sdo))

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

    def cyclic_frames(self, speeds: Sequence[float]) -> list[tuple[can.Message, int]]:
        """SYNC-applied RPDO frames with the targets of ``speeds`` (m/s by wheel index),
        then the requests of the objects moved by SDO every cycle, as (frame, worst-case
        bits). The RPDO frames, and the list itself when no object goes by SDO, are
        made once and refilled: send them before the next call, and do not change the
        list. Called once per cycle, before the cycle's SYNC: a read requested now
        belongs to that SYNC."""
        for io in self._cyclic_io:
            io.fill(speeds)
        if not self._sdo_cyclic:
            return self._cyclic_frames
        frames = list(self._cyclic_frames)
        epoch = self._epoch_source.sync_epoch + 1  # the SYNC this cycle sends next
        for sdo in self._sdo_cyclic:
            cob, data = self._sdo_request(sdo, speeds, epoch)
            frames.append((prepared_message(cob, data), frame_bits(len(data))))
        counts = self.sdo_counts
        if counts.aborts != self._aborts_logged:
            self._aborts_logged = counts.aborts
            logger.warning("node %d: per-cycle SDO aborted (%d so far), last: %s",
                           self.node_id, counts.aborts, counts.last_abort)
        return frames

    def _sdo_request(self, io: _SdoIO, speeds: Sequence[float], epoch: int) -> tuple[int, bytes]:
        entry = io.transfer.entry
        if not io.transfer.write:
            data = upload_request(entry.index, entry.subindex)
        elif isinstance(io.owner, AxisIO):
            units = speeds[io.owner.wheel_index] * io.owner.wheel.velocity_scale
            data = download_request(entry.index, entry.subindex, entry.encode(round(units)))
        else:
            data = download_request(entry.index, entry.subindex, entry.encode(io.owner.cw))
        io.pending.append((self.clock.now(), epoch))  # before the request can be answered
        self.sdo_counts.requests += 1
        return SDO_REQUEST_BASE + self.node_id, data

    def controlword_frame(self, stage: StageDriver) -> tuple[can.Message, int] | None:
        """The frame that carries ``stage``'s controlword now, as (frame, worst-case
        bits); None if it rides on the cyclic RPDO."""
        by_sdo = self._sdo_cw.get(id(stage))
        if by_sdo is not None:
            cob, data = self._sdo_request(by_sdo, (), -1)
            return prepared_message(cob, data), frame_bits(len(data))
        io = self._cw_io[id(stage)]
        if io.pdo.cyclic:
            return None
        io.msg.data = io.codec.pack(io.values(()))  # type: ignore[assignment]
        return io.msg, io.bits

    def stop(self) -> None:
        """Disable any power stage not known to be off, stop watching the host (consumer
        off) and leave OPERATIONAL; best effort."""
        # A bus that refuses frames (down, transmit queue full) must not turn the way
        # out into a traceback: the drives' heartbeat consumers stop them anyway.
        if not self.boot_count or self.twins:
            return  # never heard, or two devices answering as one: nothing was enabled
        for stage in self.stages:
            # The loop's disable did not get there (it did not run, or not for long
            # enough); a STOPPED node answers no SDO (its 6007h reaction stopped it).
            if stage.state not in _OFF_STATES and self.nmt_state != NmtState.STOPPED:
                cw = stage.controlword
                off = cia402.apply_command(stage.cw, Command.DISABLE_VOLTAGE)
                try:
                    self.remote.sdo.download(cw.index, cw.subindex, cw.encode(off))
                    sw = stage.statusword  # what it is now, for the closing line
                    raw = self.remote.sdo.upload(sw.index, sw.subindex)
                    stage.statusword_value = sw.decode(raw) & 0xFFFF
                except (SdoAbortedError, SdoCommunicationError, can.CanError, OSError) as exc:
                    logger.warning("node %d: disabling its drive by SDO failed: %s",
                                   self.node_id, exc)
        if self.has_consumer:
            try:
                self.remote.sdo.download(CONSUMER_HEARTBEAT_TIME, 1, b"\x00\x00\x00\x00")
            except (SdoAbortedError, SdoCommunicationError, can.CanError, OSError) as exc:
                logger.debug("node %d: clearing the heartbeat consumer failed: %s", self.node_id,
                             exc)
        try:
            self.network.send_message(NMT_COB_ID,
                                      bytes([NmtCommand.ENTER_PRE_OPERATIONAL, self.node_id]))
        except (can.CanError, OSError, RuntimeError) as exc:
            logger.debug("node %d: NMT pre-operational not sent: %s", self.node_id, exc)

    def detach(self) -> None:
        self._emcy_log.flush()
        for cob, handler in self._subscribed:
            if handler in self.network.subscribers.get(cob, []):
                self.network.unsubscribe(cob, handler)
        self._subscribed = []
        self._route_sdo_answers(False)  # canopen's SDO client back, for remove_network()
        if self._on_heartbeat in self.network.subscribers.get(HEARTBEAT_BASE + self.node_id, []):
            self.network.unsubscribe(HEARTBEAT_BASE + self.node_id, self._on_heartbeat)
        if self.node_id in self.network.nodes:
            del self.network[self.node_id]


def _tell(warn: list[str] | None, text: str) -> None:
    """A warning for the user: into ``warn`` at startup (the chassis shows them), else the log."""
    if warn is not None:
        warn.append(text)
    else:
        logger.warning("%s", text)
