"""CiA 402 tables: controlword commands, statusword states, transitions, modes.

Used by both sides of the wire: the host (``drive.py``: which command moves a drive
towards a wanted state) and the simulator (``sim/``: what a drive does with a
command). Tables, not branches, after canopen's ``profiles/p402.py``; states are an
enum, not strings. Commands only touch the bits they define, so the halt bit (8)
and the mode-specific bits (4-6, 9) survive every state change.

Pure module: no I/O, no CAN imports.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass


class State(enum.Enum):
    """Power drive system states, plus UNKNOWN for "no statusword seen yet"."""

    UNKNOWN = "NO DATA"
    NOT_READY_TO_SWITCH_ON = "NOT READY TO SWITCH ON"
    SWITCH_ON_DISABLED = "SWITCH ON DISABLED"
    READY_TO_SWITCH_ON = "READY TO SWITCH ON"
    SWITCHED_ON = "SWITCHED ON"
    OPERATION_ENABLED = "OPERATION ENABLED"
    QUICK_STOP_ACTIVE = "QUICK STOP ACTIVE"
    FAULT_REACTION_ACTIVE = "FAULT REACTION ACTIVE"
    FAULT = "FAULT"

    def __str__(self) -> str:
        return self.value


# Statusword bits (CiA 402 6041h).
SW_READY_TO_SWITCH_ON = 1 << 0
SW_SWITCHED_ON = 1 << 1
SW_OPERATION_ENABLED = 1 << 2
SW_FAULT = 1 << 3
SW_VOLTAGE_ENABLED = 1 << 4
SW_QUICK_STOP = 1 << 5  # 0 = quick stop active
SW_SWITCH_ON_DISABLED = 1 << 6
SW_WARNING = 1 << 7
SW_REMOTE = 1 << 9
SW_TARGET_REACHED = 1 << 10
SW_INTERNAL_LIMIT = 1 << 11
SW_OMS_12 = 1 << 12  # pv: speed is zero
SW_OMS_13 = 1 << 13  # pv: max slippage error

# (mask, value) of the state bits; first match wins (canopen p402 SW_MASK).
STATE_BITS: dict[State, tuple[int, int]] = {
    State.NOT_READY_TO_SWITCH_ON: (0x4F, 0x00),
    State.SWITCH_ON_DISABLED: (0x4F, 0x40),
    State.READY_TO_SWITCH_ON: (0x6F, 0x21),
    State.SWITCHED_ON: (0x6F, 0x23),
    State.OPERATION_ENABLED: (0x6F, 0x27),
    State.QUICK_STOP_ACTIVE: (0x6F, 0x07),
    State.FAULT_REACTION_ACTIVE: (0x4F, 0x0F),
    State.FAULT: (0x4F, 0x08),
}


#: (mask, value) of OPERATION ENABLED, for the control loop's one-comparison test: no
#: earlier entry of STATE_BITS matches a statusword that this one matches.
ENABLED_MASK, ENABLED_BITS = STATE_BITS[State.OPERATION_ENABLED]


def is_operation_enabled(statusword: int | None) -> bool:
    """``decode_state(statusword) is State.OPERATION_ENABLED``, in one comparison."""
    return statusword is not None and statusword & ENABLED_MASK == ENABLED_BITS


def decode_state(statusword: int | None) -> State:
    """State from a statusword; None (nothing received yet) -> UNKNOWN."""
    if statusword is None:
        return State.UNKNOWN
    for state, (mask, value) in STATE_BITS.items():
        if statusword & mask == value:
            return state
    return State.UNKNOWN


def state_bits(state: State) -> int:
    """The statusword state bits (0-3, 5, 6) a drive shows in ``state``; bit 4
    (voltage enabled) is set in the states where the power stage is on."""
    if state is State.UNKNOWN:
        raise ValueError("UNKNOWN is not a drive state")
    bits = STATE_BITS[state][1]
    if state in (State.READY_TO_SWITCH_ON, State.SWITCHED_ON, State.OPERATION_ENABLED):
        bits |= SW_QUICK_STOP | SW_VOLTAGE_ENABLED
    elif state in (State.QUICK_STOP_ACTIVE, State.FAULT_REACTION_ACTIVE):
        bits |= SW_VOLTAGE_ENABLED
    return bits


# Controlword bits (CiA 402 6040h).
CW_SWITCH_ON = 1 << 0
CW_ENABLE_VOLTAGE = 1 << 1
CW_QUICK_STOP = 1 << 2  # 0 = quick stop
CW_ENABLE_OPERATION = 1 << 3
CW_FAULT_RESET = 1 << 7
CW_HALT = 1 << 8


class Command(enum.Enum):
    """Device control commands, as (mask, value) over controlword bits 0-3 and 7."""

    SHUTDOWN = (0x87, 0x06)
    SWITCH_ON = (0x8F, 0x07)
    DISABLE_VOLTAGE = (0x82, 0x00)
    QUICK_STOP = (0x86, 0x02)
    DISABLE_OPERATION = (0x8F, 0x07)
    ENABLE_OPERATION = (0x8F, 0x0F)
    # A fault reset is the rising edge of bit 7; the other bits are left as they are.
    FAULT_RESET = (0x80, 0x80)

    @property
    def mask(self) -> int:
        return self.value[0]

    @property
    def bits(self) -> int:
        return self.value[1]


# DISABLE_OPERATION has the same bits as SWITCH_ON, so the enum makes it an alias of
# SWITCH_ON: a device cannot tell them apart either (the state decides the transition).


def apply_command(controlword: int, command: Command) -> int:
    """``controlword`` with ``command``'s bits written and every other bit kept."""
    return (controlword & ~command.mask & 0xFFFF) | command.bits


