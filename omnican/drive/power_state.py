"""The CiA 402 power state machine, from the host's side: walking one (one controlword)
towards a goal, with controlword bit masks: the bits it does not own (halt, mode bits)
are kept, a fault reset is a clean rising edge of bit 7, a transition that does not
happen in time is named. No I/O: :meth:`StageDriver.step` says which controlword to
send."""

from __future__ import annotations

import logging
from dataclasses import dataclass

from omnican.protocol import cia402
from omnican.protocol.cia402 import Command, State
from omnican.protocol.object_map import Entry

logger = logging.getLogger("omnican.drive")

_UNKNOWN = State.UNKNOWN  # a plain name: State.X is a descriptor call on Python 3.11


@dataclass
class StageDriver:
    """Walks one CiA 402 state machine (one controlword) towards a goal.

    Keeps every bit it does not own (halt, mode bits); a fault reset is a clean
    rising edge of bit 7 over two cycles; a transition that does not happen within
    ``timeout_s`` is reported with its name."""

    node_id: int
    controlword: Entry
    statusword: Entry
    mode: Entry | None
    mode_display: Entry | None
    error_code: Entry | None
    timeout_s: float
    resend_s: float = 0.1
    goal: State = State.SWITCH_ON_DISABLED
    allow_fault_reset: bool = False
    cw: int = 0
    statusword_value: int | None = None  # written as frames are received, read by the loop
    mode_value: int | None = None
    error_value: int | None = None
    _sent_cw: int | None = None
    _sent_at: float = -1e9
    _reset_phase: int = 0
    _waiting_since: float | None = None
    _waiting_state: State | None = None
    error: str | None = None
    _decoded: tuple[int | None, State] = (None, State.UNKNOWN)
    _at_goal_sw: int | None = None  # the statusword last seen at the goal (step's fast path)

    @property
    def state(self) -> State:
        sw = self.statusword_value
        if sw != self._decoded[0]:
            self._decoded = (sw, cia402.decode_state(sw))
        return self._decoded[1]

    def set_goal(self, goal: State, allow_fault_reset: bool = False) -> None:
        if goal is not self.goal or allow_fault_reset != self.allow_fault_reset:
            self.goal, self.allow_fault_reset = goal, allow_fault_reset
            self._at_goal_sw = None
            self._waiting_since, self.error, self._reset_phase = None, None, 0

    def forget(self) -> None:
        """The drive rebooted: its state and controlword are unknown again."""
        self.statusword_value, self.mode_value, self.error_value = None, None, None
        self._sent_cw, self.cw, self._reset_phase = None, 0, 0
        self._waiting_since = None

    def step(self, now: float) -> int | None:
        """The controlword to send this cycle, or None."""
        sw = self.statusword_value
        if sw is not None and sw == self._at_goal_sw and self.cw == self._sent_cw:
            return None  # still at the goal, its controlword sent: the loop's usual cycle
        state = self.state
        if state is self.goal or state is _UNKNOWN:
            self._waiting_since = None
            if state is self.goal:
                self._at_goal_sw = sw
                if self._sent_cw != self.cw:
                    return self._emit(now)  # e.g. the enable bits after a reboot
            return None
        self._at_goal_sw = None
        if state is State.FAULT and (self.goal is State.SWITCH_ON_DISABLED or
                                     not self.allow_fault_reset):
            self._waiting_since = None
            return None
        if state is not self._waiting_state or self._waiting_since is None:
            self._waiting_state, self._waiting_since = state, now
        elif now - self._waiting_since > self.timeout_s and self.error is None:
            cmd = cia402.command_towards(state, self.goal)
            what = "fault reset" if cmd is Command.FAULT_RESET else (
                cmd.name.lower().replace("_", " ") if cmd else "waiting")
            self.error = (f"node {self.node_id}: stuck in {state} on the way to {self.goal}: "
                          f"{what} not accepted within {self.timeout_s:g} s")
            # Said once, by whoever waits for the goal (open(), recover()): not here too.
            logger.info("%s", self.error)
        cmd = cia402.command_towards(state, self.goal)
        if cmd is None:
            return None
        if cmd is Command.FAULT_RESET:
            low, high = cia402.fault_reset_sequence(self.cw)
            if self._reset_phase == 0 or now - self._sent_at > self.resend_s * 2:
                self.cw, self._reset_phase = low, 1
            else:
                self.cw, self._reset_phase = high, 0
            return self._emit(now)
        self.cw = cia402.apply_command(self.cw, cmd)
        if self.cw != self._sent_cw or now - self._sent_at > self.resend_s:
            return self._emit(now)
        return None

    def _emit(self, now: float) -> int:
        self._sent_cw, self._sent_at = self.cw, now
        return self.cw

    def set_halt(self, halt: bool) -> None:
        self.cw = (self.cw | cia402.CW_HALT) if halt else (self.cw & ~cia402.CW_HALT)
