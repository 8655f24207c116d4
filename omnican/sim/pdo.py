"""PDO configuration of a simulated drive, read from its own object dictionary.

A real drive takes its PDO setup from its communication (14xxh/18xxh) and mapping
(16xxh/1Axxh) parameters when it goes OPERATIONAL; so does the simulator. Writes
to the mapping parameters are checked like a drive does, with the SDO abort codes
of CiA 301.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass, field

from canopen import objectdictionary as od
from canopen.sdo.exceptions import SdoAbortedError

from omnican.protocol.cia301 import (
    COB_ID_INVALID,
    COB_ID_MASK,
    MAX_PDOS,
    RPDO_MAP,
    SDO_ABORT_GENERAL_INCOMPATIBLE,
    SDO_ABORT_NOT_IN_OD,
    SDO_ABORT_NOT_MAPPABLE,
    SDO_ABORT_PDO_LENGTH,
    SDO_ABORT_SUBINDEX,
    TRANS_EVENT,
    TRANS_EVENT_MANUFACTURER,
    TRANS_SYNC_MAX,
)


@dataclass(frozen=True)
class MappedObject:
    index: int
    subindex: int
    bits: int

    @property
    def nbytes(self) -> int:
        return self.bits // 8


@dataclass
class PdoConfig:
    """One PDO as configured in the object dictionary."""

    number: int  # 1-based
    cob_id: int
    trans_type: int
    inhibit_s: float
    event_s: float
    entries: tuple[MappedObject, ...]
    # Run-time bookkeeping (TPDOs).
    sync_count: int = 0
    last_data: bytes | None = None
    last_sent: float = field(default=-1e9)
    pending_change: bool = False
    # What the fields above fix (worked out once: the PDO is taken as a whole and kept
    # until the node leaves OPERATIONAL, and these are read with every frame).
    length: int = field(init=False)  # bytes
    synchronous: bool = field(init=False)  # acts on SYNC (transmission types 0-240)
    event_driven: bool = field(init=False)  # on a change or its event timer (254, 255)

    def __post_init__(self) -> None:
        self.length = sum(e.nbytes for e in self.entries)
        self.synchronous = self.trans_type <= TRANS_SYNC_MAX
        self.event_driven = self.trans_type >= TRANS_EVENT_MANUFACTURER


Getter = Callable[[int, int], bytes]


def read_uint(getter: Getter, index: int, sub: int, fmt: str, default: int = 0) -> int:
    """An unsigned object as ``fmt`` (a struct format) decodes it; ``default`` when the
    dictionary has no value for it."""
    try:
        raw = getter(index, sub)
    except (SdoAbortedError, KeyError):
        return default
    size = struct.calcsize(fmt)
    return int(struct.unpack(fmt, raw[:size].ljust(size, b"\x00"))[0])


def read_pdos(dictionary: od.ObjectDictionary, getter: Getter, comm_base: int,
              map_base: int) -> list[PdoConfig]:
    """Every valid PDO of one direction, from the current OD values."""
    out: list[PdoConfig] = []
    for n in range(MAX_PDOS):
        comm = comm_base + n
        if comm not in dictionary or map_base + n not in dictionary:
            continue
        cob = read_uint(getter, comm, 1, "<I")
        if cob & COB_ID_INVALID:
            continue
        count = read_uint(getter, map_base + n, 0, "<B")
        entries = []
        for sub in range(1, count + 1):
            raw = read_uint(getter, map_base + n, sub, "<I")
            index, subindex, bits = raw >> 16, (raw >> 8) & 0xFF, raw & 0xFF
            if index and bits:
                entries.append(MappedObject(index, subindex, bits))
        comm_obj = dictionary[comm]
        has = comm_obj.subindices if isinstance(comm_obj, od.ODRecord) else {}
        out.append(
            PdoConfig(
                number=n + 1,
                cob_id=cob & COB_ID_MASK,
                trans_type=read_uint(getter, comm, 2, "<B", TRANS_EVENT),
                inhibit_s=(read_uint(getter, comm, 3, "<H") if 3 in has else 0) * 100e-6,
                event_s=(read_uint(getter, comm, 5, "<H") if 5 in has else 0) * 1e-3,
                entries=tuple(entries),
            )
        )
    return out


def _find(dictionary: od.ObjectDictionary, index: int, sub: int) -> od.ODVariable:
    if index not in dictionary:
        raise SdoAbortedError(SDO_ABORT_NOT_IN_OD)
    item = dictionary[index]
    if isinstance(item, od.ODVariable):
        if sub != 0:
            raise SdoAbortedError(SDO_ABORT_SUBINDEX)
        return item
    if sub not in item.subindices:
        raise SdoAbortedError(SDO_ABORT_NOT_IN_OD)
    var = item[sub]
    assert isinstance(var, od.ODVariable)
    return var


def check_mapping_write(
    dictionary: od.ObjectDictionary,
    getter: Getter,
    index: int,
    subindex: int,
    data: bytes,
    max_entries: int | None = None,
    accept_unmappable: bool = False,
) -> None:
    """Raise the SDO abort a drive would send for this write to a mapping parameter.

    Entries must name an existing, PDO-mappable object with its own size;
    the number of entries must fit in 8 bytes (and the drive's entry limit).
    ``accept_unmappable``: the drive maps objects its EDS marks not PDO-mappable
    (an EDS that understates the drive, as many vendor files do)."""
    if subindex == 0:
        count = data[0]
        limit = max_entries if max_entries is not None else 0x40
        if count > limit:
            raise SdoAbortedError(SDO_ABORT_PDO_LENGTH)
        bits = 0
        for sub in range(1, count + 1):
            bits += read_uint(getter, index, sub, "<I") & 0xFF
        if bits > 64:
            raise SdoAbortedError(SDO_ABORT_PDO_LENGTH)
        return
    value = struct.unpack("<I", data[:4].ljust(4, b"\x00"))[0]
    obj_index, obj_sub, bits = value >> 16, (value >> 8) & 0xFF, value & 0xFF
    if obj_index == 0 and bits == 0:
        return  # clearing an entry
    if max_entries is not None and subindex > max_entries:
        raise SdoAbortedError(SDO_ABORT_PDO_LENGTH)
    var = _find(dictionary, obj_index, obj_sub)
    if not var.pdo_mappable and not accept_unmappable:
        raise SdoAbortedError(SDO_ABORT_NOT_MAPPABLE)
    if bits != len(var) or bits % 8:
        raise SdoAbortedError(SDO_ABORT_GENERAL_INCOMPATIBLE)
    rx = RPDO_MAP <= index < RPDO_MAP + MAX_PDOS
    if rx and not var.writable:
        raise SdoAbortedError(SDO_ABORT_NOT_MAPPABLE)
