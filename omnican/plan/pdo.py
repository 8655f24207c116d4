"""PDO plan for one node: which objects go into which PDO, within what its EDS offers.

The plan: wheel targets on SYNC-applied RPDOs, controlwords beside them, written every
cycle (``cyclic_controlword``, the default: ros2_canopen's master rewrites the
controlword each cycle, and some drives act on one only as it arrives) or on an RPDO of
their own sent on change; positions on SYNC-triggered TPDOs, statuswords on an
event-driven TPDO. It respects each drive's limits: the number of PDOs, the
number of mapping entries each accepts (some accept one: the controlword then gets a
cyclic RPDO of its own), the sub-indices its communication parameters have (no inhibit
time or event timer on some), and the object sizes it declares (a 32-bit statusword).
When a drive has too few PDOs, the controlword rides on the cyclic RPDO and the
statusword on the cyclic TPDO.

Vendor EDS files often mark objects a drive does map (60FFh, 6064h) as not
PDO-mappable. The ``mapping`` policy says what to do with them: ``"try"`` maps
them anyway (the drive has the last word; see drive.py for what happens when it
refuses), ``"eds"`` believes the EDS and moves them to expedited SDO every cycle,
``"sdo"`` moves the targets and positions to SDO whatever the EDS says.

I/O-free: it reads a parsed object dictionary only.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from canopen import objectdictionary as od

from omnican.config import PDO_MAPPINGS
from omnican.errors import ConfigError
from omnican.protocol.cia301 import (
    COB_ID_MASK,
    PDO_NUMBER_STEP,
    RPDO1_BASE,
    RPDO_COMM,
    RPDO_MAP,
    TPDO1_BASE,
    TPDO_COMM,
    TPDO_MAP,
    TRANS_EVENT,
    TRANS_SYNC,
    TRANS_SYNC_MAX,
)
from omnican.protocol.object_map import Entry

MAX_PDO_BITS = 64
MAPPING_POLICIES = PDO_MAPPINGS  # "try", "eds", "sdo": chassis.pdo_mapping


def frame_bits(data_bytes: int) -> int:
    """Worst-case bits on the wire of a standard CAN frame with ``data_bytes`` bytes,
    bit stuffing included (135 for 8 bytes, 55 for an empty SYNC)."""
    return 8 * data_bytes + 47 + (34 + 8 * data_bytes - 1) // 4


#: Bits of one expedited SDO transfer: an 8-byte request and an 8-byte answer
#: (SDO frames always carry 8 data bytes).
SDO_TRANSFER_BITS = 2 * frame_bits(8)


@dataclass(frozen=True)
class PdoSlot:
    """What an EDS offers for one PDO."""

    number: int  # 1-based
    max_entries: int
    has_inhibit: bool
    has_event_timer: bool
    default_cob_id: int | None


@dataclass(frozen=True)
class PlannedPdo:
    number: int
    cob_id: int
    trans_type: int
    entries: tuple[Entry, ...]
    inhibit_100us: int | None = None
    event_timer_ms: int | None = None

    @property
    def data_bytes(self) -> int:
        return sum(e.bits for e in self.entries) // 8

    @property
    def cyclic(self) -> bool:
        return self.trans_type <= TRANS_SYNC_MAX

    def describe(self, kind: str) -> str:
        objs = ", ".join(f"{e.name} ({e.address})" for e in self.entries)
        timing = (f"every {self.trans_type} SYNCs" if self.cyclic and self.trans_type > 1 else
                  "every SYNC" if self.cyclic else "on change")
        extras = []
        if self.inhibit_100us:
            extras.append(f"inhibit {self.inhibit_100us / 10:g} ms")
        if self.event_timer_ms:
            extras.append(f"event timer {self.event_timer_ms} ms")
        extra = f", {', '.join(extras)}" if extras else ""
        return (f"{kind}{self.number} 0x{self.cob_id:03X} {timing}{extra}, "
                f"{self.data_bytes} bytes: {objs}")


@dataclass(frozen=True)
class SdoTransfer:
    """An object no PDO carries, moved by expedited SDO instead: written (targets,
    controlwords) or read (positions, statuswords), every cycle or on change."""

    entry: Entry
    write: bool
    cyclic: bool

    def describe(self) -> str:
        what = "written" if self.write else "read"
        when = "every cycle" if self.cyclic else "on change"
        bits = f", {SDO_TRANSFER_BITS} bits" if self.cyclic else ""
        return (f"SDO {when}: {self.entry.name} ({self.entry.address}) {what} by expedited SDO "
                f"(request + answer{bits})")


@dataclass(frozen=True)
class NodePlan:
    node_id: int
    rpdos: tuple[PlannedPdo, ...]
    tpdos: tuple[PlannedPdo, ...]
    unused_rpdos: tuple[int, ...] = ()
    unused_tpdos: tuple[int, ...] = ()
    notes: tuple[str, ...] = field(default=())
    sdo: tuple[SdoTransfer, ...] = ()
    tried: tuple[Entry, ...] = ()  # mapped although the EDS says they are not PDO-mappable

    def cyclic_bits(self) -> int:
        """Worst-case bits this node puts on the bus each control cycle (SYNC excluded)."""
        pdos = sum(frame_bits(p.data_bytes) for p in self.rpdos + self.tpdos if p.cyclic)
        return pdos + self.sdo_bits()

    def sdo_bits(self) -> int:
        """Worst-case bits per control cycle of the objects moved by SDO every cycle."""
        return SDO_TRANSFER_BITS * sum(1 for t in self.sdo if t.cyclic)

    def find(self, entry: Entry, tx: bool) -> tuple[PlannedPdo, int] | None:
        """(PDO, byte offset) where ``entry`` is mapped, or None."""
        for pdo in self.tpdos if tx else self.rpdos:
            offset = 0
            for e in pdo.entries:
                if (e.index, e.subindex) == (entry.index, entry.subindex):
                    return pdo, offset
                offset += e.bits // 8
        return None

    def describe(self) -> list[str]:
        lines = [p.describe("RPDO") for p in self.rpdos] + [p.describe("TPDO") for p in self.tpdos]
        return lines + [t.describe() for t in self.sdo] + list(self.notes)


def pdo_slots(dictionary: od.ObjectDictionary, node_id: int, tx: bool) -> list[PdoSlot]:
    """The PDOs of one direction an EDS offers, with their limits."""
    comm_base, map_base = (TPDO_COMM, TPDO_MAP) if tx else (RPDO_COMM, RPDO_MAP)
    slots = []
    # Looked up by ``in`` first: canopen's get() raises and catches a KeyError, with its
    # message formatted, for each of the 512 numbers a drive lacks.
    for n in range(512):
        if comm_base + n not in dictionary or map_base + n not in dictionary:
            continue
        comm, mapping = dictionary[comm_base + n], dictionary[map_base + n]
        if not isinstance(comm, od.ODRecord) or not isinstance(mapping, (od.ODRecord, od.ODArray)):
            continue
        entries = sum(1 for s in mapping.subindices if s >= 1)
        default_cob = None
        if 1 in comm.subindices:
            raw = comm[1].default
            if isinstance(raw, int):
                default_cob = raw & COB_ID_MASK
        if n < 4:
            default_cob = (TPDO1_BASE if tx else RPDO1_BASE) + PDO_NUMBER_STEP * n + node_id
        slots.append(PdoSlot(n + 1, entries, 3 in comm.subindices, 5 in comm.subindices,
                             default_cob))
    return slots


def _pack(entries: Sequence[Entry], slots: Sequence[PdoSlot]) -> list[tuple[PdoSlot, list[Entry]]]:
    """First-fit packing of ``entries`` into consecutive ``slots``."""
    out: list[tuple[PdoSlot, list[Entry]]] = []
    free = list(slots)
    for entry in entries:
        placed = False
        for slot, group in out:
            bits = sum(e.bits for e in group)
            if len(group) < slot.max_entries and bits + entry.bits <= MAX_PDO_BITS:
                group.append(entry)
                placed = True
                break
        if not placed:
            while free and free[0].max_entries < 1:
                free.pop(0)
            if not free:
                raise _NoRoomError
            out.append((free.pop(0), [entry]))
    return out


class _NoRoomError(Exception):
    pass


def _unique(entries: Sequence[Entry]) -> list[Entry]:
    seen: set[tuple[int, int]] = set()
    out = []
    for e in entries:
        if (e.index, e.subindex) not in seen:
            seen.add((e.index, e.subindex))
            out.append(e)
    return out


def plan_node(
    node_id: int,
    dictionary: od.ObjectDictionary,
    cyclic_rx: Sequence[Entry],
    event_rx: Sequence[Entry],
    cyclic_tx: Sequence[Entry],
    event_tx: Sequence[Entry],
    optional_tx: Sequence[Entry] = (),
    inhibit_ms: float = 5.0,
    event_timer_ms: int = 100,
    mapping: str = "try",
    event_rx_every_cycle: bool = False,
) -> NodePlan:
    """Plan the PDOs of one node.

    ``optional_tx`` objects (mode display, error code) are added to the event TPDO
    only where they fit without using another PDO. ``mapping`` (one of
    :data:`MAPPING_POLICIES`) decides what becomes of objects the EDS marks not
    PDO-mappable, and whether targets and positions go by SDO.
    ``event_rx_every_cycle``: the ``event_rx`` objects (controlwords) are written every
    cycle too: on the cyclic RPDOs, where they fit beside ``cyclic_rx`` (first fit, the
    targets placed first), else on cyclic RPDOs of their own; by SDO every cycle where the
    EDS moves them there (never because of the ``"sdo"`` policy, which is the targets')."""
    if mapping not in MAPPING_POLICIES:
        raise ValueError(f"mapping must be one of {', '.join(MAPPING_POLICIES)}, got {mapping!r}")
    rx_slots = pdo_slots(dictionary, node_id, tx=False)
    tx_slots = pdo_slots(dictionary, node_id, tx=True)
    cyclic_rx, event_rx = _unique(cyclic_rx), _unique(event_rx)
    cyclic_tx, event_tx = _unique(cyclic_tx), _unique(event_tx)
    notes: list[str] = []
    sdo: list[SdoTransfer] = []
    tried: list[Entry] = []

    def keep_mapped(entries: list[Entry], write: bool, cyclic: bool,
                    every_cycle: bool = False) -> list[Entry]:
        kept = []
        for entry in entries:
            if (cyclic and mapping == "sdo") or (not entry.pdo_mappable and mapping != "try"):
                sdo.append(SdoTransfer(entry, write, cyclic or every_cycle or not write))
                continue
            if not entry.pdo_mappable:
                tried.append(entry)
                notes.append(f"{entry.name} ({entry.address}) is not PDO-mappable in its EDS: "
                              "mapped anyway (pdo_mapping = \"try\")")
            kept.append(entry)
        return kept

    cyclic_rx = keep_mapped(cyclic_rx, write=True, cyclic=True)
    event_rx = keep_mapped(event_rx, write=True, cyclic=False, every_cycle=event_rx_every_cycle)
    if event_rx_every_cycle:  # beside the targets, every SYNC
        cyclic_rx, event_rx = cyclic_rx + event_rx, []
    cyclic_tx = keep_mapped(cyclic_tx, write=False, cyclic=True)
    event_tx = keep_mapped(event_tx, write=False, cyclic=False)

    def pack_direction(cyclic: list[Entry], event: list[Entry], slots: list[PdoSlot],
                       kind: str) -> tuple[list[tuple[PdoSlot, list[Entry]]],
                                           list[tuple[PdoSlot, list[Entry]]]]:
        try:  # on-change data (controlword, statusword) in the first PDOs, as drives default
            ev = _pack(event, slots) if event else []
            used = {s.number for s, _ in ev}
            cyc = _pack(cyclic, [s for s in slots if s.number not in used])
            return cyc, ev
        except _NoRoomError:
            pass
        try:  # too few PDOs: everything on the cyclic ones
            notes.append(f"too few {kind}s for separate on-change data: "
                         f"{', '.join(e.name for e in event)} sent every SYNC")
            return _pack(cyclic + event, slots), []
        except _NoRoomError:
            need = ", ".join(e.name for e in cyclic + event)
            raise ConfigError(
                f"node {node_id}: its EDS offers {len(slots)} {kind}s "
                f"({', '.join(str(s.max_entries) for s in slots)} mapping entries each), "
                f"too few for {need}"
            ) from None

    rx_cyc, rx_ev = pack_direction(cyclic_rx, event_rx, rx_slots, "RPDO")
    tx_cyc, tx_ev = pack_direction(cyclic_tx, event_tx, tx_slots, "TPDO")
    # Optional read-backs ride along on the event TPDO if they fit.
    for entry in _unique(optional_tx):
        for slot, group in tx_ev:
            if entry.pdo_mappable and len(group) < slot.max_entries and (
                    sum(e.bits for e in group) + entry.bits <= MAX_PDO_BITS):
                group.append(entry)
                break

    def build(groups: list[tuple[PdoSlot, list[Entry]]], trans: int, tx: bool) -> list[PlannedPdo]:
        out = []
        for slot, group in groups:
            if slot.default_cob_id is None:
                raise ConfigError(f"node {node_id}: {'T' if tx else 'R'}PDO{slot.number} has no "
                                  "COB-ID default in its EDS")
            event = trans == TRANS_EVENT and tx
            out.append(PlannedPdo(
                number=slot.number,
                cob_id=slot.default_cob_id,
                trans_type=trans,
                entries=tuple(group),
                inhibit_100us=round(inhibit_ms * 10) if event and slot.has_inhibit else None,
                event_timer_ms=event_timer_ms if event and slot.has_event_timer else None,
            ))
        return out

    rpdos = build(rx_cyc, TRANS_SYNC, False) + build(rx_ev, TRANS_EVENT, False)
    tpdos = build(tx_cyc, TRANS_SYNC, True) + build(tx_ev, TRANS_EVENT, True)
    used_rx = {p.number for p in rpdos}
    used_tx = {p.number for p in tpdos}
    return NodePlan(
        node_id=node_id,
        rpdos=tuple(sorted(rpdos, key=lambda p: p.number)),
        tpdos=tuple(sorted(tpdos, key=lambda p: p.number)),
        unused_rpdos=tuple(s.number for s in rx_slots if s.number not in used_rx),
        unused_tpdos=tuple(s.number for s in tx_slots if s.number not in used_tx),
        notes=tuple(notes),
        sdo=tuple(sdo),
        tried=tuple(tried),
    )
