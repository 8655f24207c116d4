"""CiA 301 numbers: NMT, the predefined connection set's COB-IDs, SDO abort codes,
communication objects and PDO parameters.

The one home of these numbers for the host (``drive.py``, ``bus.py``, ``chassis.py``),
the simulator (``sim/``), the offline tools (``replay.py``, ``dbcgen.py``, ``pdoplan.py``)
and the front ends (``scan``, ``traffic``). CiA 402 (the drive profile) lives in
:mod:`omnican.protocol.cia402`.

Pure module: no I/O, no CAN imports.
"""

from __future__ import annotations

import enum

# ---------------------------------------------------------------- NMT


class NmtCommand(enum.IntEnum):
    """NMT node control command specifiers (first byte of a frame on COB-ID 0)."""

    START = 0x01
    STOP = 0x02
    ENTER_PRE_OPERATIONAL = 0x80
    RESET_NODE = 0x81
    RESET_COMMUNICATION = 0x82


class NmtState(enum.IntEnum):
    """NMT states as a node reports them in its heartbeat (bits 0-6)."""

    BOOT_UP = 0x00  # the boot-up message; the node is initialising
    STOPPED = 0x04
    OPERATIONAL = 0x05
    PRE_OPERATIONAL = 0x7F


#: NMT command names, as a DBC value table shows them.
NMT_COMMAND_NAMES: dict[int, str] = {
    NmtCommand.START: "start",
    NmtCommand.STOP: "stop",
    NmtCommand.ENTER_PRE_OPERATIONAL: "enter pre-operational",
    NmtCommand.RESET_NODE: "reset node",
    NmtCommand.RESET_COMMUNICATION: "reset communication",
}

#: NMT state names, as tables and logs show them.
NMT_STATE_NAMES: dict[int, str] = {
    NmtState.BOOT_UP: "BOOT-UP",
    NmtState.STOPPED: "STOPPED",
    NmtState.OPERATIONAL: "OPERATIONAL",
    NmtState.PRE_OPERATIONAL: "PRE-OPERATIONAL",
}

#: The commands after which a node sends a fresh boot-up message.
NMT_RESETS = (NmtCommand.RESET_NODE, NmtCommand.RESET_COMMUNICATION)

#: Bit 7 of a heartbeat/node-guarding byte is node guarding's toggle bit, not state.
NMT_STATE_MASK = 0x7F


def nmt_state_name(value: int) -> str:
    """``OPERATIONAL`` for 5; the number itself for states CiA 301 does not define."""
    state = value & NMT_STATE_MASK
    return NMT_STATE_NAMES.get(state, str(state))


# ---------------------------------------------------------------- COB-IDs

NMT_COB_ID = 0x000
SYNC_COB_ID = 0x080
EMCY_BASE = 0x080  # + node id
TIME_COB_ID = 0x100
TPDO1_BASE, RPDO1_BASE = 0x180, 0x200  # + node id
PDO_NUMBER_STEP = 0x100  # PDO n (1-4) is PDO1's COB-ID + 0x100 * (n - 1)
SDO_TX_BASE = 0x580  # server -> client (responses), + node id
SDO_RX_BASE = 0x600  # client -> server (requests), + node id
HEARTBEAT_BASE = 0x700  # + node id; also node guarding and boot-up

COB_ID_MASK = 0x7FF  # an 11-bit CAN identifier
COB_ID_INVALID = 1 << 31  # bit 31 of a PDO/EMCY COB-ID entry: the object is disabled
MAX_NODE_ID = 127

# Function codes of the predefined connection set: (base, name); a node's frame is
# base + node id (1-127).
FUNCTION_CODES: tuple[tuple[int, str], ...] = (
    (EMCY_BASE, "EMCY"),
    (0x180, "TPDO1"), (0x200, "RPDO1"), (0x280, "TPDO2"), (0x300, "RPDO2"),
    (0x380, "TPDO3"), (0x400, "RPDO3"), (0x480, "TPDO4"), (0x500, "RPDO4"),
    (SDO_TX_BASE, "SDO response"), (SDO_RX_BASE, "SDO request"), (HEARTBEAT_BASE, "heartbeat"),
)


