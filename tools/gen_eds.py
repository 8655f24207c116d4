"""Writes omnican's bundled wheel-drive EDS (omnican/eds/omnican_wheel.eds).

The committed EDS is the source of truth; this script records how it was made and
rewrites it after a deliberate change:  python tools/gen_eds.py > omnican/eds/omnican_wheel.eds
Its default PDO mapping equals the plan omnican configures (see `omnican check-config`),
and tools/gen_dbc.py derives dbc/omnican.dbc from it.
"""

from __future__ import annotations

import sys

U8, U16, U32, I8, I16, I32, VSTR = 0x5, 0x6, 0x7, 0x2, 0x3, 0x4, 0x9

out: list[str] = []
objects: list[int] = []


def section(name: str, **values: object) -> None:
    out.append(f"[{name}]")
    out.extend(f"{k}={v}" for k, v in values.items())
    out.append("")


def variable(index: int, name: str, dtype: int, access: str, default: object = None,
             pdo: int = 0, sub: int | None = None) -> None:
    key = f"{index:04X}" if sub is None else f"{index:04X}sub{sub:X}"
    values: dict[str, object] = {"ParameterName": name, "ObjectType": "0x7",
                                 "DataType": f"0x{dtype:04X}", "AccessType": access}
    if default is not None:
        values["DefaultValue"] = default
    values["PDOMapping"] = pdo
    section(key, **values)


def simple(index: int, *args: object, **kwargs: object) -> None:
    objects.append(index)
    variable(index, *args, **kwargs)  # type: ignore[arg-type]


def record(index: int, name: str, subs: list[tuple[object, ...]], otype: str = "0x9") -> None:
    objects.append(index)
    section(f"{index:04X}", SubNumber=len(subs), ParameterName=name, ObjectType=otype)
    for sub, *rest in subs:
        variable(index, *rest, sub=sub)  # type: ignore[arg-type]


def mapping(index: int, title: str, entries: list[str]) -> None:
    subs: list[tuple[object, ...]] = [(0, f"Number of mapped objects in {title}", U8, "rw",
                                       len(entries))]
    for i in range(8):
        value = entries[i] if i < len(entries) else "0x00000000"
        subs.append((i + 1, f"Mapped object {i + 1}", U32, "rw", value))
    record(index, f"{title} mapping parameter", subs)


def communication(index: int, title: str, cob: int, trans: int, inhibit: int,
                  event: int) -> None:
    record(index, f"{title} communication parameter", [
        (0, "Highest sub-index supported", U8, "ro", 5),
        (1, f"COB-ID used by {title}", U32, "rw", f"$NODEID+0x{cob:08X}"),
        (2, f"Transmission type {title}", U8, "rw", trans),
        (3, f"Inhibit time {title}", U16, "rw", inhibit),
        (5, f"Event timer {title}", U16, "rw", event),
    ])


section("FileInfo", FileName="omnican_wheel.eds", FileVersion=1, FileRevision=0, EDSVersion="4.0",
        Description="omnican generic CiA 402 wheel drive (single axis; pv, csv, vl)",
        CreatedBy="omnican", CreationDate="11-23-2026", CreationTime="12:00PM")
section("DeviceInfo", VendorName="omnican", VendorNumber="0x00000000",
        ProductName="omnican wheel drive", ProductNumber="0x00000402",
        RevisionNumber="0x00010000", OrderCode="omnican-wheel", BaudRate_10=0, BaudRate_20=0,
        BaudRate_50=0, BaudRate_125=1, BaudRate_250=1, BaudRate_500=1, BaudRate_800=0,
        BaudRate_1000=1, SimpleBootUpMaster=0, SimpleBootUpSlave=1, Granularity=8,
        DynamicChannelsSupported=0, GroupMessaging=0, NrOfRXPDO=4, NrOfTXPDO=4, LSS_Supported=0)
section("DummyUsage", **{f"Dummy000{i}": 0 for i in range(1, 8)})
section("Comments", Lines=2, Line1="Bundled with omnican; also the default drive of the simulator.",
        Line2="Position in encoder increments; velocity (60FFh, 606Ch) in increments/s; "
              "vl (6042h) in rpm.")
body_start = len(out)

simple(0x1000, "Device type", U32, "ro", "0x00020192")
simple(0x1001, "Error register", U8, "ro", "0x00", pdo=1)
simple(0x1005, "COB-ID SYNC", U32, "rw", "0x00000080")
simple(0x1008, "Manufacturer device name", VSTR, "const", "omnican wheel drive")
simple(0x1014, "COB-ID EMCY", U32, "rw", "$NODEID+0x80")
record(0x1016, "Consumer heartbeat time", [
    (0, "Highest sub-index supported", U8, "ro", 2),
    (1, "Consumer heartbeat time 1", U32, "rw", "0x00000000"),
    (2, "Consumer heartbeat time 2", U32, "rw", "0x00000000"),
], otype="0x8")
simple(0x1017, "Producer heartbeat time", U16, "rw", 0)
record(0x1018, "Identity object", [
    (0, "Highest sub-index supported", U8, "ro", 4),
    (1, "Vendor-ID", U32, "ro", "0x00000000"),
    (2, "Product code", U32, "ro", "0x00000402"),
    (3, "Revision number", U32, "ro", "0x00010000"),
    (4, "Serial number", U32, "ro", "0x00000000"),
])
# PDO defaults = the plan omnican's host configures for the demo base (pv mode, 100 Hz):
# RPDO1 controlword (on change), RPDO2 target velocity (SYNC), TPDO1 statusword +
# mode display + error code (event, 2 ms inhibit, 100 ms event timer), TPDO2 position (SYNC),
# TPDO3 and TPDO4 the health values every 20th SYNC (5 Hz): current, torque, DC link
# voltage; temperature, error register, digital inputs (the e-stop).
RPDOS = [(0x200, 255, ["0x60400010"]), (0x300, 1, ["0x60FF0020"]), (0x80000400, 255, []),
         (0x80000500, 255, [])]