def decode_command(controlword: int) -> Command | None:
    """Which command a controlword carries (device side, CiA 402 table 48).

    Fault reset is edge-triggered and detected by the caller from the previous word;
    with bit 7 set, the other bits are ignored here and None is returned."""
    if controlword & CW_FAULT_RESET:
        return None
    if not controlword & CW_ENABLE_VOLTAGE:
        return Command.DISABLE_VOLTAGE
    if not controlword & CW_QUICK_STOP:
        return Command.QUICK_STOP
    if not controlword & CW_SWITCH_ON:
        return Command.SHUTDOWN
    if controlword & CW_ENABLE_OPERATION:
        return Command.ENABLE_OPERATION
    return Command.SWITCH_ON  # == DISABLE_OPERATION


@dataclass(frozen=True)
class Transition:
    number: int
    source: State
    command: Command
    target: State


# Device transitions triggered by a command (CiA 402 figure 7). Transitions 0, 1, 13
# and 14 are internal (power-up, fault); transition 15 is the fault-reset edge.
TRANSITIONS: tuple[Transition, ...] = (
    Transition(2, State.SWITCH_ON_DISABLED, Command.SHUTDOWN, State.READY_TO_SWITCH_ON),
    Transition(3, State.READY_TO_SWITCH_ON, Command.SWITCH_ON, State.SWITCHED_ON),
    # "Switch on + enable operation" from READY TO SWITCH ON (3 then 4 at once).
    Transition(3, State.READY_TO_SWITCH_ON, Command.ENABLE_OPERATION, State.OPERATION_ENABLED),
    Transition(4, State.SWITCHED_ON, Command.ENABLE_OPERATION, State.OPERATION_ENABLED),
    Transition(5, State.OPERATION_ENABLED, Command.SWITCH_ON, State.SWITCHED_ON),
    Transition(6, State.SWITCHED_ON, Command.SHUTDOWN, State.READY_TO_SWITCH_ON),
    Transition(7, State.READY_TO_SWITCH_ON, Command.DISABLE_VOLTAGE, State.SWITCH_ON_DISABLED),
    Transition(7, State.READY_TO_SWITCH_ON, Command.QUICK_STOP, State.SWITCH_ON_DISABLED),
    Transition(8, State.OPERATION_ENABLED, Command.SHUTDOWN, State.READY_TO_SWITCH_ON),
    Transition(9, State.OPERATION_ENABLED, Command.DISABLE_VOLTAGE, State.SWITCH_ON_DISABLED),
    Transition(10, State.SWITCHED_ON, Command.DISABLE_VOLTAGE, State.SWITCH_ON_DISABLED),
    Transition(10, State.SWITCHED_ON, Command.QUICK_STOP, State.SWITCH_ON_DISABLED),
    Transition(11, State.OPERATION_ENABLED, Command.QUICK_STOP, State.QUICK_STOP_ACTIVE),
    Transition(12, State.QUICK_STOP_ACTIVE, Command.DISABLE_VOLTAGE, State.SWITCH_ON_DISABLED),
    Transition(16, State.QUICK_STOP_ACTIVE, Command.ENABLE_OPERATION, State.OPERATION_ENABLED),
)

