"""Where a drive keeps each CiA 402 object of each axis, read from its EDS.

Drives lay out multiple axes in one of two ways:

* CiA 402-2 offsets: axis ``k`` at ``index + 0x800 * k`` (Roboteq: 0x6040, 0x6840);
* sub-indexed objects: axis ``k`` at sub-index ``k + 1`` of an array (ZLAC8015D:
  0x6064 sub 1 = left, sub 2 = right), while node-wide objects (controlword,
  statusword, mode) are shared by both axes.

:class:`AxisObjects` resolves the objects of one axis once, so the host
(``drive/``) and the simulator (``sim/``) agree on the addressing. Which objects hold
signed values whatever the EDS declares is the drive's :class:`~omnican.protocol.vendors.Quirks`.
No I/O: it only reads a parsed :class:`canopen.ObjectDictionary`.
"""

from __future__ import annotations

import configparser
import contextlib
import enum
import pickle
import re
from dataclasses import dataclass
from pathlib import Path

from canopen import objectdictionary as od
from canopen.objectdictionary import datatypes
from canopen.objectdictionary import eds as canopen_eds

from omnican.errors import ConfigError
from omnican.protocol import eds_check
from omnican.protocol.vendors import quirks_of

AXIS_OFFSET = 0x800
MAX_AXES = 8


class Obj(enum.IntEnum):
    """CiA 402 objects omnican uses, by their axis-0 index."""

    ABORT_OPTION = 0x6007
    ERROR_CODE = 0x603F
    CONTROLWORD = 0x6040
    STATUSWORD = 0x6041
    QUICK_STOP_OPTION = 0x605A
    MODE = 0x6060
    MODE_DISPLAY = 0x6061
    POSITION_ACTUAL = 0x6064
    VELOCITY_ACTUAL = 0x606C
    RATED_CURRENT = 0x6075  # mA
    TORQUE_ACTUAL = 0x6077  # per mille of the rated torque
    CURRENT_ACTUAL = 0x6078  # per mille of the rated current
    DC_LINK_VOLTAGE = 0x6079  # mV
    MAX_PROFILE_VELOCITY = 0x607F
    PROFILE_ACCEL = 0x6083
    PROFILE_DECEL = 0x6084
    QUICK_STOP_DECEL = 0x6085
    FOLLOWING_ERROR = 0x60F4  # position units
    DIGITAL_INPUTS = 0x60FD
    TARGET_VELOCITY = 0x60FF
    VL_TARGET = 0x6042
    VL_DEMAND = 0x6043
    VL_ACTUAL = 0x6044
    VL_ACCEL = 0x6048  # record: sub 1 delta speed, sub 2 delta time
    VL_DECEL = 0x6049
    VL_QUICK_STOP = 0x604A
    SUPPORTED_MODES = 0x6502


# Objects a drive has once per node when it has no per-axis copy (ZLAC8015D).
NODE_WIDE = frozenset(
    {
        Obj.ABORT_OPTION,
        Obj.ERROR_CODE,
        Obj.CONTROLWORD,
        Obj.STATUSWORD,
        Obj.QUICK_STOP_OPTION,
        Obj.MODE,
        Obj.MODE_DISPLAY,
        Obj.SUPPORTED_MODES,
        Obj.DC_LINK_VOLTAGE,
        Obj.DIGITAL_INPUTS,
    }
)

# vl ramps are records (delta speed / delta time), resolved by index only.
RECORDS = frozenset({Obj.VL_ACCEL, Obj.VL_DECEL, Obj.VL_QUICK_STOP})


