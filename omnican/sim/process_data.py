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

from omnican.cia301 import RPDO_COMM, RPDO_MAP, TPDO_COMM, TPDO_MAP
from omnican.sim.pdo import PdoConfig, read_pdos

logger = logging.getLogger(__name__)

Reader = Callable[[], int]
_CODES = {8: "B", 16: "H", 32: "I", 64: "Q"}  # unsigned: each value is wrapped to its width
Send = Callable[[int, bytes], None]


class ProcessData:
    """The PDOs of one node.

    Args:
        local: the LocalNode whose dictionary the PDOs read and write.
        readers: dynamic objects, (index, subindex) -> raw value; a TPDO reads them
            directly instead of through the dictionary.
        send: sends one frame (COB-ID, data); it may lose it.
    """

    def __init__(self, local: canopen.LocalNode, readers: Mapping[tuple[int, int], Reader],
                 send: Send) -> None:
        self._local = local
        self._readers = readers
        self._send = send
        self.tpdos: list[PdoConfig] = []
        self.rpdos: dict[int, PdoConfig] = {}  # by COB-ID
        self._pending: dict[int, bytes] = {}  # synchronous RPDOs waiting for the SYNC
        self._makers: dict[int, Callable[[], bytes]] = {}  # id(TPDO) -> its frame
        self._slots: dict[int, list[tuple[int, int, Any, int, int, int]]] = {}  # id(RPDO)

    def start(self) -> list[int]:
        """Take the PDOs as the dictionary configures them now; returns the RPDOs'
        COB-IDs (to listen to)."""
        getter = self._local.get_data
        dictionary = self._local.object_dictionary
        self.tpdos = read_pdos(dictionary, getter, TPDO_COMM, TPDO_MAP)
        self.rpdos = {p.cob_id: p for p in read_pdos(dictionary, getter, RPDO_COMM, RPDO_MAP)}
        self._pending = {}
        self._makers = {id(t): self._maker(t) for t in self.tpdos}
        self._slots = {}
        for tpdo in self.tpdos:
            tpdo.last_data = None
            tpdo.pending_change = tpdo.event_driven  # first event TPDO goes out at once
        return list(self.rpdos)

    def _maker(self, tpdo: PdoConfig) -> Callable[[], bytes]:
        """The TPDO's frame in one call: where every object is a dynamic one of 8, 16,
        32 or 64 bits, one precompiled struct over their readers (each value wrapped to
        its width, as a drive's register would); else object by object."""
        readers = [self._readers.get((e.index, e.subindex)) for e in tpdo.entries]
        codes = [_CODES.get(e.bits) for e in tpdo.entries]
        if tpdo.entries and all(readers) and all(codes):
            pack = struct.Struct("<" + "".join(c for c in codes if c)).pack
            parts = tuple((r, (1 << e.bits) - 1)
                          for r, e in zip(readers, tpdo.entries, strict=True))
            return lambda: pack(*[r() & mask for r, mask in parts])  # type: ignore[misc]
        return lambda: self._slow_frame(tpdo)

    def stop(self) -> None:
        """No PDOs (out of OPERATIONAL)."""
        self.tpdos, self.rpdos, self._pending = [], {}, {}

    def hold(self, cob_id: int, data: bytes) -> None:
        """A synchronous RPDO: applied at the next SYNC (the last one received wins)."""
        self._pending[cob_id] = data

    def sync(self, now: float) -> None:
        """A SYNC: apply the RPDOs that waited for it, send the TPDOs due on it."""
        pending, self._pending = self._pending, {}
        for cob, payload in pending.items():
            rpdo = self.rpdos.get(cob)
            if rpdo is not None:
                self.apply(rpdo, payload)
        for tpdo in self.tpdos:
            if tpdo.trans_type == 0:
                if tpdo.pending_change or self._frame(tpdo) != tpdo.last_data:
                    self._send_tpdo(tpdo, now)
            elif tpdo.synchronous:
                tpdo.sync_count += 1
                if tpdo.sync_count >= tpdo.trans_type:
                    tpdo.sync_count = 0
                    self._send_tpdo(tpdo, now)

    def apply(self, rpdo: PdoConfig, payload: bytes) -> None:
        """Write an RPDO's objects, as an SDO download would: LocalNode's write callbacks
        (the drive's hooks), then the store; each object found once, when the PDOs were
        taken, not looked up in the dictionary with every frame."""
        slots = self._slots.get(id(rpdo))
        if slots is None:
            slots = self._slots[id(rpdo)] = self._rpdo_slots(rpdo)
        local = self._local
        callbacks, store = local._write_callbacks, local.data_store
        for index, subindex, obj, start, end, size in slots:
            chunk = payload[start:end]
            if len(chunk) != size:
                chunk = chunk[:size].ljust(size, b"\x00")
            try:
                for callback in callbacks:
                    callback(index=index, subindex=subindex, od=obj, data=chunk)
            except SdoAbortedError as exc:  # e.g. an unsupported mode: ignored, as on a drive
                logger.debug("node %d: RPDO write to 0x%04X refused: %s", local.id, index, exc)
                continue
            store.setdefault(index, {})[subindex] = chunk

    def _rpdo_slots(self, rpdo: PdoConfig) -> list[tuple[int, int, Any, int, int, int]]:
        """(index, subindex, the dictionary's variable, start, end, its size in bytes) of
        each object an RPDO maps."""
        slots, offset = [], 0
        for entry in rpdo.entries:
            obj = self._local._find_object(entry.index, entry.subindex)
            slots.append((entry.index, entry.subindex, obj, offset, offset + entry.nbytes,
                          len(obj) // 8))
            offset += entry.nbytes
        return slots

    def events(self, now: float) -> None:
        """Send the event-driven TPDOs whose data changed or whose event timer ran out,
        as their inhibit times allow."""
        for tpdo in self.tpdos:
            if not tpdo.event_driven:
                continue
            data = self._frame(tpdo)
            if data != tpdo.last_data:
                tpdo.pending_change = True
            due = tpdo.pending_change or (tpdo.event_s and now - tpdo.last_sent >= tpdo.event_s)
            if due and now - tpdo.last_sent >= tpdo.inhibit_s:
                self._send_tpdo(tpdo, now)

    def _frame(self, tpdo: PdoConfig) -> bytes:
        return self._makers[id(tpdo)]()

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

    def _send_tpdo(self, tpdo: PdoConfig, now: float) -> None:
        data = self._frame(tpdo)
        tpdo.last_data, tpdo.last_sent, tpdo.pending_change = data, now, False
        self._send(tpdo.cob_id, data)
