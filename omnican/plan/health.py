"""What each drive reports of its health, and how omnican reads it: the plan.

Per wheel: the motor current (6078h, per mille of the rated current 6075h, unless the
config names another object and its scale), the torque (6077h, per mille of the rated
torque), a temperature (a vendor object the config names), and the following error
(60F4h, informative: read only where a PDO has room for it). Per node: the DC link
voltage (6079h in mV, or the config's object and scale), the error register (1001h)
and, where the e-stop is wired to this node, its input (60FDh or the config's object;
a statusword bit needs no read). A config names an object as ``"0xIIII:SS"``,
``"0xIIII"`` (the axis's copy: CiA 402-2 offsets or sub-indices, as
:class:`omnican.protocol.object_map.AxisObjects` resolves them) or by its EDS entry's name.

They are read a few times a second (``chassis.health_rate_hz``), never in the way of the
control loop: what the EDS marks PDO-mappable goes into the node's spare TPDOs, sent
every n-th SYNC (or, where the drive cannot, on an event timer); the rest is read one
object at a time by expedited SDO, round robin, sent with the cycle's frames.

Pure: reads a parsed object dictionary, no I/O.
"""

from __future__ import annotations

import difflib
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, replace

from canopen import objectdictionary as od

from omnican.config import SCHEMA, EstopSettings, WheelConfig
from omnican.errors import ConfigError
from omnican.plan.health_fields import HEALTH_FIELDS
from omnican.plan.pdo import MAX_PDO_BITS, SDO_TRANSFER_BITS, PdoSlot, PlannedPdo, frame_bits
from omnican.protocol.cia301 import ERROR_REGISTER, TPDO_COMM, TRANS_EVENT, TRANS_SYNC_MAX
from omnican.protocol.object_map import AxisObjects, Entry, Obj, entry_at, variable_at

#: What is read, in the order the spare PDOs are filled (most wanted first): what the
#: drives report (omnican.plan.health_fields), then what the checks alone read.
QUANTITIES = (*(f.quantity for f in HEALTH_FIELDS), "estop", "following_error")
PER_AXIS = frozenset({f.quantity for f in HEALTH_FIELDS if f.per_axis} | {"following_error"})
TORQUE_PCT_PER_UNIT = 0.1  # 6077h: per mille -> percent
#: SI per unit of a value whose config gives no ``<quantity>_scale`` (a standard's unit)
FIXED_SCALES = {"torque": TORQUE_PCT_PER_UNIT}
_ADDRESS = re.compile(r"0x([0-9a-fA-F]{1,4})(?::(?:0x)?([0-9a-fA-F]{1,2}))?")
_WHEEL_KEYS = SCHEMA["wheel"]
#: Per value a wheel's config names the object of (its key is the quantity), that
#: config key and the one giving its scale (None: FIXED_SCALES'), in the table's order.
_CONFIGURED = tuple((f.quantity, f"{f.quantity}_scale" if f"{f.quantity}_scale" in _WHEEL_KEYS
                     else None) for f in HEALTH_FIELDS if f.quantity in _WHEEL_KEYS)
#: The [[wheel]] keys that say what its drive reports: objects and their scales.
CONFIG_KEYS = tuple(key for pair in _CONFIGURED for key in pair if key is not None)
#: The values whose SI units per count the config gives (else a standard's: 6077h).
CONFIG_SCALED = frozenset(quantity for quantity, key in _CONFIGURED if key is not None)


@dataclass(frozen=True)
class HealthRead:
    """One object read for health: what it is, which wheels it describes (a node-wide
    object: each of the node's wheels), and its SI units per unit (None: the current of
    6078h, whose scale comes from the rated current read at startup)."""

    quantity: str  # one of QUANTITIES
    entry: Entry
    wheels: tuple[int, ...]  # wheel indices
    scale: float | None
    pdo_only: bool = False  # informative: not worth an SDO of its own

    @property
    def key(self) -> tuple[int, int]:
        return (self.entry.index, self.entry.subindex)

    def describe(self) -> str:
        return f"{self.quantity.replace('_', ' ')} {self.entry.name} ({self.entry.address})"


