"""The CiA 402 power stage of a simulated drive: one device state machine.

What a drive does with a controlword, an internal fault, a quick stop and a lost
master (6007h), and the statusword bits that show its state. The transitions are the
tables of :mod:`omnican.protocol.cia402`; this module adds what a device adds to them: the
fault reset on the rising edge of bit 7, a fault whose cause persists, a power stage
that cannot enable, and the quick stop option code (605Ah) that decides whether
QUICK STOP ACTIVE ends by itself.

Pure: no I/O, no clock, no object dictionary. Each event returns a
:class:`Reaction` that tells the caller what to do about it (EMCY frames, the
motors); the mode-specific statusword bits (10-13) are the axes' business
(:mod:`omnican.sim.axis`).
"""

from __future__ import annotations

import enum
from collections.abc import Callable
from dataclasses import dataclass

from omnican.protocol import cia402
from omnican.protocol.cia301 import EMCY_HEARTBEAT
from omnican.protocol.cia402 import Command, State

#: 605Ah when the drive has none: slow down on the quick stop ramp, then disable.
DEFAULT_QUICK_STOP_OPTION = 2
#: 605Ah codes that stay in QUICK STOP ACTIVE once stopped (left by transition 12 or 16).
STAY_IN_QUICK_STOP = frozenset({5, 6, 7, 8})

# By the member's id: State is an Enum, whose hash is a Python call (members are
# singletons), and the statusword is read with every event check.
_STATE_BITS: dict[int, int] = {id(s): cia402.state_bits(s) for s in State if s is not State.UNKNOWN}
_POWERED = (State.OPERATION_ENABLED, State.QUICK_STOP_ACTIVE)
_FAULTED = (State.FAULT, State.FAULT_REACTION_ACTIVE)
_SETTLING = (State.FAULT_REACTION_ACTIVE, State.QUICK_STOP_ACTIVE)


class Reaction(enum.Enum):
    """What an event of the power stage asks of the rest of the drive."""

    NONE = "nothing changed"
    STATE = "a new state: the motors follow it"
    ENABLED = "operation enabled: the motors start from where they are"
    FAULT = "a fault tripped: EMCY with the fault code"
    RESET = "the fault was reset: EMCY error reset"


def _default_quick_stop_option() -> int:
    return DEFAULT_QUICK_STOP_OPTION


