"""The ``[[wheel.sdo]]`` writes: objects a drive needs set at every configuration,
written in PRE-OPERATIONAL at startup, after a reboot and after the bus comes back
(the ZLAC8015D's communication-offline timeout, 2000h, is one: that drive has no
heartbeat consumer).

Each write is checked against the drive's EDS before anything is sent: the object
exists, is writable, has an integer (or boolean) type the write's type matches, and
the value fits that type and the EDS's LowLimit/HighLimit. Pure: a parsed object
dictionary in, the bytes to write out.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

from canopen import objectdictionary as od
from canopen.objectdictionary import datatypes

from omnican.config import SDO_TYPES, SdoWrite, WheelConfig
from omnican.errors import ConfigError
from omnican.protocol.object_map import Entry, variable_at

#: EDS data types a written object may have: (bits, signed).
_EDS_TYPES: dict[int, tuple[int, bool]] = {
    datatypes.BOOLEAN: (8, False), datatypes.INTEGER8: (8, True),
    datatypes.INTEGER16: (16, True), datatypes.INTEGER32: (32, True),
    datatypes.UNSIGNED8: (8, False), datatypes.UNSIGNED16: (16, False),
    datatypes.UNSIGNED32: (32, False),
}
_TYPE_NAMES = {datatypes.BOOLEAN: "BOOLEAN", datatypes.INTEGER8: "INTEGER8",
               datatypes.INTEGER16: "INTEGER16", datatypes.INTEGER32: "INTEGER32",
               datatypes.UNSIGNED8: "UNSIGNED8", datatypes.UNSIGNED16: "UNSIGNED16",
               datatypes.UNSIGNED32: "UNSIGNED32"}


@dataclass(frozen=True)
class VendorWrite:
    """One ``[[wheel.sdo]]`` write, resolved: ``data`` goes to ``entry`` by expedited SDO."""

    entry: Entry
    value: int
    data: bytes
    origin: str  # where the config gave it, e.g. "wheel[0].sdo[1]"

    def describe(self) -> str:
        return f"{self.entry.name} ({self.entry.address}) = {self.value} ({self.origin})"


def resolve(dictionary: od.ObjectDictionary, sdo: SdoWrite, axis: int,
            origin: str) -> VendorWrite:
    """Check one write against the EDS; :class:`ConfigError` (one line) if it cannot
    be written as given."""
    from omnican.plan.health import find_object

    try:
        entry = find_object(dictionary, sdo.object, axis)
    except ConfigError as exc:
        raise ConfigError(f"{origin}.object: {exc}") from None
    what = f"{origin}: {entry.name} ({entry.address})"
    var = variable_at(dictionary, entry.index, entry.subindex)
    assert var is not None  # find_object returns variables only
    if not var.writable:
        raise ConfigError(f"{what} is not writable (AccessType {var.access_type})")
    eds_type = _EDS_TYPES.get(var.data_type or 0)
    if sdo.type is not None:
        given = SDO_TYPES[sdo.type]
        if eds_type is not None and given != eds_type:
            raise ConfigError(f"{what}: type {sdo.type} does not match the EDS's "
                              f"{_TYPE_NAMES[var.data_type or 0]}")
        bits, signed = given
    elif eds_type is not None:
        bits, signed = eds_type
    else:
        raise ConfigError(f"{what} has DataType 0x{var.data_type or 0:04X}: omnican writes "
                          "integers and booleans (give type if the EDS is wrong)")
    value = _integer(sdo.value, var.data_type == datatypes.BOOLEAN or sdo.type == "bool",
                     what)
    lo, hi = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if signed else (0, (1 << bits) - 1)
    if isinstance(var.min, int):
        lo = max(lo, var.min)
    if isinstance(var.max, int):
        hi = min(hi, var.max)
    if not lo <= value <= hi:
        raise ConfigError(f"{what}: {sdo.value!r} is out of range {lo}-{hi}")
    return VendorWrite(entry, value, value.to_bytes(bits // 8, "little", signed=signed), origin)


def _integer(value: int | float | bool, boolean: bool, what: str) -> int:
    if boolean:
        if not isinstance(value, bool) and value not in (0, 1):
            raise ConfigError(f"{what} is a boolean: give true or false, got {value!r}")
        return int(value)
    if isinstance(value, bool):
        raise ConfigError(f"{what} is an integer, got {value!r}")
    if isinstance(value, float):
        if not value.is_integer():
            raise ConfigError(f"{what} is an integer, got {value!r}")
        return int(value)
    return value


def overwrite_problem(writes: Sequence[VendorWrite],
                      owned: Callable[[int, int], str | None]) -> str | None:
    """The first write that would overwrite an object omnican configures itself
    (``owned(index, subindex)`` says what for; None: not omnican's). They are
    written after omnican's own configuration, so such a write would undo it."""
    for write in writes:
        why = owned(write.entry.index, write.entry.subindex)
        if why is not None:
            return (f"{write.origin}: {write.entry.name} ({write.entry.address}) is set by "
                    f"omnican ({why}); a vendor setting would overwrite it")
    return None


def vendor_writes(dictionary: od.ObjectDictionary,
                  wheels: Sequence[tuple[int, WheelConfig]]) -> tuple[VendorWrite, ...]:
    """The ``[[wheel.sdo]]`` writes of a node's wheels, resolved, in order; one object given twice
    must have one value."""
    out: dict[tuple[int, int], VendorWrite] = {}
    for index, wheel in wheels:
        for k, sdo in enumerate(wheel.sdo_writes):
            write = resolve(dictionary, sdo, wheel.axis, f"wheel[{index}].sdo[{k}]")
            key = (write.entry.index, write.entry.subindex)
            seen = out.get(key)
            if seen is not None and seen.value != write.value:
                raise ConfigError(f"{write.origin}: {write.entry.name} ({write.entry.address}) "
                                  f"is {write.value} here and {seen.value} in {seen.origin}")
            out.setdefault(key, write)
    return tuple(out.values())
