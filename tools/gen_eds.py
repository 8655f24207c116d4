"""One-off generator of omnican's bundled wheel-drive EDS (output committed)."""
import sys
out = []
def sec(name, **kv):
    out.append(f"[{name}]")
    for k, v in kv.items():
        out.append(f"{k}={v}")
    out.append("")

def var(idx, name, dtype, access, default=None, pdo=0, sub=None, low=None, high=None):
    key = f"{idx:04X}" if sub is None else f"{idx:04X}sub{sub:X}"
    kv = dict(ParameterName=name, ObjectType="0x7", DataType=f"0x{dtype:04X}", AccessType=access)
    if low is not None: kv["LowLimit"] = low
    if high is not None: kv["HighLimit"] = high
    if default is not None: kv["DefaultValue"] = default
    kv["PDOMapping"] = pdo
    sec(key, **kv)

U8, U16, U32, I8, I16, I32, VSTR = 0x5, 0x6, 0x7, 0x2, 0x3, 0x4, 0x9
objs = []
def record(idx, name, subs, otype="0x9"):
    objs.append(idx)
    sec(f"{idx:04X}", SubNumber=len(subs), ParameterName=name, ObjectType=otype)
    for s in subs:
        var(idx, *s[1:], sub=s[0])

def simple(idx, *a, **k):
    objs.append(idx)
    var(idx, *a, **k)

hdr = []
sec("FileInfo", FileName="omnican_wheel.eds", FileVersion=1, FileRevision=0, EDSVersion="4.0",
    Description="omnican generic CiA 402 wheel drive (single axis; pv, csv, vl)",
    CreatedBy="omnican", CreationDate="11-23-2026", CreationTime="12:00PM")
sec("DeviceInfo", VendorName="omnican", VendorNumber="0x00000000", ProductName="omnican wheel drive",
    ProductNumber="0x00000402", RevisionNumber="0x00010000", OrderCode="omnican-wheel",
    BaudRate_10=0, BaudRate_20=0, BaudRate_50=0, BaudRate_125=1, BaudRate_250=1, BaudRate_500=1,
    BaudRate_800=0, BaudRate_1000=1, SimpleBootUpMaster=0, SimpleBootUpSlave=1, Granularity=8,
    DynamicChannelsSupported=0, GroupMessaging=0, NrOfRXPDO=4, NrOfTXPDO=4, LSS_Supported=0)
sec("DummyUsage", Dummy0001=0, Dummy0002=0, Dummy0003=0, Dummy0004=0, Dummy0005=0, Dummy0006=0, Dummy0007=0)
sec("Comments", Lines=2, Line1="Bundled with omnican; also the default drive of the simulator.",
    Line2="Position in encoder increments; velocity (60FFh, 606Ch) in increments/s; vl (6042h) in rpm.")
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
# PDO defaults = the plan omnican's host configures for this drive in pv mode:
# RPDO1 controlword (on change), RPDO2 target velocity (SYNC), TPDO1 statusword +
# mode display + error code (event, 2 ms inhibit, 100 ms event timer), TPDO2 position (SYNC).
rpdo = {0: (0x200, 255, ["0x60400010"]), 1: (0x300, 1, ["0x60FF0020"]),
        2: (0x80000400, 255, []), 3: (0x80000500, 255, [])}
tpdo = {0: (0x180, 255, ["0x60410010", "0x60610008", "0x603F0010"], 20, 100),
        1: (0x280, 1, ["0x60640020"], 0, 0),
        2: (0x80000380, 255, [], 0, 0), 3: (0x80000480, 255, [], 0, 0)}
for n, (cob, tt, maps) in rpdo.items():
    record(0x1400 + n, f"RPDO{n+1} communication parameter", [
        (0, "Highest sub-index supported", U8, "ro", 5),
        (1, f"COB-ID used by RPDO{n+1}", U32, "rw", f"$NODEID+0x{cob:08X}"),
        (2, f"Transmission type RPDO{n+1}", U8, "rw", tt),
        (3, f"Inhibit time RPDO{n+1}", U16, "rw", 0),
        (5, f"Event timer RPDO{n+1}", U16, "rw", 0),
    ])
for n, (cob, tt, maps) in rpdo.items():
    subs = [(0, f"Number of mapped objects in RPDO{n+1}", U8, "rw", len(maps))]
    for i in range(8):
        subs.append((i + 1, f"Mapped object {i+1}", U32, "rw", maps[i] if i < len(maps) else "0x00000000"))
    record(0x1600 + n, f"RPDO{n+1} mapping parameter", subs)
for n, (cob, tt, maps, inh, evt) in tpdo.items():
    record(0x1800 + n, f"TPDO{n+1} communication parameter", [
        (0, "Highest sub-index supported", U8, "ro", 5),
        (1, f"COB-ID used by TPDO{n+1}", U32, "rw", f"$NODEID+0x{cob:08X}"),
        (2, f"Transmission type TPDO{n+1}", U8, "rw", tt),
        (3, f"Inhibit time TPDO{n+1}", U16, "rw", inh),
        (5, f"Event timer TPDO{n+1}", U16, "rw", evt),
    ])
for n, (cob, tt, maps, inh, evt) in tpdo.items():
    subs = [(0, f"Number of mapped objects in TPDO{n+1}", U8, "rw", len(maps))]
    for i in range(8):
        subs.append((i + 1, f"Mapped object {i+1}", U32, "rw", maps[i] if i < len(maps) else "0x00000000"))
    record(0x1A00 + n, f"TPDO{n+1} mapping parameter", subs)

simple(0x6007, "Abort connection option code", I16, "rw", 3)
simple(0x603F, "Error code", U16, "ro", 0, pdo=1)
simple(0x6040, "Controlword", U16, "rww", 0, pdo=1)
simple(0x6041, "Statusword", U16, "ro", 0, pdo=1)

simple(0x6042, "vl target velocity", I16, "rww", 0, pdo=1)
simple(0x6043, "vl velocity demand", I16, "ro", 0, pdo=1)
simple(0x6044, "vl velocity actual value", I16, "ro", 0, pdo=1)
record(0x6048, "vl velocity acceleration", [
    (0, "Highest sub-index supported", U8, "ro", 2),
    (1, "Delta speed", U32, "rw", 3000),
    (2, "Delta time", U16, "rw", 1),
])
record(0x6049, "vl velocity deceleration", [
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
simple(0x607F, "Max profile velocity", U32, "rw", 2000000)
simple(0x6083, "Profile acceleration", U32, "rw", 2000000, pdo=1)
simple(0x6084, "Profile deceleration", U32, "rw", 2000000, pdo=1)
simple(0x6085, "Quick stop deceleration", U32, "rw", 4000000, pdo=1)
simple(0x60FF, "Target velocity", I32, "rww", 0, pdo=1)
simple(0x6502, "Supported drive modes", U32, "ro", "0x00000106", pdo=1)

objs = [o for o in objs if o is not None]
mand = [0x1000, 0x1001, 0x1018]
opt = [o for o in objs if o < 0x2000 and o not in mand]
prof = [o for o in objs if o >= 0x6000]
lists = []
def objlist(name, items):
    lists.append(f"[{name}]")
    lists.append(f"SupportedObjects={len(items)}")
    for i, o in enumerate(items, 1):
        lists.append(f"{i}=0x{o:04X}")
    lists.append("")
objlist("MandatoryObjects", mand)
objlist("OptionalObjects", opt + prof)
objlist("ManufacturerObjects", [])
text = out[:body_start] + lists + out[body_start:]
sys.stdout.write("\r\n".join(text) + "\r\n")