@dataclass(frozen=True)
class HealthPlan:
    """How one node's health is read: TPDOs every ``every``-th SYNC (or on their event
    timer), the rest by expedited SDO one at a time, each object ``rate_hz`` times a
    second (``sdo_period_s`` between requests)."""

    node_id: int
    reads: tuple[HealthRead, ...]
    pdos: tuple[PlannedPdo, ...] = ()
    sdo: tuple[HealthRead, ...] = ()
    every: int = 1  # SYNCs per health TPDO
    rate_hz: float = 10.0

    @property
    def sdo_period_s(self) -> float:
        return 1.0 / (len(self.sdo) * self.rate_hz) if self.sdo else math.inf

    def bits_per_s(self, loop_rate_hz: float) -> float:
        """Worst-case bits per second the reads add to the bus at ``loop_rate_hz``."""
        pdo = 0.0
        for p in self.pdos:
            per_s = loop_rate_hz / p.trans_type if p.cyclic else (
                1000.0 / (p.event_timer_ms or 1000.0 / self.rate_hz))
            pdo += frame_bits(p.data_bytes) * per_s
        return pdo + SDO_TRANSFER_BITS * len(self.sdo) * self.rate_hz

    def without_pdos(self) -> HealthPlan:
        """Everything by SDO (a drive that keeps its own mapping)."""
        return replace(self, pdos=(), sdo=tuple(r for r in self.reads if not r.pdo_only))

    def describe(self) -> list[str]:
        lines = []
        for p in self.pdos:
            when = (f"every {p.trans_type} SYNC{'s' if p.trans_type > 1 else ''}" if p.cyclic
                    else f"event timer {p.event_timer_ms} ms")
            objs = ", ".join(f"{e.name} ({e.address})" for e in p.entries)
            lines.append(f"health TPDO{p.number} 0x{p.cob_id:03X} {when}, {p.data_bytes} "
                         f"bytes: {objs}")
        if self.sdo:
            names = ", ".join(f"{r.entry.name} ({r.entry.address})" for r in self.sdo)
            lines.append(f"health by expedited SDO, one every {1000 * self.sdo_period_s:.0f} ms "
                         f"round robin ({self.rate_hz:g} Hz each): {names}")
        if not self.reads:
            lines.append("health: the EDS names none of the objects omnican reads")
        return lines


# ------------------------------------------------------------------ naming objects


def find_object(dictionary: od.ObjectDictionary, spec: str, axis: int) -> Entry:
    """The entry a config names for ``axis``: ``"0xIIII:SS"``, ``"0xIIII"`` (this axis's
    copy) or an EDS entry's name (a record's: this axis's sub-index). Raises
    :class:`ConfigError` (one line) when the EDS has no such object."""
    m = _ADDRESS.fullmatch(spec.strip())
    if m:
        index = int(m.group(1), 16)
        if m.group(2) is not None:
            sub = int(m.group(2), 16)
            if variable_at(dictionary, index, sub) is None:
                raise ConfigError(f"the EDS has no object 0x{index:04X}:{sub:02X}")
            return entry_at(dictionary, index, sub)
        return _axis_copy(dictionary, index, axis, f"0x{index:04X}")
    wanted = _name_key(spec)
    for item in dictionary.values():
        if _name_key(item.name) == wanted:
            return _axis_copy(dictionary, item.index, axis, repr(spec))
        if not isinstance(item, od.ODVariable):
            for var in item.values():
                if _name_key(var.name) == wanted and var.subindex > 0:
                    return entry_at(dictionary, var.index, var.subindex)
    names = [item.name for item in dictionary.values()]
    names += [v.name for item in dictionary.values() if not isinstance(item, od.ODVariable)
              for v in item.values()]
    close = difflib.get_close_matches(spec, names, n=1, cutoff=0.6)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    raise ConfigError(f"the EDS has no object named {spec!r}{hint}")