@dataclass(eq=False)
class PowerStage:
    """A CiA 402 device state machine (one per controlword).

    ``quick_stop_option`` reads 605Ah; it is called only when a transition depends on
    it (16, and the end of a quick stop), as a drive consults the object then."""

    quick_stop_option: Callable[[], int] = _default_quick_stop_option
    state: State = State.SWITCH_ON_DISABLED
    controlword: int = 0  # the last word written
    warning: bool = False  # statusword bit 7 (the master's heartbeat was lost)
    fault_code: int = 0  # 603Fh: the code of the fault that tripped, 0 when none
    fault_persists: bool = False  # its cause is still there: a fault reset does not clear it
    enable_held: bool = False  # no power for the motor (DC link off)
    torque_off: bool = False  # safe torque off (an e-stop): no torque, no enabling
    #: acts on a controlword only as one arrives (ros2_canopen's fake CiA 402 slave): in
    #: OPERATION ENABLED its motors start at a controlword that arrives there, not at the
    #: one that enabled it (a master that writes it only on change never moves them)
    on_arrival: bool = False
    running: bool = True  # in OPERATION ENABLED, the motors follow the targets
    #: (state, enable held, torque off, running) when the controlword now held was written
    #: and changed nothing: written again in them, it changes nothing either (:meth:`idle`)
    _idle: tuple[State, bool, bool, bool] | None = None

    @property
    def halted(self) -> bool:
        """Controlword bit 8: the axes stop on their ramp (profile modes)."""
        return bool(self.controlword & cia402.CW_HALT)

    @property
    def powered(self) -> bool:
        """The motors are under control (OPERATION ENABLED, QUICK STOP ACTIVE)."""
        return self.state in _POWERED

    @property
    def settling(self) -> bool:
        """In a state that ends once the motors stand still (see :meth:`settle`)."""
        return self.state in _SETTLING

    def statusword(self) -> int:
        """The bits of 6041h the device control function owns: the state (0-6),
        warning (7) and remote (9, always: the drive takes commands over CANopen)."""
        sw = _STATE_BITS[id(self.state)] | cia402.SW_REMOTE
        if self.warning:
            sw |= cia402.SW_WARNING
        return sw

    def idle(self, value: int) -> bool:
        """Writing ``value`` would change nothing: it is the controlword held, which changed
        nothing when it was written, and nothing that decides a transition changed since
        (a master that writes the controlword every cycle, in a steady state)."""
        idle = self._idle
        return (idle is not None and value == self.controlword and
                idle == (self.state, self.enable_held, self.torque_off, self.running))

    def write_controlword(self, value: int) -> Reaction:
        """A controlword (6040h) written. FAULT is left only by a rising edge of bit 7
        when the cause is gone; FAULT REACTION ACTIVE ignores every command."""
        reaction = self._write_controlword(value)
        state = self.state
        # QUICK STOP ACTIVE's way out reads 605Ah, which may change: never taken as idle.
        self._idle = ((state, self.enable_held, self.torque_off, self.running)
                      if reaction is Reaction.NONE and state is not State.QUICK_STOP_ACTIVE
                      else None)
        return reaction

    def _write_controlword(self, value: int) -> Reaction:
        previous, self.controlword = self.controlword, value & 0xFFFF
        if self.state is State.FAULT:
            rising = value & cia402.CW_FAULT_RESET and not previous & cia402.CW_FAULT_RESET
            if rising and not self.fault_persists:
                self.fault_code = 0
                self.state = State.SWITCH_ON_DISABLED
                return Reaction.RESET
            return Reaction.NONE
        if self.state is State.FAULT_REACTION_ACTIVE:
            return Reaction.NONE
        command = cia402.decode_command(value)
        if command is None:
            return Reaction.NONE
        transition = cia402.DEVICE_TRANSITIONS.get((self.state, command))
        if transition is None:
            if (not self.running and command is Command.ENABLE_OPERATION
                    and self.state is State.OPERATION_ENABLED):
                self.running = True  # the enable command again, in OPERATION ENABLED
                return Reaction.STATE
            return Reaction.NONE
        if transition.number == 16 and self.quick_stop_option() not in STAY_IN_QUICK_STOP:
            return Reaction.NONE  # QUICK STOP ACTIVE is not a state this drive stays in
        if transition.target is State.OPERATION_ENABLED:
            if self.enable_held or self.torque_off:
                return Reaction.NONE
            self.state = State.OPERATION_ENABLED
            self.running = not self.on_arrival
            return Reaction.ENABLED
        self.state = transition.target
        return Reaction.STATE

    def trip(self, code: int) -> Reaction:
        """An internal fault with EMCY error ``code`` (transition 13 or 14): a powered
        stage first stops the motors (FAULT REACTION ACTIVE), an unpowered one is in
        FAULT at once. A stage already in fault keeps its first code."""
        if self.state in _FAULTED:
            return Reaction.NONE
        self.fault_code = code
        self.state = State.FAULT_REACTION_ACTIVE if self.powered else State.FAULT
        return Reaction.FAULT

    def abort_connection(self, option: int) -> Reaction:
        """The master is gone (its heartbeat lost, an NMT stop): react per 6007h. An
        unpowered stage has nothing to stop; with "no action" it only warns."""
        if not self.powered:
            if option == cia402.ABORT_NO_ACTION:
                self.warning = True
            return Reaction.NONE
        if option == cia402.ABORT_FAULT:
            return self.trip(EMCY_HEARTBEAT)
        if option == cia402.ABORT_DISABLE_VOLTAGE:
            self.state = State.SWITCH_ON_DISABLED
            return Reaction.STATE
        if option == cia402.ABORT_NO_ACTION:
            self.warning = True
            return Reaction.NONE
        if self.state is State.OPERATION_ENABLED:  # quick stop, and any other code
            self.state = State.QUICK_STOP_ACTIVE
            return Reaction.STATE
        return Reaction.NONE

    def safe_torque_off(self, active: bool) -> Reaction:
        """Safe torque off engaged (an e-stop pressed) or released: engaged, a powered
        stage loses its torque at once (SWITCH ON DISABLED) and none can be enabled."""
        self.torque_off = active
        if active and self.powered:
            self.state = State.SWITCH_ON_DISABLED
            return Reaction.STATE
        return Reaction.NONE

    def connection_restored(self) -> None:
        """The master's heartbeat is back: the warning goes."""
        self.warning = False

    def settle(self) -> Reaction:
        """The motors stand still: a fault reaction ends in FAULT (transition 14), a
        quick stop in SWITCH ON DISABLED (12) unless 605Ah says stay."""
        if self.state is State.FAULT_REACTION_ACTIVE:
            self.state = State.FAULT
            return Reaction.STATE
        if self.state is State.QUICK_STOP_ACTIVE and (
            self.quick_stop_option() not in STAY_IN_QUICK_STOP
        ):
            self.state = State.SWITCH_ON_DISABLED
            return Reaction.STATE
        return Reaction.NONE

    def power_up(self) -> None:
        """Back to the power-on state (a reboot); what holds the power stage off stays."""
        self.state, self.controlword, self.warning = State.SWITCH_ON_DISABLED, 0, False
        self._idle = None
        self.fault_code, self.fault_persists = 0, False