def heartbeat_cob_id(node_id: int) -> int:
    return HEARTBEAT_BASE + node_id


def emcy_cob_id(node_id: int) -> int:
    return EMCY_BASE + node_id


def canopen_name(can_id: int, extended: bool = False) -> str:
    """What a standard frame is in CANopen's predefined connection set, e.g.
    ``SDO request node 1`` for 0x601; empty for other ids (and every extended id)."""
    if extended:
        return ""
    if can_id == NMT_COB_ID:
        return "NMT"
    if can_id == SYNC_COB_ID:
        return "SYNC"
    if can_id == TIME_COB_ID:
        return "TIME"
    for base, name in FUNCTION_CODES:
        if base < can_id <= base + MAX_NODE_ID:
            return f"{name} node {can_id - base}"
    return ""


# ---------------------------------------------------------------- objects

COMMUNICATION_PROFILE = range(0x1000, 0x2000)  # the objects NMT reset communication resets
DEVICE_TYPE = 0x1000
ERROR_REGISTER = 0x1001
DEVICE_NAME = 0x1008
SYNC_COB_ID_OBJECT = 0x1005
EMCY_COB_ID_OBJECT = 0x1014
CONSUMER_HEARTBEAT_TIME = 0x1016  # sub n: (producer node id << 16) | timeout ms
PRODUCER_HEARTBEAT_TIME = 0x1017  # ms, 0 = no heartbeat
IDENTITY = 0x1018  # sub 1 vendor, 2 product, 3 revision, 4 serial
STORE_PARAMETERS = 0x1010  # sub 1 all, 2 communication, 3 application, 4 manufacturer
RESTORE_DEFAULTS = 0x1011  # the same sub-indices
SAVE_SIGNATURE = 0x65766173  # "save" (little-endian): written to 1010h sub n, stores
LOAD_SIGNATURE = 0x64616F6C  # "load" (little-endian): written to 1011h sub n, restores defaults

# Error register (1001h) bits.
ERROR_REGISTER_GENERIC = 0x01
ERROR_REGISTER_CURRENT = 0x02
ERROR_REGISTER_VOLTAGE = 0x04
ERROR_REGISTER_TEMPERATURE = 0x08
ERROR_REGISTER_COMMUNICATION = 0x10

# Emergency error codes of the communication profile (the drive profile's are in cia402).
EMCY_NO_ERROR = 0x0000
EMCY_HEARTBEAT = 0x8130  # life guard or heartbeat error
EMCY_PDO_LENGTH = 0x8210  # PDO not processed due to length error

# ---------------------------------------------------------------- PDOs

RPDO_COMM, RPDO_MAP, TPDO_COMM, TPDO_MAP = 0x1400, 0x1600, 0x1800, 0x1A00
MAX_PDOS = 512  # per direction: 1400h-15FFh, 1800h-19FFh

# Communication parameter sub-indices.
PDO_COB_ID, PDO_TRANSMISSION_TYPE, PDO_INHIBIT_TIME, PDO_EVENT_TIMER = 1, 2, 3, 5

# Transmission types.
TRANS_SYNC_ACYCLIC = 0  # on SYNC, when the data changed
TRANS_SYNC = 1  # every SYNC (n: every n-th SYNC, up to 240)
TRANS_SYNC_MAX = 240
TRANS_EVENT_MANUFACTURER = 254
TRANS_EVENT = 255  # event-driven (device profile)

# ---------------------------------------------------------------- SDO aborts