DEVICE_TRANSITIONS: dict[tuple[State, Command], Transition] = {
    (t.source, t.command): t for t in TRANSITIONS
}


# Host side: the command that takes a drive one step from a state towards a goal.
_TOWARDS_ENABLED: dict[State, Command] = {
    State.SWITCH_ON_DISABLED: Command.SHUTDOWN,
    State.READY_TO_SWITCH_ON: Command.SWITCH_ON,
    State.SWITCHED_ON: Command.ENABLE_OPERATION,
    State.OPERATION_ENABLED: Command.ENABLE_OPERATION,
    # Out of quick stop through SWITCH ON DISABLED: works whatever 605Ah says.
    State.QUICK_STOP_ACTIVE: Command.DISABLE_VOLTAGE,
    State.NOT_READY_TO_SWITCH_ON: Command.DISABLE_VOLTAGE,
}

_TOWARDS_DISABLED: dict[State, Command] = {
    State.OPERATION_ENABLED: Command.DISABLE_VOLTAGE,
    State.SWITCHED_ON: Command.DISABLE_VOLTAGE,
    State.READY_TO_SWITCH_ON: Command.DISABLE_VOLTAGE,
    State.QUICK_STOP_ACTIVE: Command.DISABLE_VOLTAGE,
    State.SWITCH_ON_DISABLED: Command.DISABLE_VOLTAGE,
    State.NOT_READY_TO_SWITCH_ON: Command.DISABLE_VOLTAGE,
}


def command_towards(state: State, goal: State) -> Command | None:
    """The next command to send to move from ``state`` towards ``goal``
    (OPERATION_ENABLED or SWITCH_ON_DISABLED). FAULT needs a fault reset (edge on
    bit 7, see :func:`fault_reset_sequence`): returns ``Command.FAULT_RESET``.
    Returns None for states the host must wait out (FAULT REACTION ACTIVE, UNKNOWN)."""
    if state is State.FAULT:
        return Command.FAULT_RESET
    if goal is State.OPERATION_ENABLED:
        return _TOWARDS_ENABLED.get(state)
    if goal is State.SWITCH_ON_DISABLED:
        return _TOWARDS_DISABLED.get(state)
    raise ValueError(f"goal must be OPERATION ENABLED or SWITCH ON DISABLED, not {goal}")


def fault_reset_sequence(controlword: int) -> tuple[int, int]:
    """Two controlwords that make a clean rising edge on bit 7 from ``controlword``:
    bit 7 low (with the state bits cleared so the drive stays put), then high."""
    low = apply_command(controlword, Command.DISABLE_VOLTAGE) & ~CW_FAULT_RESET
    return low, low | CW_FAULT_RESET


