"""CiA 402 tables: state decoding, commands keep other bits, transition paths."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from omnican.protocol.cia402 import (
    CW_FAULT_RESET,
    CW_HALT,
    DEVICE_TRANSITIONS,
    Command,
    Mode,
    State,
    apply_command,
    command_towards,
    decode_command,
    decode_state,
    describe_emcy,
    fault_reset_sequence,
    is_operation_enabled,
    modes_to_bits,
    state_bits,
    supported_modes,
)

REAL_STATES = [s for s in State if s is not State.UNKNOWN]


@pytest.mark.parametrize(
    ("sw", "state"),
    [
        (0x0000, State.NOT_READY_TO_SWITCH_ON),
        (0x0250, State.SWITCH_ON_DISABLED),
        (0x0231, State.READY_TO_SWITCH_ON),
        (0x0233, State.SWITCHED_ON),
        (0x0237, State.OPERATION_ENABLED),
        (0x1637, State.OPERATION_ENABLED),  # with target reached, remote, oms bits
        (0x0217, State.QUICK_STOP_ACTIVE),
        (0x021F, State.FAULT_REACTION_ACTIVE),
        (0x0218, State.FAULT),
        (0x0208, State.FAULT),
    ],
)
def test_decode_state(sw: int, state: State) -> None:
    assert decode_state(sw) is state


def test_no_data_is_its_own_state() -> None:
    assert decode_state(None) is State.UNKNOWN


def test_the_loops_enabled_test_agrees_with_the_table_for_every_statusword() -> None:
    # The control loop tests OPERATION ENABLED with one mask; every 16-bit value checked.
    for sw in range(0x10000):
        assert is_operation_enabled(sw) == (decode_state(sw) is State.OPERATION_ENABLED), hex(sw)
    assert not is_operation_enabled(None)


@pytest.mark.parametrize("state", REAL_STATES)
def test_state_bits_round_trip(state: State) -> None:
    assert decode_state(state_bits(state)) is state
    # Warning, remote, target reached and the other high bits do not change the state.
    assert decode_state(state_bits(state) | 0xFF80) is state


@given(st.integers(0, 0xFFFF), st.sampled_from(list(Command)))
def test_commands_keep_halt_and_mode_bits(cw: int, cmd: Command) -> None:
    out = apply_command(cw, cmd)
    untouched = 0xFFFF & ~cmd.mask
    assert out & untouched == cw & untouched
    assert out & cmd.mask == cmd.bits
    assert out & CW_HALT == cw & CW_HALT


@pytest.mark.parametrize(
    "cmd", [Command.SHUTDOWN, Command.SWITCH_ON, Command.ENABLE_OPERATION,
            Command.DISABLE_VOLTAGE, Command.QUICK_STOP],
)
def test_device_decodes_what_host_sends(cmd: Command) -> None:
    for other in (0x0000, CW_HALT, 0x0070, 0xFF00 & ~CW_FAULT_RESET):
        assert decode_command(apply_command(other, cmd)) is cmd


@pytest.mark.parametrize("start", REAL_STATES)
def test_host_path_reaches_enabled_and_disabled(start: State) -> None:
    for goal in (State.OPERATION_ENABLED, State.SWITCH_ON_DISABLED):
        state = start
        for _ in range(6):
            if state is goal:
                break
            cmd = command_towards(state, goal)
            if state is State.FAULT_REACTION_ACTIVE:
                assert cmd is None
                state = State.FAULT  # transition 14, automatic
                continue
            assert cmd is not None
            if cmd is Command.FAULT_RESET:
                state = State.SWITCH_ON_DISABLED  # transition 15
            elif state is State.NOT_READY_TO_SWITCH_ON:
                state = State.SWITCH_ON_DISABLED  # transition 1, automatic
            else:
                state = DEVICE_TRANSITIONS[(state, cmd)].target
        assert state is goal


def test_fault_reset_sequence_is_a_rising_edge() -> None:
    low, high = fault_reset_sequence(0x018F)
    assert not low & CW_FAULT_RESET and high & CW_FAULT_RESET
    assert low & CW_HALT and high & CW_HALT  # halt kept
    assert decode_command(low) is Command.DISABLE_VOLTAGE


def test_modes() -> None:
    assert supported_modes(0x106) == {2, 3, 9}
    assert modes_to_bits({2, 3, 9}) == 0x106
    assert supported_modes(911) == {1, 2, 3, 4, 8, 9, 10}  # Roboteq 6502h
    assert Mode.from_name("csv") is Mode.CYCLIC_SYNC_VELOCITY
    assert Mode.from_name(2) is Mode.VELOCITY
    with pytest.raises(ValueError, match="unknown mode"):
        Mode.from_name("torque")


def test_describe_emcy() -> None:
    assert describe_emcy(0x2310) == "0x2310 continuous over-current"
    assert describe_emcy(0x2399) == "0x2399 current"
    assert describe_emcy(0x8130) == "0x8130 life guard error or heartbeat error"