SDO_ABORT_TOGGLE = 0x05030000
SDO_ABORT_TIMEOUT = 0x05040000
SDO_ABORT_COMMAND = 0x05040001
SDO_ABORT_BLOCK_SIZE = 0x05040002
SDO_ABORT_SEQUENCE = 0x05040003
SDO_ABORT_CRC = 0x05040004
SDO_ABORT_OUT_OF_MEMORY = 0x05040005
SDO_ABORT_UNSUPPORTED_ACCESS = 0x06010000
SDO_ABORT_WRITE_ONLY = 0x06010001
SDO_ABORT_READ_ONLY = 0x06010002
SDO_ABORT_NOT_IN_OD = 0x06020000
SDO_ABORT_NOT_MAPPABLE = 0x06040041
SDO_ABORT_PDO_LENGTH = 0x06040042
SDO_ABORT_GENERAL_INCOMPATIBLE = 0x06040043
SDO_ABORT_INTERNAL_INCOMPATIBLE = 0x06040047
SDO_ABORT_HARDWARE = 0x06060000
SDO_ABORT_LENGTH = 0x06070010
SDO_ABORT_TOO_LONG = 0x06070012
SDO_ABORT_TOO_SHORT = 0x06070013
SDO_ABORT_SUBINDEX = 0x06090011
SDO_ABORT_VALUE_RANGE = 0x06090030
SDO_ABORT_VALUE_TOO_HIGH = 0x06090031
SDO_ABORT_VALUE_TOO_LOW = 0x06090032
SDO_ABORT_GENERAL = 0x08000000
SDO_ABORT_CANNOT_STORE = 0x08000020
SDO_ABORT_LOCAL_CONTROL = 0x08000021
SDO_ABORT_DEVICE_STATE = 0x08000022

SDO_ABORT_TEXT: dict[int, str] = {
    SDO_ABORT_TOGGLE: "toggle bit not alternated",
    SDO_ABORT_TIMEOUT: "SDO protocol timed out",
    SDO_ABORT_COMMAND: "command specifier not valid",
    SDO_ABORT_BLOCK_SIZE: "invalid block size",
    SDO_ABORT_SEQUENCE: "invalid sequence number",
    SDO_ABORT_CRC: "CRC error",
    SDO_ABORT_OUT_OF_MEMORY: "out of memory",
    SDO_ABORT_UNSUPPORTED_ACCESS: "unsupported access to an object",
    SDO_ABORT_WRITE_ONLY: "attempt to read a write-only object",
    SDO_ABORT_READ_ONLY: "attempt to write a read-only object",
    SDO_ABORT_NOT_IN_OD: "object does not exist in the object dictionary",
    SDO_ABORT_NOT_MAPPABLE: "object cannot be mapped to the PDO",
    SDO_ABORT_PDO_LENGTH: "the number and length of the objects to be mapped would exceed PDO "
                          "length",
    SDO_ABORT_GENERAL_INCOMPATIBLE: "general parameter incompatibility",
    SDO_ABORT_INTERNAL_INCOMPATIBLE: "general internal incompatibility in the device",
    SDO_ABORT_HARDWARE: "access failed due to a hardware error",
    SDO_ABORT_LENGTH: "data type does not match, length of service parameter does not match",
    SDO_ABORT_TOO_LONG: "data type does not match, length of service parameter too high",
    SDO_ABORT_TOO_SHORT: "data type does not match, length of service parameter too low",
    SDO_ABORT_SUBINDEX: "sub-index does not exist",
    SDO_ABORT_VALUE_RANGE: "invalid value for parameter",
    SDO_ABORT_VALUE_TOO_HIGH: "value of parameter written too high",
    SDO_ABORT_VALUE_TOO_LOW: "value of parameter written too low",
    SDO_ABORT_GENERAL: "general error",
    SDO_ABORT_CANNOT_STORE: "data cannot be transferred or stored to the application",
    SDO_ABORT_LOCAL_CONTROL: "data cannot be transferred because of local control",
    SDO_ABORT_DEVICE_STATE: "data cannot be transferred because of the present device state",
}


def abort_text(code: int) -> str:
    """``0x06020000 object does not exist in the object dictionary``."""
    return f"0x{code:08X} {SDO_ABORT_TEXT.get(code, 'unknown abort code')}"
