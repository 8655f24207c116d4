"""The PDOs of a simulated node at run time: RPDOs written into its object dictionary,
TPDOs sent on SYNC and on events.

The node takes its PDOs from the dictionary when it enters OPERATIONAL
(:func:`omnican.sim.pdo.read_pdos`) and keeps them until it leaves. canopen's
LocalNode does neither half (canopen #555, #558). Synchronous RPDOs wait for the next
SYNC; synchronous TPDOs go every n-th SYNC (or on a change, type 0); event-driven
TPDOs go when their data changes or their event timer runs out, no sooner than their
inhibit time allows.

The node decides whether a frame is taken at all (NMT state, frame loss, a frozen
node) and brings the device up to date before calling in here.
"""

from __future__ import annotations

import logging
import struct
from collections.abc import Callable, Mapping
from typing import Any

import canopen
from canopen.sdo.exceptions import SdoAbortedError

from omnican.protocol.cia301 import RPDO_COMM, RPDO_MAP, TPDO_COMM, TPDO_MAP
from omnican.sim.pdo import PdoConfig, read_pdos

logger = logging.getLogger(__name__)

Reader = Callable[[], int]
_CODES = {8: "B", 16: "H", 32: "I", 64: "Q"}  # unsigned: each value is wrapped to its width
Send = Callable[[int, bytes], None]
Write = Callable[[bytes], None]
#: Compiles the write of one object an RPDO maps: (index, subindex, the dictionary's
#: variable) -> what writing it takes, as an SDO download would do it; None: the
#: generic path (LocalNode's write callbacks, then the store).
CompileWrite = Callable[[int, int, Any], "Write | None"]
Maker = Callable[[], bytes]
#: An event TPDO's last frame made and the stamp it was made at (None: the TPDO maps an
#: object the stamp does not cover; it is made at every check).
Made = list[Any]
_NEVER = object()  # the stamp of a frame not made yet: equal to none