@dataclass(frozen=True)
class Entry:
    """One resolved object: where it is and how wide it is."""

    obj: Obj | None  # None: an object omnican does not use (in a drive's fixed mapping)
    index: int
    subindex: int
    bits: int
    signed: bool  # holds a signed quantity
    declared_signed: bool  # the EDS declares a signed type
    shared: bool  # the node's single copy, shared by all axes
    pdo_mappable: bool
    writable: bool
    name: str

    @property
    def address(self) -> str:
        return f"0x{self.index:04X}:{self.subindex:02X}"

    def decode(self, data: bytes | bytearray) -> int:
        """Integer value of raw little-endian data (two's complement if signed)."""
        raw = int.from_bytes(bytes(data[: self.bits // 8]), "little")
        if self.signed and raw >= 1 << (self.bits - 1):
            raw -= 1 << self.bits
        return raw

    def encode(self, value: int) -> bytes:
        """Raw little-endian bytes of ``value``, saturated to the object's range."""
        lo, hi = (-(1 << (self.bits - 1)), (1 << (self.bits - 1)) - 1) if self.signed else (
            0, (1 << self.bits) - 1)
        value = max(lo, min(hi, int(value)))
        return (value % (1 << self.bits)).to_bytes(self.bits // 8, "little")


def obj_name(obj: Obj) -> str:
    """Readable name of an object: ``Obj.VL_TARGET`` -> ``"vl target"``."""
    return obj.name.lower().replace("_", " ")


def _var_bits(var: od.ODVariable) -> int:
    return len(var)


def _entry(obj: Obj | None, var: od.ODVariable, shared: bool, signed: frozenset[int]) -> Entry:
    """``signed``: the objects (axis-0 index) read as signed whatever the EDS declares."""
    signed_type = var.data_type in od.SIGNED_TYPES
    return Entry(
        obj=obj,
        index=var.index,
        subindex=var.subindex,
        bits=_var_bits(var),
        signed=signed_type or (obj is not None and obj in signed),
        declared_signed=signed_type,
        shared=shared,
        pdo_mappable=bool(var.pdo_mappable),
        writable=bool(var.writable),
        name=var.name,
    )


def entry_at(dictionary: od.ObjectDictionary, index: int, subindex: int) -> Entry:
    """An entry for any object (e.g. one in a drive's fixed PDO mapping)."""
    item = dictionary[index]
    var = item if isinstance(item, od.ODVariable) else item[subindex]
    if not isinstance(var, od.ODVariable):
        raise KeyError(f"0x{index:04X}:{subindex:02X} is not a variable")
    obj = Obj(index) if index in Obj._value2member_map_ else None
    return _entry(obj, var, shared=False, signed=quirks_of(dictionary).signed)


def variable_at(dictionary: od.ObjectDictionary, index: int,
                subindex: int) -> od.ODVariable | None:
    """The variable at ``index:subindex`` (a VAR at sub 0, or a sub of a record or array)."""
    # Not get(): canopen's raises a KeyError, its message formatted, and catches it.
    item = dictionary[index] if index in dictionary else None  # noqa: SIM401
    if isinstance(item, od.ODVariable):
        return item if subindex == 0 else None
    var = item.subindices.get(subindex) if item is not None else None
    return var if isinstance(var, od.ODVariable) else None


def count_axes(dictionary: od.ObjectDictionary) -> int:
    """Number of axes a drive has, from its position-actual objects."""
    base = int(Obj.POSITION_ACTUAL)
    if base not in dictionary:
        return 0
    offsets = sum(1 for k in range(MAX_AXES) if base + AXIS_OFFSET * k in dictionary)
    first = dictionary[base]
    if isinstance(first, (od.ODArray, od.ODRecord)):
        subs = sum(1 for s in first.subindices if s >= 1)
        return max(offsets, subs)
    return offsets


def axis_layout(dictionary: od.ObjectDictionary) -> str:
    """``"single"``, ``"offset"`` (0x800 per axis) or ``"subindex"``."""
    base = int(Obj.POSITION_ACTUAL)
    if base in dictionary and isinstance(dictionary[base], (od.ODArray, od.ODRecord)):
        return "subindex"
    return "offset" if count_axes(dictionary) > 1 else "single"


class AxisObjects:
    """The objects of axis ``axis`` (0-based) of a drive described by ``dictionary``."""

    def __init__(self, dictionary: od.ObjectDictionary, axis: int = 0) -> None:
        self.dictionary = dictionary
        self.axis = axis
        self.num_axes = count_axes(dictionary)
        self.layout = axis_layout(dictionary)
        self._signed = quirks_of(dictionary).signed
        self._entries: dict[Obj, Entry | None] = {}
        self._record_index: dict[Obj, int | None] = {}

    def _resolve(self, obj: Obj) -> Entry | None:
        d, k, base = self.dictionary, self.axis, int(obj)
        offset_item = d.get(base + AXIS_OFFSET * k) if k > 0 else None
        if isinstance(offset_item, od.ODVariable):
            return _entry(obj, offset_item, shared=False, signed=self._signed)
        if base not in d:
            return None
        item = d[base]
        if isinstance(item, od.ODVariable):
            if k == 0:
                return _entry(obj, item, shared=self.num_axes > 1 and obj in NODE_WIDE,
                              signed=self._signed)
            if obj in NODE_WIDE and self.layout == "subindex":
                return _entry(obj, item, shared=True, signed=self._signed)
            return None
        sub = k + 1
        if sub in item.subindices:
            var = item[sub]
            if isinstance(var, od.ODVariable):
                return _entry(obj, var, shared=False, signed=self._signed)
        return None

    def get(self, obj: Obj) -> Entry | None:
        """The entry of ``obj`` for this axis, or None if the drive lacks it."""
        if obj not in self._entries:
            self._entries[obj] = self._resolve(obj)
        return self._entries[obj]

    def __getitem__(self, obj: Obj) -> Entry:
        entry = self.get(obj)
        if entry is None:
            raise KeyError(f"drive has no {obj_name(obj)} (0x{int(obj):04X}) for axis {self.axis}")
        return entry

    def __contains__(self, obj: object) -> bool:
        return isinstance(obj, Obj) and self.get(obj) is not None

    def record(self, obj: Obj) -> int | None:
        """Index of a record object (vl ramps) for this axis, or None."""
        if obj not in self._record_index:
            index = int(obj) + AXIS_OFFSET * self.axis
            found = index in self.dictionary and isinstance(self.dictionary[index], od.ODRecord)
            self._record_index[obj] = index if found else None
        return self._record_index[obj]


#: EDS files parsed, each a pickled dictionary, the node id it was parsed for and its
#: axis count (:func:`count_axes`, for :func:`eds_axes`), by
#: (path, mtime, size, inode, whether a node id was given): a process that opens a base
#: parses each file once (the simulator's drives, the node plans of the simulator and of
#: the host), whatever the node ids; another node's copy has its $NODEID values
#: resolved again (:func:`_for_node`). Bounded.
_PARSED: dict[tuple[str, int, int, int, bool], tuple[bytes, int | None, int]] = {}
_PARSED_MAX = 64


def parse_eds(path: str | Path, node_id: int | None = None) -> od.ObjectDictionary:
    """``canopen.objectdictionary.import_od(path, node_id)``, the file parsed once per
    version (its modification time, size and inode): each call returns a dictionary of
    its own (a copy), which its caller may change without another caller seeing it, its
    values given as ``$NODEID+...`` those of ``node_id``. Raises what ``import_od`` raises
    (OSError, parser errors)."""
    key = _version(path, node_id)
    cached = _PARSED.get(key)
    if cached is not None:
        blob, parsed_for, _ = cached
        copy: od.ObjectDictionary = pickle.loads(blob)  # our own bytes, made below
        if node_id != parsed_for and node_id is not None:
            _for_node(copy, node_id)
        return copy
    dictionary = od.import_od(str(path), node_id)
    if len(_PARSED) >= _PARSED_MAX:
        _PARSED.clear()
    _PARSED[key] = (pickle.dumps(dictionary, pickle.HIGHEST_PROTOCOL), node_id,
                    count_axes(dictionary))
    return dictionary


def eds_axes(path: str | Path) -> int:
    """How many axes the drive of an EDS file has (:func:`count_axes` of its dictionary),
    from :func:`parse_eds`'s parse of that version of the file: no copy made."""
    cached = _PARSED.get(_version(path, 1))
    return cached[2] if cached is not None else count_axes(parse_eds(path, 1))


def _version(path: str | Path, node_id: int | None) -> tuple[str, int, int, int, bool]:
    """A parse's key: the file (its modification time, size and inode), and whether a
    node id was given."""
    p = Path(path)
    st = p.stat()
    return (str(p.resolve()), st.st_mtime_ns, st.st_size, st.st_ino, node_id is None)


def _for_node(dictionary: od.ObjectDictionary, node_id: int) -> None:
    """A dictionary parsed for another node id made the one canopen parses for
    ``node_id``: its node id (canopen sets one only where the file has a
    DeviceComissioning section), and each default and parameter value the file gives as
    ``$NODEID+...`` converted again as canopen's parser converts it (a value that did not
    convert for one node id converts for none: it stays unset)."""
    if dictionary.node_id is not None:
        dictionary.node_id = node_id
    for obj in dictionary.values():
        for var in [obj] if isinstance(obj, od.ODVariable) else obj.subindices.values():
            raw = var.__dict__.get("default_raw")
            if raw is not None and "$NODEID" in raw:
                with contextlib.suppress(ValueError):
                    var.default = canopen_eds._convert_variable(node_id, var.data_type, raw)
            raw = var.__dict__.get("value_raw")
            if raw is not None and "$NODEID" in raw:
                with contextlib.suppress(ValueError):
                    var.value = canopen_eds._convert_variable(node_id, var.data_type, raw)


def load_dictionary(path: str | Path, node_id: int = 1) -> od.ObjectDictionary:
    """Parse an EDS/DCF file and check what omnican needs of every node's dictionary
    (:func:`omnican.protocol.eds_check.dictionary_problems`); a missing, unreadable or impossible
    file is a :class:`ConfigError` of one line naming the file and the object."""
    p = Path(path)
    try:
        found = p.is_file()
    except OSError as exc:  # a name longer than the file system allows, say
        shown = str(p) if len(str(p)) <= 80 else f"{str(p)[:60]}... ({len(str(p))} characters)"
        raise ConfigError(f"cannot read EDS file {shown}: {exc.strerror or exc}") from None
    if not found:
        raise ConfigError(f"EDS file not found: {p}")
    try:
        dictionary = parse_eds(p, node_id)
    except Exception as exc:  # canopen raises a variety of parser errors, some multi-line
        text = str(exc).strip().splitlines()[0].rstrip(".") if str(exc).strip() else \
            type(exc).__name__
        line = getattr(exc, "lineno", None)  # configparser's errors know where
        where = f" at line {line}" if isinstance(line, int) else ""
        raise ConfigError(f"cannot parse EDS {p}: {text}{where}") from None
    problems = eds_check.dictionary_problems(dictionary, declared_types(p))
    if problems:
        raise ConfigError(f"EDS {p}: {eds_check.one_line(problems)}")
    return dictionary


_SECTION = re.compile(r"([0-9A-Fa-f]{4})(?:sub([0-9A-Fa-f]+))?")


def declared_types(path: Path) -> eds_check.DeclaredType:
    """The DataType a variable has in the file itself: canopen turns one it does not know
    (0x0020, a structure) into DOMAIN. The file is read again only for such a variable."""
    sections: dict[tuple[int, int], str] | None = None

    def declared(var: od.ODVariable) -> int:
        nonlocal sections
        parsed = var.data_type or 0
        if parsed != datatypes.DOMAIN:
            return parsed
        if sections is None:
            parser = configparser.RawConfigParser(inline_comment_prefixes=(";",), strict=False)
            parser.optionxform = str  # type: ignore[assignment,method-assign]
            try:
                parser.read(path)  # as canopen reads it
            except (configparser.Error, OSError, UnicodeDecodeError):
                return parsed
            sections = {}
            for name in parser.sections():
                m = _SECTION.fullmatch(name)
                text = parser.get(name, "DataType", fallback=None)
                if m and text is not None:
                    sections[(int(m.group(1), 16), int(m.group(2) or "0", 16))] = text
        text = sections.get((var.index, var.subindex))
        try:
            return int(text, 0) if text is not None else parsed
        except ValueError:
            return parsed

    return declared
