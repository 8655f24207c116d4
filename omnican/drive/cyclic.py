"""A node's cyclic I/O: the RPDO frames refilled each cycle with the wheels' targets
and the controlwords, the TPDO handlers that copy positions and statuswords as they
arrive (on the receiving thread; they only copy values), and the objects a drive's
own mapping lacks, moved by expedited SDO every cycle without waiting for answers.

The control loop calls :meth:`CyclicIO.cyclic_frames` and :meth:`CyclicIO.controlword_frame`
once a cycle; :meth:`CyclicIO.build` makes everything for a PDO plan (at configuration).
"""

from __future__ import annotations

import collections
import functools
import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import can
import canopen

from omnican.clock import Clock
from omnican.config import ChassisSettings, WheelConfig
from omnican.drive.power_state import StageDriver
from omnican.io.bus import prepared_message
from omnican.plan.codec import PdoCodec
from omnican.plan.pdo import NodePlan, PlannedPdo, SdoTransfer, frame_bits
from omnican.protocol.cia301 import abort_text
from omnican.protocol.object_map import AxisObjects, Entry
from omnican.protocol.sdo_cycle import (
    SDO_REQUEST_BASE,
    Answer,
    AnswerKind,
    download_request,
    parse_answer,
    upload_request,
)

logger = logging.getLogger("omnican.drive")

_MAX_PENDING = 8  # unanswered per-cycle SDO requests kept (a silent drive must not grow them)


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
    # Position samples (written as frames are received: by the loop's own poll while the
    # base runs, by python-can's Notifier before; read by the loop): a CounterSample,
    # folded into travel by the chassis' WheelOdometry.
    raw: int | None = None
    epoch: int = -1
    restarts: int = 0  # times the counter restarted (reseed)

    def reseed(self) -> None:
        """After a reboot the counter restarts: the next sample continues the travel."""
        self.restarts += 1


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
    _cw_stages: tuple[StageDriver, ...] = ()  # the stages whose controlwords it carries
    #: their controlwords now, in one call: () for none, the one stage's ``cw`` (a C call,
    #: no Python frame: the usual RPDO carries one), a tuple for several
    _cws: Callable[[], object] = tuple
    #: the plan's own layout, targets then controlwords, as (wheel index, scale, lowest,
    #: highest) per target (None: another layout, field by field); and whether ``_cws``
    #: gives one controlword (an int) rather than a tuple of them
    _targets: tuple[tuple[int, float, int, int], ...] | None = None
    _one_cw: bool = False
    _filled: tuple[object, object] | None = None  # (speeds, controlwords) in msg

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
            self._filled = None
            return
        # The loop passes the same list while its targets hold (lists it never changes).
        cws = self._cws()
        filled = self._filled
        if filled is not None and filled[0] is speeds and filled[1] == cws:
            return  # the frame holds these targets and controlwords already
        self._filled = (speeds, cws)
        out = []
        targets = self._targets
        if targets is not None:  # targets, then the controlwords: each cycle's usual frame
            for i, scale, lo, hi in targets:
                v = round(speeds[i] * scale)
                out.append(lo if v < lo else hi if v > hi else v)
            if self._one_cw:
                out.append(cws)  # type: ignore[arg-type]
            else:
                out += cws  # type: ignore[arg-type]
            self.msg.data = self._pack(*out)  # type: ignore[assignment]
            return
        for (ax, scale, stage), (lo, hi) in self._fields:
            v = (round(speeds[ax.wheel_index] * scale) if ax is not None else
                 stage.cw if stage is not None else 0)
            out.append(lo if v < lo else hi if v > hi else v)
        self.msg.data = self._pack(*out)  # type: ignore[assignment]

    def seal(self) -> None:
        """Compile :meth:`fill` once ``sources`` is complete."""
        self._fields = tuple(zip(self.sources, self.codec.ranges, strict=True))
        self._pack = self.codec.packer()
        stages = self._cw_stages = tuple(stage for _, _, stage in self.sources
                                         if stage is not None)
        self._one_cw = len(stages) == 1
        if self._one_cw:
            self._cws = functools.partial(getattr, stages[0], "cw")
        elif stages:
            self._cws = lambda: tuple([stage.cw for stage in stages])
        else:
            self._cws = tuple
        # Targets first, then controlwords each in a field that holds any (16 bits or
        # more, unsigned): filled without a look at each field's kind or a clamp of the
        # controlwords.
        n = sum(1 for ax, _, _ in self.sources if ax is not None)
        head, tail = self._fields[:n], self._fields[n:]
        plain = (all(ax is not None for (ax, _, _), _ in head) and
                 all(ax is None and stage is not None and lo <= 0 and hi >= 0xFFFF
                     for (ax, _, stage), (lo, hi) in tail))
        self._targets = tuple((ax.wheel_index, scale, lo, hi)  # type: ignore[union-attr]
                              for (ax, scale, _), (lo, hi) in head) if plain else None
        self._filled = None


@dataclass
class _SdoIO:
    """One object moved by expedited SDO.

    ``pending`` holds (sent at, SYNC epoch) of each unanswered request, oldest first:
    the loop appends, the receiving thread pops (the loop's poll while the base runs, the
    Notifier before; deque operations are atomic). A server
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
    answers: int = 0  # the receiving thread
    aborts: int = 0  # the receiving thread
    last_abort: str | None = None  # e.g. "Target velocity (0x60FF:00): 0x06090030 ..."




class CyclicIO:
    """The cyclic frames of one node (see the module docstring)."""

    def __init__(self, network: canopen.Network, remote: canopen.RemoteNode, node_id: int,
                 axes: list[AxisIO], stages: list[StageDriver], epoch_source: EpochSource,
                 settings: ChassisSettings, clock: Clock) -> None:
        self.network = network
        self.remote = remote
        self.node_id = node_id
        self.axes = axes
        self.stages = stages
        self._epoch_source = epoch_source
        self.settings = settings
        self.clock = clock
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
        #: takes the node's other SDO answers first (its health reads), True when taken
        self.answer_hook: Callable[[Answer], bool] | None = None

    def build(self, plan: NodePlan) -> SdoCounts:
        """Frames, handlers and SDO transfers for ``plan``; returns the new counts."""
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
        self.route_sdo_answers(bool(sdo_io) or self.answer_hook is not None)
        return self.sdo_counts

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

    def route_sdo_answers(self, on: bool) -> None:
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
            hook = self.answer_hook
            if answer is not None and hook is not None and hook(answer):
                return  # a health read's
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
        bits); None if it goes every cycle anyway (on the cyclic RPDO, or by SDO)."""
        by_sdo = self._sdo_cw.get(id(stage))
        if by_sdo is not None:
            if by_sdo.transfer.cyclic:
                return None
            cob, data = self._sdo_request(by_sdo, (), -1)
            return prepared_message(cob, data), frame_bits(len(data))
        io = self._cw_io[id(stage)]
        if io.pdo.cyclic:
            return None
        io.msg.data = io.codec.pack(io.values(()))  # type: ignore[assignment]
        return io.msg, io.bits


    def detach(self) -> None:
        for cob, handler in self._subscribed:
            if handler in self.network.subscribers.get(cob, []):
                self.network.unsubscribe(cob, handler)
        self._subscribed = []
        self.route_sdo_answers(False)  # canopen's SDO client back, for remove_network()
