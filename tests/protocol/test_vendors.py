"""Vendor knowledge has one home (:mod:`omnican.protocol.vendors`), keyed by what an EDS
says its device is (issue 39 step 3): each real drive's EDS is matched by its own
identity; a drive of a vendor omnican does not know gets the generic behaviour; the
object map and the EDS checks read the drive's row."""

from __future__ import annotations

import configparser
from dataclasses import replace
from pathlib import Path

import pytest
from canopen import objectdictionary as od
from canopen.objectdictionary import datatypes as dt
from hypothesis import given
from hypothesis import strategies as st

from omnican import WHEEL_EDS
from omnican.protocol import eds_check, vendors
from omnican.protocol.object_map import AxisObjects, Obj, load_dictionary
from omnican.protocol.vendors import (
    GENERIC,
    VENDORS,
    Identity,
    Vendor,
    identity_of,
    quirks_of,
    vendor_for,
)
from tests.protocol.test_eds_check import edit_eds
from tests.support.helpers import VENDOR_EDS

STRANGER = 0x12345678  # a vendor-ID no row of the table has

REAL = {"zlac8015d.eds": "ZLTECH ZLAC8015D", "roboteq_v80_21.eds": "Roboteq motor controller",
        "maxon_epos4.eds": "maxon EPOS4"}


def device_info(path: Path) -> configparser.SectionProxy:
    """The file's own [DeviceInfo], read apart from canopen (keys in any case)."""
    parser = configparser.RawConfigParser(strict=False)
    parser.read(path)
    return parser["DeviceInfo"]


@pytest.mark.parametrize("name", sorted(REAL))
def test_each_real_drive_is_known_by_what_its_own_eds_says(name: str) -> None:
    path = VENDOR_EDS / name
    info = device_info(path)
    dictionary = load_dictionary(path)
    who = identity_of(dictionary)
    assert who.vendor_number == int(info["vendornumber"], 0)
    assert who.product_number == int(info["productnumber"], 0)
    assert who.product_name == info["productname"].strip()
    vendor = vendor_for(who)
    assert vendor is not None and vendor.name == REAL[name]
    assert quirks_of(dictionary) is vendor.quirks


def test_the_vendor_id_is_read_from_1018h_where_deviceinfo_has_none(tmp_path: Path) -> None:
    eds = tmp_path / "zlac.eds"
    text = (VENDOR_EDS / "zlac8015d.eds").read_text()
    eds.write_text("\n".join(line for line in text.splitlines()
                             if not line.startswith("VendorNumber=")) + "\n")
    dictionary = load_dictionary(eds)
    assert dictionary.device_information.vendor_number is None
    who = identity_of(dictionary)
    assert who.vendor_number == 0x100  # 1018h sub 1's DefaultValue
    found = vendor_for(who)
    assert found is not None and found.name == "ZLTECH ZLAC8015D"


def stranger_zlac(tmp_path: Path) -> Path:
    """The ZLAC8015D's EDS as another vendor's: everything but the vendor-ID the same."""
    return edit_eds(tmp_path / "stranger.eds", set_key={
        "DeviceInfo": ("VendorNumber", f"0x{STRANGER:08X}"),
        "1018sub1": ("DefaultValue", f"0x{STRANGER:08X}")}, source=VENDOR_EDS / "zlac8015d.eds")


def test_a_drive_of_an_unknown_vendor_gets_the_generic_behaviour(tmp_path: Path) -> None:
    assert all(v.vendor_number != STRANGER for v in VENDORS)
    dictionary = load_dictionary(stranger_zlac(tmp_path))
    who = identity_of(dictionary)
    assert who.vendor_number == STRANGER and who.product_name == "ZLAC8015"
    assert vendor_for(who) is None
    assert quirks_of(dictionary) is GENERIC
    assert GENERIC.watchdogs == {}  # its 2000h is nothing omnican knows of
    # What any drive is forgiven: 606Ch declared UNSIGNED32, read as signed (CiA 402).
    right = AxisObjects(dictionary, 1)[Obj.VELOCITY_ACTUAL]
    assert right.signed and not right.declared_signed


def test_the_object_map_and_the_eds_checks_read_the_drives_row(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A row that forgives nothing, for one vendor: its drives' EDS files are checked to
    the letter of CiA 301 and read as they declare; the same files as another vendor's
    are not."""
    strict = replace(GENERIC, signed=frozenset(), sub0_types=frozenset({dt.UNSIGNED8}),
                     pdo_parameter_types=frozenset({dt.UNSIGNED8, dt.UNSIGNED16}))
    monkeypatch.setattr(vendors, "VENDORS", (Vendor("strict", STRANGER, quirks=strict),
                                             *VENDORS))
    zlac = load_dictionary(stranger_zlac(tmp_path))
    assert quirks_of(zlac) is strict
    assert not AxisObjects(zlac, 1)[Obj.VELOCITY_ACTUAL].signed  # as declared, UNSIGNED32
    assert AxisObjects(load_dictionary(VENDOR_EDS / "zlac8015d.eds"), 1)[
        Obj.VELOCITY_ACTUAL].signed

    def sub0_u16(path: Path, vendor: int) -> Path:
        return edit_eds(path, set_key={
            "DeviceInfo": ("VendorNumber", f"0x{vendor:08X}"),
            "1018sub1": ("DefaultValue", f"0x{vendor:08X}"),
            "1800sub0": ("DataType", "0x0006")}, source=WHEEL_EDS)

    strict_eds = sub0_u16(tmp_path / "strict.eds", STRANGER)
    generic_eds = sub0_u16(tmp_path / "generic.eds", STRANGER + 1)
    assert eds_check.dictionary_problems(od.import_od(str(generic_eds))) == []
    assert eds_check.dictionary_problems(od.import_od(str(strict_eds))) == [
        "0x1800 TPDO1 communication parameter sub-index 0 (highest sub-index supported) has "
        "DataType 0x0006 UNSIGNED16; omnican needs UNSIGNED8"]


# -- the table's matching, as a property -------------------------------------------------

names = st.text(st.characters(codec="ascii", categories=("L", "N", "Zs")), max_size=12)
numbers = st.none() | st.integers(0, 0xFFFFFFFF)


@given(st.integers(0, 0xFFFFFFFF), numbers, names)
def test_a_vendor_id_no_row_has_finds_no_row(vendor: int, product: int | None,
                                              name: str) -> None:
    if any(v.vendor_number == vendor for v in VENDORS):
        return
    assert vendor_for(Identity(vendor, product, name)) is None


@given(st.sampled_from(VENDORS), numbers, names, st.sampled_from(["", " ", "  "]))
def test_a_row_matches_what_it_names_and_leaves_the_rest_open(
        row: Vendor, product: int | None, name: str, pad: str) -> None:
    shown = row.product_name if row.product_name is not None else name
    number = row.product_number if row.product_number is not None else product
    who = Identity(row.vendor_number, number, f"{pad}{shown.upper()}{pad}")
    assert row.matches(who)
    found = vendor_for(who)
    assert found is not None and found.matches(who)
    assert VENDORS.index(found) <= VENDORS.index(row)  # the first row that matches
    if row.product_name is not None:
        assert not row.matches(replace(who, product_name=f"{row.product_name}X"))
    assert not row.matches(replace(who, vendor_number=row.vendor_number + 1))