class Mode(enum.IntEnum):
    """Modes of operation (6060h) that omnican drives a wheel in."""

    VELOCITY = 2  # vl: 6042h target (INTEGER16), 6044h actual
    PROFILE_VELOCITY = 3  # pv: 60FFh target, 606Ch actual, ramps 6083h/6084h
    CYCLIC_SYNC_VELOCITY = 9  # csv: 60FFh target, no ramp in the drive

    @property
    def short(self) -> str:
        return {2: "vl", 3: "pv", 9: "csv"}[int(self)]

    @classmethod
    def from_name(cls, name: str | int) -> Mode:
        if isinstance(name, int) and not isinstance(name, bool):
            return cls(name)
        table = {"vl": cls.VELOCITY, "pv": cls.PROFILE_VELOCITY, "csv": cls.CYCLIC_SYNC_VELOCITY}
        try:
            return table[str(name).lower()]
        except KeyError:
            raise ValueError(f"unknown mode {name!r}; use one of pv, csv, vl") from None


MODE_NAMES: dict[int, str] = {
    -1: "manufacturer",
    0: "no mode",
    1: "profile position",
    2: "velocity",
    3: "profile velocity",
    4: "profile torque",
    6: "homing",
    7: "interpolated position",
    8: "cyclic sync position",
    9: "cyclic sync velocity",
    10: "cyclic sync torque",
}


def supported_modes(bits_6502: int) -> frozenset[int]:
    """Mode numbers from the supported-drive-modes bit field (6502h: bit n-1 = mode n)."""
    return frozenset(bit + 1 for bit in range(16) if bits_6502 & (1 << bit))


def modes_to_bits(modes: frozenset[int] | set[int]) -> int:
    return sum(1 << (m - 1) for m in modes if 1 <= m <= 16)


# Emergency error codes (CiA 301 / CiA 402): exact codes first, then classes.
EMCY_CODES: dict[int, str] = {
    0x0000: "error reset / no error",
    0x1000: "generic error",
    0x2310: "continuous over-current",
    0x2320: "short circuit at outputs",
    0x3110: "mains over-voltage",
    0x3120: "mains under-voltage",
    0x3210: "DC link over-voltage",
    0x3220: "DC link under-voltage",
    0x4210: "excess temperature device",
    0x4310: "excess temperature drive",
    0x5112: "supply voltage low",
    0x5530: "EEPROM / data storage error",
    0x6010: "software reset (watchdog)",
    0x7121: "motor blocked",
    0x7305: "incremental sensor 1 fault",
    0x8110: "CAN overrun (objects lost)",
    0x8120: "CAN in error passive mode",
    0x8130: "life guard error or heartbeat error",
    0x8140: "recovered from bus off",
    0x8210: "PDO not processed due to length error",
    0x8400: "velocity speed controller error",
    0x8611: "following error",
    0xFF00: "device specific",
}

EMCY_CLASSES: tuple[tuple[int, int, str], ...] = (
    (0xFF00, 0x1000, "generic error"),
    (0xF000, 0x2000, "current"),
    (0xF000, 0x3000, "voltage"),
    (0xF000, 0x4000, "temperature"),
    (0xFF00, 0x5000, "device hardware"),
    (0xF000, 0x6000, "device software"),
    (0xFF00, 0x7000, "additional modules"),
    (0xF000, 0x8000, "monitoring"),
    (0xFF00, 0x9000, "external error"),
    (0xFF00, 0xF000, "additional functions"),
    (0xFF00, 0xFF00, "device specific"),
)


def describe_emcy(code: int) -> str:
    """Human text for an EMCY error code, e.g. ``0x2310 continuous over-current``."""
    text = EMCY_CODES.get(code)
    if text is None:
        text = next(
            (name for mask, value, name in EMCY_CLASSES if code & mask == value), "unknown"
        )
    return f"0x{code:04X} {text}"


# 6007h abort connection option codes (what a drive does when the host's heartbeat stops).
ABORT_NO_ACTION = 0
ABORT_FAULT = 1
ABORT_DISABLE_VOLTAGE = 2
ABORT_QUICK_STOP = 3
