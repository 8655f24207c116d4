"""What an EDS must hold before omnican plans with it.

Two kinds of object, each with the sub-indices and the data types omnican relies on:

* the objects CiA 301 makes mandatory in every device: 1000h device type (UNSIGNED32),
  1001h error register (UNSIGNED8), 1018h identity with sub 0 and sub 1 (vendor-ID,
  UNSIGNED32); sub 2-4 are optional;
* the objects omnican will read, write or map: every PDO's communication parameter
  (sub 0, COB-ID sub 1, transmission type sub 2; inhibit time sub 3 and event timer
  sub 5 where the EDS has them) and mapping parameter (sub 0, entries UNSIGNED32), as
  omnican configures or disables each PDO the EDS offers; the heartbeat producer 1017h
  (conditional in CiA 301, but omnican sets it) and, where the EDS has one, the
  heartbeat consumer 1016h sub 1; and each axis's CiA 402 objects (controlword,
  statusword, mode, target, position, ramps ...), which must be integers omnican can
  encode.

What the control loop needs beyond the types (:func:`width_problem`,
:func:`counter_problem`, :func:`access_problem`, :func:`modes_problem`, applied by
:class:`omnican.plan.node.NodeLayout` with the config's speed, scales and rate): a target
wide enough for the top speed, a position counter that cannot pass half its span between
samples, write access where omnican writes, a velocity mode among 6502h's.

Real drives' files understate their drives (objects marked not PDO-mappable, optional
sub-indices left out, a sub 0 declared UNSIGNED16): none of that is refused here; the
types accepted where CiA 301 names one are the drive's
:class:`~omnican.protocol.vendors.Quirks`. What is refused is a file no drive could
have, before a frame is sent.

Pure: it reads a parsed :class:`canopen.ObjectDictionary`. canopen turns a data type
it does not know into DOMAIN; ``declared`` (a function of the variable) gives the
type the file itself declares, for the message.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from typing import NamedTuple

from canopen import objectdictionary as od
from canopen.objectdictionary import datatypes as dt

from omnican.protocol.cia301 import (
    CONSUMER_HEARTBEAT_TIME,
    DEVICE_TYPE,
    ERROR_REGISTER,
    IDENTITY,
    MAX_PDOS,
    PDO_COB_ID,
    PDO_EVENT_TIMER,
    PDO_INHIBIT_TIME,
    PDO_TRANSMISSION_TYPE,
    PRODUCER_HEARTBEAT_TIME,
    RPDO_COMM,
    RPDO_MAP,
    TPDO_COMM,
    TPDO_MAP,
)
from omnican.protocol.vendors import UNSIGNED_TYPES, Quirks, quirks_of

#: The types an object omnican sends or reads as a number may have.
INTEGER_TYPES = UNSIGNED_TYPES | {dt.INTEGER8, dt.INTEGER16, dt.INTEGER24, dt.INTEGER32,
                                  dt.INTEGER40, dt.INTEGER48, dt.INTEGER56, dt.INTEGER64}

#: CiA 301 names of the data types, by code (0x0020-0x0023 define structures).
TYPE_NAMES: dict[int, str] = {
    value: name for name, value in vars(dt).items()
    if name.isupper() and isinstance(value, int) and not isinstance(value, bool)
}

DeclaredType = Callable[[od.ODVariable], int]


def type_name(code: int) -> str:
    """``0x0007 UNSIGNED32``; ``0x0020 PDO_COMMUNICATION_PARAMETER, a structure``."""
    name = TYPE_NAMES.get(code)
    if name is None:
        return f"0x{code:04X}, not a CiA 301 data type"
    if code >= dt.PDO_COMMUNICATION_PARAMETER:
        return f"0x{code:04X} {name}, a structure"
    return f"0x{code:04X} {name}"


class Want(NamedTuple):
    """One sub-index omnican relies on: its CiA 301 name and the types it may have."""

    subindex: int
    name: str
    types: frozenset[int]
    type_text: str


U16 = frozenset({dt.UNSIGNED16})
U32 = frozenset({dt.UNSIGNED32})


def types_text(types: frozenset[int]) -> str:
    """``an unsigned integer``, ``UNSIGNED8``, ``UNSIGNED8 or UNSIGNED16``."""
    if types == UNSIGNED_TYPES:
        return "an unsigned integer"
    return " or ".join(TYPE_NAMES.get(t, f"0x{t:04X}") for t in sorted(types))


def _sub0(quirks: Quirks) -> Want:
    """A record's sub 0 (its highest sub-index), as the drive's quirks allow it."""
    return Want(0, "", quirks.sub0_types, types_text(quirks.sub0_types))


def _declared_type(var: od.ODVariable) -> int:
    return var.data_type or 0


def _sub(record: od.ODRecord | od.ODArray, subindex: int) -> od.ODVariable | None:
    var = record.subindices.get(subindex)
    return var if isinstance(var, od.ODVariable) else None


def _type_problem(var: od.ODVariable, what: str, types: frozenset[int], type_text: str,
                  declared: DeclaredType) -> str | None:
    code = declared(var)
    if code in types and var.data_type in types:
        return None
    return f"{what} has DataType {type_name(code)}; omnican needs {type_text}"


def _record_problems(dictionary: od.ObjectDictionary, index: int, name: str,
                     required: Iterable[Want], optional: Iterable[Want], why: str,
                     declared: DeclaredType, entries: Want | None = None) -> Iterator[str]:
    """A record's (or array's) sub-indices: ``required`` must be there (``why``),
    ``optional`` and every other sub-index from 1 on (``entries``) must have the right
    type if there."""
    item = dictionary.get(index)
    where = f"0x{index:04X} {name}"
    if item is None:
        yield f"{where} is missing ({why})"
        return
    if not isinstance(item, (od.ODRecord, od.ODArray)):
        yield f"{where} is a VAR; CiA 301 defines it as a RECORD with sub-indices"
        return
    checked: set[int] = set()
    for want in required:
        var = _sub(item, want.subindex)
        sub_name = want.name or "highest sub-index supported"
        if var is None:
            yield f"{where} has no sub-index {want.subindex} ({sub_name}; {why})"
            continue
        checked.add(want.subindex)
        problem = _type_problem(var, f"{where} sub-index {want.subindex} ({sub_name})",
                                want.types, want.type_text, declared)
        if problem:
            yield problem
    for want in optional:
        var = _sub(item, want.subindex)
        if var is not None:
            checked.add(want.subindex)
            problem = _type_problem(var, f"{where} sub-index {want.subindex} ({want.name})",
                                    want.types, want.type_text, declared)
            if problem:
                yield problem
    if entries is not None:
        for subindex in sorted(item.subindices):
            var = _sub(item, subindex)
            if subindex == 0 or subindex in checked or var is None:
                continue
            problem = _type_problem(var, f"0x{index:04X}:{subindex:02X} ({name} entry)",
                                    entries.types, entries.type_text, declared)
            if problem:
                yield problem


def _variable_problems(dictionary: od.ObjectDictionary, index: int, name: str,
                       types: frozenset[int], type_text: str, why: str,
                       declared: DeclaredType) -> Iterator[str]:
    item = dictionary.get(index)
    where = f"0x{index:04X} {name}"
    if item is None:
        yield f"{where} is missing ({why})"
    elif not isinstance(item, od.ODVariable):
        yield f"{where} is not a VAR ({why})"
    else:
        problem = _type_problem(item, where, types, type_text, declared)
        if problem:
            yield problem


def _pdo_problems(dictionary: od.ObjectDictionary, declared: DeclaredType,
                  quirks: Quirks) -> Iterator[str]:
    """Every PDO the EDS offers: omnican maps it, or disables it through its COB-ID."""
    u8 = _sub0(quirks)
    parameter, parameter_text = quirks.pdo_parameter_types, types_text(
        quirks.pdo_parameter_types)
    for kind, comm_base, map_base in (("RPDO", RPDO_COMM, RPDO_MAP),
                                      ("TPDO", TPDO_COMM, TPDO_MAP)):
        for n in range(MAX_PDOS):
            comm_index, map_index = comm_base + n, map_base + n
            has_comm, has_map = comm_index in dictionary, map_index in dictionary
            if not (has_comm or has_map):
                continue
            comm_name = f"{kind}{n + 1} communication parameter"
            map_name = f"{kind}{n + 1} mapping parameter"
            if not has_comm:
                yield (f"0x{comm_index:04X} {comm_name} is missing, though its mapping "
                       f"parameter 0x{map_index:04X} is there")
                continue
            if not has_map:
                yield (f"0x{map_index:04X} {map_name} is missing, though its communication "
                       f"parameter 0x{comm_index:04X} is there")
                continue
            yield from _record_problems(
                dictionary, comm_index, comm_name,
                required=(u8, Want(PDO_COB_ID, "COB-ID", U32, "UNSIGNED32"),
                          Want(PDO_TRANSMISSION_TYPE, "transmission type", parameter,
                               parameter_text)),
                optional=(Want(PDO_INHIBIT_TIME, "inhibit time", parameter, parameter_text),
                          Want(PDO_EVENT_TIMER, "event timer", parameter, parameter_text)),
                why="mandatory in CiA 301", declared=declared)
            yield from _record_problems(
                dictionary, map_index, map_name, required=(u8,), optional=(),
                why="mandatory in CiA 301", declared=declared,
                entries=Want(1, "", U32, "UNSIGNED32 (index, sub-index, bits)"))


def dictionary_problems(dictionary: od.ObjectDictionary,
                        declared: DeclaredType = _declared_type) -> list[str]:
    """What is wrong with the node-wide objects of ``dictionary``, one text each
    (``0x1000 device type is missing (mandatory in CiA 301)``); empty if nothing. The
    types accepted where CiA 301 names one are the drive's quirks (:func:`quirks_of`)."""
    mandatory = "mandatory in CiA 301"
    quirks = quirks_of(dictionary)
    u8 = _sub0(quirks)
    problems = [
        *_variable_problems(dictionary, DEVICE_TYPE, "device type", U32, "UNSIGNED32",
                            mandatory, declared),
        *_variable_problems(dictionary, ERROR_REGISTER, "error register",
                            frozenset({dt.UNSIGNED8}), "UNSIGNED8", mandatory, declared),
    ]
    problems += _record_problems(
        dictionary, IDENTITY, "identity object",
        required=(u8, Want(1, "vendor-ID", U32, "UNSIGNED32")),
        optional=(Want(2, "product code", U32, "UNSIGNED32"),
                  Want(3, "revision number", U32, "UNSIGNED32"),
                  Want(4, "serial number", U32, "UNSIGNED32")),
        why=mandatory, declared=declared)
    problems += _variable_problems(dictionary, PRODUCER_HEARTBEAT_TIME,
                                   "producer heartbeat time", U16, "UNSIGNED16",
                                   "omnican sets each drive's heartbeat", declared)
    consumer = dictionary.get(CONSUMER_HEARTBEAT_TIME)
    if isinstance(consumer, (od.ODArray, od.ODRecord)):  # a VAR: taken as no consumer
        problems += _record_problems(
            dictionary, CONSUMER_HEARTBEAT_TIME, "consumer heartbeat time",
            required=(u8, Want(1, "consumer heartbeat time 1", U32, "UNSIGNED32")),
            optional=(), why="omnican sets it to watch the host's heartbeat", declared=declared)
    problems += _pdo_problems(dictionary, declared, quirks)
    return problems