TPDOS = [(0x180, 255, ["0x60410010", "0x60610008", "0x603F0010"], 20, 100),
         (0x280, 1, ["0x60640020"], 0, 0),
         (0x380, 20, ["0x60780010", "0x60770010", "0x60790020"], 0, 0),
         (0x480, 20, ["0x21000010", "0x10010008", "0x60FD0020"], 0, 0)]
for n, (cob, trans, _) in enumerate(RPDOS):
    communication(0x1400 + n, f"RPDO{n + 1}", cob, trans, 0, 0)
for n, (_, _, entries) in enumerate(RPDOS):
    mapping(0x1600 + n, f"RPDO{n + 1}", entries)
for n, (cob, trans, _, inhibit, event) in enumerate(TPDOS):
    communication(0x1800 + n, f"TPDO{n + 1}", cob, trans, inhibit, event)
for n, (_, _, entries, _, _) in enumerate(TPDOS):
    mapping(0x1A00 + n, f"TPDO{n + 1}", entries)

# Manufacturer-specific: the motor winding temperature, 0.1 degC per unit.
simple(0x2100, "Motor temperature", I16, "ro", 250, pdo=1)
simple(0x6007, "Abort connection option code", I16, "rw", 3)
simple(0x603F, "Error code", U16, "ro", 0, pdo=1)
simple(0x6040, "Controlword", U16, "rww", 0, pdo=1)
simple(0x6041, "Statusword", U16, "ro", 0, pdo=1)
simple(0x6042, "vl target velocity", I16, "rww", 0, pdo=1)
simple(0x6043, "vl velocity demand", I16, "ro", 0, pdo=1)
simple(0x6044, "vl velocity actual value", I16, "ro", 0, pdo=1)
for index, name in ((0x6048, "vl velocity acceleration"), (0x6049, "vl velocity deceleration")):
    record(index, name, [
        (0, "Highest sub-index supported", U8, "ro", 2),
        (1, "Delta speed", U32, "rw", 3000),
        (2, "Delta time", U16, "rw", 1),
    ])
simple(0x605A, "Quick stop option code", I16, "rw", 2)
simple(0x6060, "Modes of operation", I8, "rww", 0, pdo=1)
simple(0x6061, "Modes of operation display", I8, "ro", 0, pdo=1)
simple(0x6064, "Position actual value", I32, "ro", 0, pdo=1)
simple(0x606C, "Velocity actual value", I32, "ro", 0, pdo=1)
simple(0x606D, "Velocity window", U16, "rw", 2000)
simple(0x606E, "Velocity window time", U16, "rw", 0)
simple(0x6075, "Motor rated current", U32, "rw", 5000)  # mA
simple(0x6077, "Torque actual value", I16, "ro", 0, pdo=1)  # per mille of rated torque
simple(0x6078, "Current actual value", I16, "ro", 0, pdo=1)  # per mille of rated current
simple(0x6079, "DC link circuit voltage", U32, "ro", 24000, pdo=1)  # mV
simple(0x607F, "Max profile velocity", U32, "rw", 2000000)
simple(0x6083, "Profile acceleration", U32, "rw", 2000000, pdo=1)
simple(0x6084, "Profile deceleration", U32, "rw", 2000000, pdo=1)
simple(0x6085, "Quick stop deceleration", U32, "rw", 4000000, pdo=1)
simple(0x60F4, "Following error actual value", I32, "ro", 0, pdo=1)
simple(0x60FD, "Digital inputs", U32, "ro", 0, pdo=1)  # bit 16: digital input 1 (the e-stop)
simple(0x60FF, "Target velocity", I32, "rww", 0, pdo=1)
simple(0x6502, "Supported drive modes", U32, "ro", "0x00000106", pdo=1)

MANDATORY = [0x1000, 0x1001, 0x1018]
MANUFACTURER = [o for o in objects if 0x2000 <= o < 0x6000]
lists: list[str] = []
for title, items in (("MandatoryObjects", MANDATORY),
                     ("OptionalObjects", [o for o in objects
                                          if o not in MANDATORY and o not in MANUFACTURER]),
                     ("ManufacturerObjects", MANUFACTURER)):
    lists += [f"[{title}]", f"SupportedObjects={len(items)}"]
    lists += [f"{i}=0x{o:04X}" for i, o in enumerate(items, 1)]
    lists.append("")

sys.stdout.write("\r\n".join(out[:body_start] + lists + out[body_start:]) + "\r\n")