class ProcessData:
    """The PDOs of one node.

    Args:
        local: the LocalNode whose dictionary the PDOs read and write.
        readers: dynamic objects, (index, subindex) -> raw value; a TPDO reads them
            directly instead of through the dictionary.
        send: sends one frame (COB-ID, data); it may lose it.
        compile_write: the node's writes, decided once per mapped object (see
            :data:`CompileWrite`); default every write through LocalNode's callbacks.
        stamp: a value equal between two calls only if each object in ``stamped`` reads
            the same in both (:meth:`omnican.sim.device.Device.event_stamp`).
        stamped: the readers ``stamp`` covers, by object: an event TPDO that maps only
            objects read by these (the same readers) is made again only when the stamp
            changed, else its last frame is compared, as made.
    """

    def __init__(self, local: canopen.LocalNode, readers: Mapping[tuple[int, int], Reader],
                 send: Send, compile_write: CompileWrite | None = None,
                 stamp: Callable[[], object] | None = None,
                 stamped: Mapping[tuple[int, int], Reader] | None = None) -> None:
        self._local = local
        self._readers = readers
        self._send = send
        self._compile_write = compile_write
        self._stamp = stamp
        self._stamped = stamped or {}
        self._stamping: Callable[[], object] | None = None  # the stamp, where a TPDO needs it
        self.tpdos: list[PdoConfig] = []
        self.rpdos: dict[int, PdoConfig] = {}  # by COB-ID
        self._pending: dict[int, bytes] = {}  # synchronous RPDOs waiting for the SYNC
        # What a SYNC and an event check go through: (TPDO, its frame maker), in order.
        self._on_sync: list[tuple[PdoConfig, Maker]] = []
        self._on_event: list[tuple[PdoConfig, Maker, Made | None]] = []
        self._appliers: dict[int, Write] = {}  # id(RPDO) -> writes its objects

    def start(self) -> list[int]:
        """Take the PDOs as the dictionary configures them now; returns the RPDOs'
        COB-IDs (to listen to)."""
        getter = self._local.get_data
        dictionary = self._local.object_dictionary
        self.tpdos = read_pdos(dictionary, getter, TPDO_COMM, TPDO_MAP)
        self.rpdos = {p.cob_id: p for p in read_pdos(dictionary, getter, RPDO_COMM, RPDO_MAP)}
        self._pending = {}
        self._on_sync = [(t, self._maker(t)) for t in self.tpdos if t.synchronous]
        self._on_event = [(t, self._maker(t), [_NEVER, b""] if self._covered(t) else None)
                          for t in self.tpdos if t.event_driven]
        covered = any(made is not None for _, _, made in self._on_event)
        self._stamping = self._stamp if covered else None
        self._appliers = {}
        for tpdo in self.tpdos:
            tpdo.last_data = None
            tpdo.pending_change = tpdo.event_driven  # first event TPDO goes out at once
        return list(self.rpdos)

    def _covered(self, tpdo: PdoConfig) -> bool:
        """Every object the TPDO maps is read by a reader the stamp covers."""
        if self._stamp is None or not tpdo.entries:
            return False
        readers, stamped = self._readers, self._stamped
        for e in tpdo.entries:
            key = (e.index, e.subindex)
            reader = stamped.get(key)
            if reader is None or readers.get(key) is not reader:
                return False
        return True

    def _maker(self, tpdo: PdoConfig) -> Maker:
        """The TPDO's frame in one call: where every object is a dynamic one of 8, 16,
        32 or 64 bits, one precompiled struct over their readers (each value wrapped to
        its width, as a drive's register would); else object by object."""
        readers = [self._readers.get((e.index, e.subindex)) for e in tpdo.entries]
        codes = [_CODES.get(e.bits) for e in tpdo.entries]
        if not (tpdo.entries and all(readers) and all(codes)):
            return lambda: self._slow_frame(tpdo)
        pack = struct.Struct("<" + "".join(c for c in codes if c)).pack
        parts = [(r, (1 << e.bits) - 1) for r, e in zip(readers, tpdo.entries, strict=True)]
        # One to three objects (nearly every PDO) without building an argument list.
        if len(parts) == 1:
            (r1, m1), = parts
            return lambda: pack(r1() & m1)  # type: ignore[misc]
        if len(parts) == 2:
            (r1, m1), (r2, m2) = parts
            return lambda: pack(r1() & m1, r2() & m2)  # type: ignore[misc]
        if len(parts) == 3:
            (r1, m1), (r2, m2), (r3, m3) = parts
            return lambda: pack(r1() & m1, r2() & m2, r3() & m3)  # type: ignore[misc]
        return lambda: pack(*[r() & mask for r, mask in parts])  # type: ignore[misc]

    def stop(self) -> None:
        """No PDOs (out of OPERATIONAL)."""
        self.tpdos, self.rpdos, self._pending = [], {}, {}
        self._on_sync, self._on_event, self._appliers = [], [], {}
        self._stamping = None

    def hold(self, cob_id: int, data: bytes) -> None:
        """A synchronous RPDO: applied at the next SYNC (the last one received wins)."""
        self._pending[cob_id] = data

    def sync(self, now: float) -> None:
        """A SYNC: apply the RPDOs that waited for it, send the TPDOs due on it."""
        if self._pending:
            pending, self._pending = self._pending, {}
            rpdos = self.rpdos
            for cob, payload in pending.items():
                rpdo = rpdos.get(cob)
                if rpdo is not None:
                    self.apply(rpdo, payload)
        for tpdo, make in self._on_sync:
            if tpdo.trans_type == 0:  # acyclic: on the SYNC after a change
                data = make()
                if tpdo.pending_change or data != tpdo.last_data:
                    self._emit(tpdo, data, now)
            else:
                tpdo.sync_count += 1
                if tpdo.sync_count >= tpdo.trans_type:
                    tpdo.sync_count = 0
                    self._emit(tpdo, make(), now)

    def apply(self, rpdo: PdoConfig, payload: bytes) -> None:
        """Write an RPDO's objects, as an SDO download would (the drive's hooks, then the
        store); each object found and its write decided once, when the PDO is first
        applied, not looked up in the dictionary with every frame."""
        applier = self._appliers.get(id(rpdo))
        if applier is None:
            applier = self._appliers[id(rpdo)] = self._applier(rpdo)
        applier(payload)

    def _applier(self, rpdo: PdoConfig) -> Write:
        local = self._local
        parts: list[tuple[int, int, int, int, Write]] = []
        offset = 0
        for entry in rpdo.entries:
            index, subindex = entry.index, entry.subindex
            obj = local._find_object(index, subindex)
            write = self._compile_write(index, subindex, obj) if self._compile_write else None
            if write is None:
                write = self._generic_write(index, subindex, obj)
            parts.append((index, offset, offset + entry.nbytes, len(obj) // 8, write))
            offset += entry.nbytes

        def apply(payload: bytes) -> None:
            for index, start, end, size, write in parts:
                chunk = payload[start:end]
                if len(chunk) != size:
                    chunk = chunk[:size].ljust(size, b"\x00")
                try:
                    write(chunk)
                except SdoAbortedError as exc:  # e.g. an unsupported mode: ignored, as a drive
                    logger.debug("node %d: RPDO write to 0x%04X refused: %s", local.id,
                                 index, exc)

        return apply

    def _generic_write(self, index: int, subindex: int, obj: Any) -> Write:
        """LocalNode's write callbacks (a refusal raises), then the store."""
        local = self._local

        def write(chunk: bytes) -> None:
            for callback in local._write_callbacks:
                callback(index=index, subindex=subindex, od=obj, data=chunk)
            local.data_store.setdefault(index, {})[subindex] = chunk

        return write

    def events(self, now: float) -> None:
        """Send the event-driven TPDOs whose data changed or whose event timer ran out,
        as their inhibit times allow."""
        stamping = self._stamping
        stamp = stamping() if stamping is not None else None
        for tpdo, make, made in self._on_event:
            if made is None:
                data = make()
            elif made[0] == stamp:  # nothing it maps changed since it was made
                data = made[1]
            else:
                data = make()
                made[0], made[1] = stamp, data
            if data != tpdo.last_data:
                tpdo.pending_change = True
            due = tpdo.pending_change or (tpdo.event_s and now - tpdo.last_sent >= tpdo.event_s)
            if due and now - tpdo.last_sent >= tpdo.inhibit_s:
                self._emit(tpdo, data, now)

    def _slow_frame(self, tpdo: PdoConfig) -> bytes:
        out = bytearray()
        for entry in tpdo.entries:
            reader = self._readers.get((entry.index, entry.subindex))
            if reader is not None:  # dynamic object: skip the OD machinery
                width = entry.nbytes * 8
                out += (reader() % (1 << width)).to_bytes(entry.nbytes, "little")
            else:
                out += self._local.get_data(entry.index, entry.subindex)[: entry.nbytes]
        return bytes(out)

    def _emit(self, tpdo: PdoConfig, data: bytes, now: float) -> None:
        tpdo.last_data, tpdo.last_sent, tpdo.pending_change = data, now, False
        self._send(tpdo.cob_id, data)