def variable_problem(var: od.ODVariable, name: str, declared: DeclaredType = _declared_type,
                     bits: int | None = None, min_bits: int | None = None) -> str | None:
    """An object omnican sends or reads as a number: an integer type (of ``bits`` bits,
    where omnican writes it with a fixed width; of at least ``min_bits``, where the
    values it carries need them: the controlword's and the statusword's bits go up to
    15). None if it is one."""
    where = f"0x{var.index:04X}:{var.subindex:02X} {name}"
    if min_bits is not None:
        wide = frozenset(t for t in INTEGER_TYPES
                         if od.ODVariable.STRUCT_TYPES[t].size * 8 >= min_bits)
        return _type_problem(var, where, wide, f"an integer type of at least {min_bits} bits",
                             declared)
    if bits is None:
        return _type_problem(var, where, INTEGER_TYPES, "an integer type", declared)
    types = frozenset(t for t in INTEGER_TYPES
                      if od.ODVariable.STRUCT_TYPES[t].size * 8 == bits)
    return _type_problem(var, where, types, f"a {bits}-bit integer type", declared)


def one_line(problems: list[str]) -> str:
    """The first problem, and how many more there are."""
    more = len(problems) - 1
    return problems[0] + (f" (and {more} more problem{'s' if more > 1 else ''})" if more else "")


