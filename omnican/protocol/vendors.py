"""What omnican knows of particular drives, in one place, keyed by what their EDS says
they are: the vendor-ID ([DeviceInfo] VendorNumber, or 1018h sub 1's default) and the
product ([DeviceInfo] ProductName and ProductNumber, or 1018h sub 2's default).

Every drive gets :data:`GENERIC`, what omnican forgives any EDS (real drives' files
understate their drives); a drive a row of :data:`VENDORS` names gets that row's
:class:`Quirks` instead. Read by the object map (:mod:`omnican.protocol.object_map`:
which objects hold signed values), the EDS checks (:mod:`omnican.protocol.eds_check`:
the data types accepted where CiA 301 names one) and ``omnican check-config`` (what a
drive without a heartbeat consumer does when the host dies).

A drive of another vendor: a row here, matched by its EDS's own identity, and a test
in ``tests/protocol/test_vendors.py`` with its EDS.

Pure: it reads a parsed :class:`canopen.ObjectDictionary`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

from canopen.objectdictionary import datatypes as dt

from omnican.protocol.cia301 import IDENTITY

#: Every unsigned integer type of CiA 301.
UNSIGNED_TYPES = frozenset({dt.UNSIGNED8, dt.UNSIGNED16, dt.UNSIGNED24, dt.UNSIGNED32,
                            dt.UNSIGNED40, dt.UNSIGNED48, dt.UNSIGNED56, dt.UNSIGNED64})


@dataclass(frozen=True)
class Identity:
    """What an EDS says its device is (None or "" where it says nothing)."""

    vendor_number: int | None
    product_number: int | None = None
    product_name: str = ""
    vendor_name: str = ""


@dataclass(frozen=True)
class Quirks:
    """What omnican forgives or knows of one kind of drive."""

    #: Objects (their axis-0 index) read as signed whatever type the EDS declares: CiA
    #: 402 defines them signed (ZLAC8015D's EDS declares 606Ch and 6077h sub 2 unsigned).
    signed: frozenset[int]
    #: Data types a record's sub 0 (its highest sub-index) may have; CiA 301 says
    #: UNSIGNED8 (ZLAC8015D declares its own records' UNSIGNED16).
    sub0_types: frozenset[int]
    #: Data types a PDO's transmission type (CiA 301: UNSIGNED8), inhibit time and event
    #: timer (UNSIGNED16) may have.
    pdo_parameter_types: frozenset[int]
    #: Vendor objects that stop the drive once the bus falls silent, what it does instead
    #: of consuming the host's heartbeat (1016h): (index, sub-index) -> the unit of the
    #: value written there (0 is off).
    watchdogs: Mapping[tuple[int, int], str] = field(default_factory=dict)


#: What every drive gets, and all a drive of a vendor not in :data:`VENDORS` gets.
GENERIC = Quirks(
    signed=frozenset({
        0x6064,  # position actual value
        0x606C,  # velocity actual value
        0x60FF,  # target velocity
        0x6042, 0x6043, 0x6044,  # vl target, demand, actual
        0x6060, 0x6061,  # modes of operation, and its display
        0x6077, 0x6078,  # torque and current actual value
        0x60F4,  # following error actual value
    }),
    sub0_types=UNSIGNED_TYPES,
    pdo_parameter_types=UNSIGNED_TYPES,
)


@dataclass(frozen=True)
class Vendor:
    """One row: the drives it is for, as their EDS names them, and what omnican knows of
    them. A product name or number left None matches any."""

    name: str  # what the drive is, in words
    vendor_number: int
    quirks: Quirks
    product_name: str | None = None
    product_number: int | None = None

    def matches(self, who: Identity) -> bool:
        return (who.vendor_number == self.vendor_number
                and (self.product_name is None or
                     who.product_name.strip().casefold() == self.product_name.casefold())
                and (self.product_number is None or who.product_number == self.product_number))


#: The drives omnican knows, first match wins (a product's row before its vendor's).
VENDORS: tuple[Vendor, ...] = (
    # ZLTECH ZLAC8015D (its EDS: VendorName LHY): both axes on one node as sub-indices,
    # no 6502h, no heartbeat consumer; 2000h "Offline Communication Parameter" stops it
    # after that many ms without frames.
    Vendor("ZLTECH ZLAC8015D", 0x00000100, product_name="ZLAC8015",
           quirks=replace(GENERIC, watchdogs={(0x2000, 0): "ms"})),
    # Roboteq motor controllers: channel 2 at +0x800 (CiA 402-2). Its EDS spells the key
    # "Vendorname", so canopen reads no vendor name: the number names it.
    Vendor("Roboteq motor controller", 0x00000469, quirks=GENERIC),
    # maxon EPOS4: a full single-axis drive; no PDO event timer (sub 5), which omnican
    # sets only where the object dictionary has it.
    Vendor("maxon EPOS4", 0x000000FB, quirks=GENERIC),
)


def _default(dictionary: Any, index: int, subindex: int) -> int | None:
    item = dictionary.get(index)
    var = getattr(item, "subindices", {}).get(subindex) if item is not None else None
    value = getattr(var, "default", None)
    return value if isinstance(value, int) and not isinstance(value, bool) else None


def identity_of(dictionary: Any) -> Identity:
    """What the EDS of ``dictionary`` (a :class:`canopen.ObjectDictionary`) says its
    device is: [DeviceInfo], else 1018h's defaults."""
    info = dictionary.device_information
    vendor = info.vendor_number
    product = info.product_number
    return Identity(
        vendor_number=vendor if vendor is not None else _default(dictionary, IDENTITY, 1),
        product_number=product if product is not None else _default(dictionary, IDENTITY, 2),
        product_name=(info.product_name or "").strip(),
        vendor_name=(info.vendor_name or "").strip())


def vendor_for(who: Identity) -> Vendor | None:
    """The row of :data:`VENDORS` for ``who``; None: a drive omnican knows nothing of."""
    return next((v for v in VENDORS if v.matches(who)), None)


def quirks_of(dictionary: Any) -> Quirks:
    """What omnican forgives or knows of the drive ``dictionary`` describes."""
    vendor = vendor_for(identity_of(dictionary))
    return vendor.quirks if vendor is not None else GENERIC