def _name_key(name: str) -> str:
    return " ".join(name.replace("_", " ").split()).lower()


def _axis_copy(dictionary: od.ObjectDictionary, index: int, axis: int, what: str) -> Entry:
    """Axis ``axis``'s copy of object ``index``: as AxisObjects for the CiA 402 objects,
    else the variable itself (the node's one copy, for every axis) or sub-index
    ``axis + 1`` of a record or array."""
    if index in Obj._value2member_map_:
        entry = AxisObjects(dictionary, axis).get(Obj(index))
        if entry is not None:
            return entry
    item = dictionary.get(index)
    if isinstance(item, od.ODVariable):
        return entry_at(dictionary, index, 0)
    if item is not None and not isinstance(item, od.ODVariable) and axis + 1 in item.subindices:
        return entry_at(dictionary, index, axis + 1)
    if item is None:
        raise ConfigError(f"the EDS has no object {what}")
    raise ConfigError(f"the EDS has no copy of {what} ({item.name}) for axis {axis}: name "
                      "its sub-index (\"0xIIII:SS\")")


def wheel_reads(dictionary: od.ObjectDictionary, wheel_index: int,
                wheel: WheelConfig) -> list[HealthRead]:
    """The health objects of one wheel, as its config names them (the defaults only
    where the EDS has them): for each value of :data:`~omnican.plan.health_fields.HEALTH_FIELDS`
    whose object the config names (the key ``<quantity>``; ``<quantity>_scale``, SI per
    unit), and the following error. Raises ConfigError naming the key."""
    out = []
    for quantity, scale_key in _CONFIGURED:
        spec: str | None = getattr(wheel, quantity)
        scale: float | None = (getattr(wheel, scale_key) if scale_key is not None else
                               FIXED_SCALES.get(quantity, 1.0))
        if not spec:
            continue
        try:
            entry = find_object(dictionary, spec, wheel.axis)
        except ConfigError as exc:
            if spec == _WHEEL_KEYS[quantity].default:
                continue  # a standard object this drive does not have
            raise ConfigError(f"{quantity}: {exc}") from None
        if entry.bits > 32 or entry.bits % 8:
            raise ConfigError(f"{quantity}: {entry.name} ({entry.address}) has {entry.bits} "
                              "bits; omnican reads integers of 8, 16 or 32 bits")
        if quantity == "current" and scale is None and entry.obj is not Obj.CURRENT_ACTUAL:
            raise ConfigError(f"current: {entry.name} ({entry.address}) is not 6078h: give "
                              "current_scale (A per unit)")
        out.append(HealthRead(quantity, entry, (wheel_index,), scale))
    following = AxisObjects(dictionary, wheel.axis).get(Obj.FOLLOWING_ERROR)
    if following is not None:
        out.append(HealthRead("following_error", following, (wheel_index,), 1.0, pdo_only=True))
    return out


def node_reads(dictionary: od.ObjectDictionary, node_id: int,
               wheels: Sequence[tuple[int, WheelConfig]],
               estop: EstopSettings | None) -> list[HealthRead]:
    """Every health object of one node, each once (a node-wide object describes all of
    its wheels), in :data:`QUANTITIES` order."""
    reads: dict[tuple[int, int], HealthRead] = {}
    for index, wheel in wheels:
        for r in wheel_reads(dictionary, index, wheel):
            seen = reads.get(r.key)
            if seen is None:
                reads[r.key] = r
            elif seen.quantity == r.quantity:
                reads[r.key] = replace(seen, wheels=seen.wheels + r.wheels)
            else:
                raise ConfigError(f"{r.entry.name} ({r.entry.address}) is both the "
                                  f"{seen.quantity} and the {r.quantity}")
    every = tuple(i for i, _ in wheels)
    if ERROR_REGISTER in dictionary:
        register = entry_at(dictionary, ERROR_REGISTER, 0)
        reads.setdefault(entry_key(register), HealthRead("error_register", register, every, 1.0))
    if estop is not None and estop.node_id in (None, node_id):
        entry = estop_entry(dictionary, estop, wheels[0][1].axis)
        if entry is not None and entry.obj is not Obj.STATUSWORD:
            reads.setdefault(entry_key(entry), HealthRead("estop", entry, every, 1.0))
    return sorted(reads.values(), key=lambda r: QUANTITIES.index(r.quantity))