# ------------------------------------------------ what the control loop needs of it

def value_range(bits: int, signed: bool) -> tuple[int, int]:
    """The integers a ``bits``-wide object holds."""
    return (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if signed else (0, (1 << bits) - 1)


def width_problem(where: str, bits: int, signed: bool, largest: float, why: str) -> str | None:
    """An object omnican sends values up to +-``largest`` in: its type holds them (else
    the drive gets a capped value, or a wrapped one). None if it does."""
    lo, hi = value_range(bits, signed)
    if -largest >= lo and largest <= hi:
        return None
    kind = "signed" if signed else "unsigned"
    return (f"{where} is {bits}-bit {kind} ({lo} to {hi}): too narrow for "
            f"+-{largest:.0f} ({why})")


def counter_problem(where: str, bits: int, counts_per_cycle: float, cycles: int,
                    why: str) -> str | None:
    """A counter read once a cycle: it must not move half its span in ``cycles``
    cycles (a sample or a few lost), or a wrap cannot be told from a step back."""
    half = 1 << (bits - 1)
    if counts_per_cycle * cycles < half:
        return None
    return (f"{where} is {bits}-bit (wraps every {1 << bits} counts): {why} moves it "
            f"{counts_per_cycle:.0f} counts a cycle, so a wrap cannot be told from a step back; "
            f"omnican needs under {half // cycles} counts a cycle (a wider type, or a lower "
            "position_scale)")


def access_problem(var: od.ODVariable, where: str, write: bool, why: str) -> str | None:
    """An object omnican writes (``write``) or reads: its EDS access allows it."""
    if (var.writable if write else var.readable):
        return None
    need = "writes" if write else "reads"
    return f"{where} is AccessType {var.access_type}; omnican {need} it ({why})"


def modes_problem(where: str, offered: frozenset[int], mode: int, mode_name: str,
                  velocity_modes: dict[int, str], configured: bool) -> str | None:
    """6502h, where the EDS gives its value (0: not given): a velocity mode, and the
    chosen one."""
    if not offered or mode in offered:
        return None
    names = ", ".join(velocity_modes.values())
    if not offered & velocity_modes.keys():
        return (f"{where} offers no velocity mode ({names}); omnican drives each wheel in "
                "one of them")
    have = ", ".join(velocity_modes[m] for m in sorted(offered & velocity_modes.keys()))
    return (f"{where} does not offer mode {mode_name}{' (configured)' if configured else ''}; "
            f"it offers {have}")
