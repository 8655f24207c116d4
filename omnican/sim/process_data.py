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
from collections.abc import Callable, Mapping

import canopen
from canopen.sdo.exceptions import SdoAbortedError

from omnican.cia301 import RPDO_COMM, RPDO_MAP, TPDO_COMM, TPDO_MAP
from omnican.sim.pdo import MappedObject, PdoConfig, read_pdos

logger = logging.getLogger(__name__)

Reader = Callable[[], int]
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

    def start(self) -> list[int]:
        """Take the PDOs as the dictionary configures them now; returns the RPDOs'
        COB-IDs (to listen to)."""
        getter = self._local.get_data
        dictionary = self._local.object_dictionary
        self.tpdos = read_pdos(dictionary, getter, TPDO_COMM, TPDO_MAP)
        self.rpdos = {p.cob_id: p for p in read_pdos(dictionary, getter, RPDO_COMM, RPDO_MAP)}
        self._pending = {}
        for tpdo in self.tpdos:
            tpdo.last_data = None
            tpdo.pending_change = tpdo.event_driven  # first event TPDO goes out at once
        return list(self.rpdos)

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
        """Write an RPDO's objects, as an SDO download would."""
        offset = 0
        for entry in rpdo.entries:
            chunk = payload[offset : offset + entry.nbytes]
            offset += entry.nbytes
            try:
                self._local.set_data(entry.index, entry.subindex, self._fit(entry, chunk))
            except SdoAbortedError as exc:  # e.g. an unsupported mode: ignored, as on a drive
                logger.debug("node %d: RPDO write to 0x%04X refused: %s", self._local.id,
                             entry.index, exc)

    def _fit(self, entry: MappedObject, chunk: bytes) -> bytes:
        var = self._local._find_object(entry.index, entry.subindex)
        size = len(var) // 8
        return chunk[:size].ljust(size, b"\x00")

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