def entry_key(entry: Entry) -> tuple[int, int]:
    return (entry.index, entry.subindex)


def estop_entry(dictionary: od.ObjectDictionary, estop: EstopSettings, axis: int) -> Entry | None:
    """The object the e-stop shows in on this drive (None: a default object it lacks,
    60FDh, when the e-stop is not said to be on this node)."""
    try:
        entry = find_object(dictionary, estop.object, axis)
    except ConfigError as exc:
        if estop.node_id is None and estop.object == SCHEMA["estop"]["object"].default:
            return None
        raise ConfigError(f"estop.object: {exc}") from None
    if estop.bit >= entry.bits:
        raise ConfigError(f"estop.bit: {entry.name} ({entry.address}) has {entry.bits} bits, "
                          f"no bit {estop.bit}")
    return entry


# ------------------------------------------------------------------ the plan


def plan_health(node_id: int, dictionary: od.ObjectDictionary, reads: Sequence[HealthRead],
                spare: Sequence[PdoSlot], loop_rate_hz: float,
                rate_hz: float) -> HealthPlan:
    """Which of ``reads`` go into the ``spare`` TPDOs (first fit, by the EDS's mapping
    limits), which by SDO. A health TPDO goes every n-th SYNC (n = loop rate / health
    rate, at most 240); a drive whose transmission type cannot say n gets an event timer
    and an inhibit time of one health period instead, where it has both."""
    every = max(1, min(TRANS_SYNC_MAX, round(loop_rate_hz / rate_hz)))
    groups: list[tuple[PdoSlot, list[Entry]]] = []
    free = [s for s in spare if s.max_entries >= 1 and _timing(dictionary, s, every)]
    sdo: list[HealthRead] = []
    for r in reads:
        e = r.entry
        placed = False
        if e.pdo_mappable:
            for slot, group in groups:
                if len(group) < slot.max_entries and sum(x.bits for x in group) + e.bits <= \
                        MAX_PDO_BITS:
                    group.append(e)
                    placed = True
                    break
            if not placed and free:
                groups.append((free.pop(0), [e]))
                placed = True
        if not placed and not r.pdo_only:
            sdo.append(r)
    period_ms = max(1, round(1000.0 / rate_hz))
    pdos = []
    for slot, group in groups:
        assert slot.default_cob_id is not None
        trans = _timing(dictionary, slot, every)
        assert trans is not None  # free slots are those with a timing
        pdos.append(PlannedPdo(slot.number, slot.default_cob_id, trans, tuple(group),
                               inhibit_100us=10 * period_ms if trans == TRANS_EVENT else None,
                               event_timer_ms=period_ms if trans == TRANS_EVENT else None))
    return HealthPlan(node_id, tuple(reads), tuple(pdos), tuple(sdo), every, rate_hz)


def _timing(dictionary: od.ObjectDictionary, slot: PdoSlot, every: int) -> int | None:
    """The transmission type a health TPDO in ``slot`` gets: ``every`` where the EDS's
    transmission type allows it, else event-driven with timer and inhibit time, else
    None (the slot cannot carry it at a few Hz)."""
    if slot.default_cob_id is None:
        return None
    var = variable_at(dictionary, TPDO_COMM + slot.number - 1, 2)
    allowed = var is None or (var.writable and (var.min is None or var.min <= every) and
                              (var.max is None or var.max >= every))
    if allowed:
        return every
    if slot.has_event_timer and slot.has_inhibit:
        return TRANS_EVENT
    return None
