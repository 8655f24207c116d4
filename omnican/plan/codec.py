"""The wire layout of a PDO, compiled once: where each mapped object sits in the frame
and how to pack or unpack all of them in one call.

The control loop packs its RPDOs and unpacks its TPDOs through :class:`PdoCodec` (one
precompiled ``struct.Struct`` per PDO instead of slicing and converting object by
object); replay unpacks recorded PDOs with it and the DBC generator places, sizes and
signs its signals by its fields, so the three always agree.

Pure module: no I/O, no CAN imports.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from omnican.plan.pdo import PlannedPdo
from omnican.protocol.object_map import Entry

_CODES = {8: "b", 16: "h", 32: "i", 64: "q"}


def value_range(bits: int, signed: bool) -> tuple[int, int]:
    """(lowest, highest) integer a field of ``bits`` holds (two's complement if signed)."""
    return (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if signed else (0, (1 << bits) - 1)


@dataclass(frozen=True)
class WireField:
    """One mapped object of a PDO: ``offset`` in bytes from the start of the frame."""

    entry: Entry
    offset: int

    @property
    def start_bit(self) -> int:
        return self.offset * 8

    @property
    def bits(self) -> int:
        return self.entry.bits

    @property
    def size(self) -> int:
        return self.entry.bits // 8

    @property
    def signed(self) -> bool:
        """Read as signed: a signed quantity, whatever the EDS declares (``Entry.signed``)."""
        return self.entry.signed

    @property
    def lo(self) -> int:
        return value_range(self.bits, self.signed)[0]

    @property
    def hi(self) -> int:
        return value_range(self.bits, self.signed)[1]


class PdoCodec:
    """Packs and unpacks every object of one PDO at once (little-endian, as mapped).

    Values are integers in the objects' own units; :meth:`pack` saturates each to its
    object's range (a target beyond it is sent as the largest the object holds), and
    :meth:`unpack` reads signed quantities as signed (see ``Entry.signed``)."""

    def __init__(self, pdo: PlannedPdo) -> None:
        self.pdo = pdo
        self.cob_id = pdo.cob_id
        fields = []
        offset = 0
        for entry in pdo.entries:
            fields.append(WireField(entry, offset))
            offset += entry.bits // 8
        self.fields: tuple[WireField, ...] = tuple(fields)
        self.length = offset
        codes = [_CODES.get(f.bits) for f in fields]
        # Objects of 24, 40, 48 or 56 bits have no struct code: those PDOs go slowly.
        self._struct: struct.Struct | None = None
        if all(codes):
            self._struct = struct.Struct("<" + "".join(
                c if f.signed else c.upper()
                for c, f in zip(codes, fields, strict=True) if c))
        self._ranges = tuple((f.lo, f.hi) for f in fields)

    def index_of(self, entry: Entry) -> int | None:
        """Position of ``entry`` among the fields (by index and sub-index), or None."""
        for i, f in enumerate(self.fields):
            if (f.entry.index, f.entry.subindex) == (entry.index, entry.subindex):
                return i
        return None

    def packer(self) -> Callable[..., bytes]:
        """``pack`` for values already in range, one argument per field: the compiled
        ``struct`` itself where there is one (the control loop's form: it clamps as it
        makes the values, and saves the list and the call)."""
        if self._struct is not None:
            return self._struct.pack
        return lambda *values: self.pack(values)

    def unpacker(self) -> Callable[[bytes | bytearray], tuple[int, ...] | None]:
        """:meth:`unpack` as one call: the compiled ``struct``'s own where there is one
        (it raises on a short frame, so check ``length`` first)."""
        if self._struct is not None:
            return self._struct.unpack_from
        return self.unpack

    @property
    def ranges(self) -> tuple[tuple[int, int], ...]:
        """(lowest, highest) value of each field."""
        return self._ranges

    def pack(self, values: Sequence[int]) -> bytes:
        """The frame's data bytes for ``values`` (one per field, saturated)."""
        clamped = [lo if v < lo else hi if v > hi else v
                   for v, (lo, hi) in zip(values, self._ranges, strict=True)]
        if self._struct is not None:
            return self._struct.pack(*clamped)
        return b"".join(f.entry.encode(v) for f, v in zip(self.fields, clamped, strict=True))

    def unpack(self, data: bytes | bytearray) -> tuple[int, ...] | None:
        """The fields' values, or None when ``data`` is shorter than the PDO."""
        if len(data) < self.length:
            return None
        if self._struct is not None:
            return self._struct.unpack_from(data)
        return tuple(f.entry.decode(data[f.offset : f.offset + f.size]) for f in self.fields)
