"""The simulated drive's CiA 402 power stage, on its own: no bus, no clock, no motors."""

from __future__ import annotations

from dataclasses import dataclass

import pytest
from hypothesis import given
from hypothesis import strategies as st

from omnican.protocol import cia402
from omnican.protocol.cia301 import EMCY_HEARTBEAT
from omnican.protocol.cia402 import Command, State, apply_command, command_towards, decode_state
from omnican.sim.stage import STAY_IN_QUICK_STOP, PowerStage, Reaction

SHUTDOWN, SWITCH_ON, ENABLE, DISABLE_VOLTAGE, QUICK_STOP = 0x06, 0x07, 0x0F, 0x00, 0x02
FAULT_RESET = 0x80


def stage_in(state: State, option: int = 2) -> PowerStage:
    """A stage walked into ``state`` by the commands a master would send."""
    stage = PowerStage(quick_stop_option=lambda: option)
    walks = {
        State.SWITCH_ON_DISABLED: [],
        State.READY_TO_SWITCH_ON: [SHUTDOWN],
        State.SWITCHED_ON: [SHUTDOWN, SWITCH_ON],
        State.OPERATION_ENABLED: [SHUTDOWN, SWITCH_ON, ENABLE],
        State.QUICK_STOP_ACTIVE: [SHUTDOWN, SWITCH_ON, ENABLE, 0x0B],
    }
    if state in walks:
        for word in walks[state]:
            stage.write_controlword(word)
    elif state is State.FAULT_REACTION_ACTIVE:
        for word in walks[State.OPERATION_ENABLED]:
            stage.write_controlword(word)
        stage.trip(0x2310)
    elif state is State.FAULT:
        stage.trip(0x2310)
    assert stage.state is state
    return stage


@pytest.mark.parametrize("transition", cia402.TRANSITIONS,
                         ids=lambda t: f"{t.number}-{t.source.name}-{t.command.name}")
def test_every_device_transition_of_the_table(transition: cia402.Transition) -> None:
    stage = stage_in(transition.source, option=6)  # 605Ah = 6: transition 16 exists
    word = apply_command(stage.controlword, transition.command)
    reaction = stage.write_controlword(word)
    assert stage.state is transition.target
    want = Reaction.ENABLED if transition.target is State.OPERATION_ENABLED else Reaction.STATE
    assert reaction is want


def test_commands_without_a_transition_change_nothing() -> None:
    stage = stage_in(State.SWITCH_ON_DISABLED)
    for word in (SWITCH_ON, ENABLE, QUICK_STOP, DISABLE_VOLTAGE):
        assert stage.write_controlword(word) is Reaction.NONE
        assert stage.state is State.SWITCH_ON_DISABLED


def test_the_halt_bit_survives_and_is_read_back() -> None:
    stage = stage_in(State.OPERATION_ENABLED)
    assert not stage.halted
    assert stage.write_controlword(ENABLE | cia402.CW_HALT) is Reaction.NONE
    assert stage.halted and stage.state is State.OPERATION_ENABLED


def test_a_fault_trips_through_the_reaction_when_powered() -> None:
    stage = stage_in(State.OPERATION_ENABLED)
    assert stage.trip(0x2310) is Reaction.FAULT
    assert stage.state is State.FAULT_REACTION_ACTIVE and stage.fault_code == 0x2310
    assert stage.trip(0x4210) is Reaction.NONE  # the first code stays
    for word in (DISABLE_VOLTAGE, FAULT_RESET, ENABLE):  # the reaction ignores commands
        assert stage.write_controlword(word) is Reaction.NONE
    assert stage.state is State.FAULT_REACTION_ACTIVE
    assert stage.settle() is Reaction.STATE  # the motors stopped: transition 14
    assert stage.state is State.FAULT and stage.fault_code == 0x2310
    unpowered = stage_in(State.SWITCHED_ON)
    assert unpowered.trip(0x3210) is Reaction.FAULT
    assert unpowered.state is State.FAULT  # nothing to stop: no reaction phase


def test_a_fault_is_reset_by_the_rising_edge_of_bit_7_only() -> None:
    stage = stage_in(State.FAULT)
    stage.write_controlword(FAULT_RESET)  # the edge from 0
    assert stage.state is State.SWITCH_ON_DISABLED and stage.fault_code == 0
    stage.trip(0x4210)
    assert stage.write_controlword(FAULT_RESET | SHUTDOWN) is Reaction.NONE  # bit 7 held high
    assert stage.state is State.FAULT
    assert stage.write_controlword(SHUTDOWN) is Reaction.NONE  # no command leaves FAULT
    assert stage.write_controlword(FAULT_RESET) is Reaction.RESET
    assert stage.state is State.SWITCH_ON_DISABLED


def test_a_persistent_fault_is_not_reset_until_its_cause_is_gone() -> None:
    stage = stage_in(State.FAULT)
    stage.fault_persists = True
    for word in (FAULT_RESET, DISABLE_VOLTAGE, FAULT_RESET):
        assert stage.write_controlword(word) is Reaction.NONE
    assert stage.state is State.FAULT and stage.fault_code == 0x2310
    stage.fault_persists = False
    assert stage.write_controlword(FAULT_RESET) is Reaction.NONE  # bit 7 was already high
    assert stage.write_controlword(DISABLE_VOLTAGE) is Reaction.NONE
    assert stage.write_controlword(FAULT_RESET) is Reaction.RESET


@pytest.mark.parametrize("option", range(9))
def test_quick_stop_ends_or_stays_per_605a(option: int) -> None:
    stage = stage_in(State.QUICK_STOP_ACTIVE, option)
    stays = option in STAY_IN_QUICK_STOP
    enable = stage.write_controlword(ENABLE)  # transition 16 exists only where it stays
    assert enable is (Reaction.ENABLED if stays else Reaction.NONE)
    if stays:
        stage.write_controlword(0x0B)
    assert stage.settle() is (Reaction.NONE if stays else Reaction.STATE)
    assert stage.state is (State.QUICK_STOP_ACTIVE if stays else State.SWITCH_ON_DISABLED)


def test_the_quick_stop_option_is_read_only_when_a_transition_needs_it() -> None:
    reads: list[int] = []

    def option() -> int:
        reads.append(2)
        return 2

    stage = PowerStage(quick_stop_option=option)
    for word in (SHUTDOWN, SWITCH_ON, ENABLE, SWITCH_ON, ENABLE, 0x0B):
        stage.write_controlword(word)
    assert reads == []
    stage.write_controlword(ENABLE)  # transition 16?
    stage.settle()  # end of the quick stop?
    assert len(reads) == 2


@pytest.mark.parametrize(("option", "powered_to", "reaction", "warns"), [
    (cia402.ABORT_NO_ACTION, State.OPERATION_ENABLED, Reaction.NONE, True),
    (cia402.ABORT_FAULT, State.FAULT_REACTION_ACTIVE, Reaction.FAULT, False),
    (cia402.ABORT_DISABLE_VOLTAGE, State.SWITCH_ON_DISABLED, Reaction.STATE, False),
    (cia402.ABORT_QUICK_STOP, State.QUICK_STOP_ACTIVE, Reaction.STATE, False),
    (7, State.QUICK_STOP_ACTIVE, Reaction.STATE, False),  # a code it does not know
])
def test_abort_connection_per_6007(option: int, powered_to: State, reaction: Reaction,
                                   warns: bool) -> None:
    stage = stage_in(State.OPERATION_ENABLED)
    assert stage.abort_connection(option) is reaction
    assert stage.state is powered_to and stage.warning is warns
    if reaction is Reaction.FAULT:
        assert stage.fault_code == EMCY_HEARTBEAT
    stage.connection_restored()
    assert not stage.warning
    idle = stage_in(State.SWITCHED_ON)  # nothing to stop: only "no action" warns
    assert idle.abort_connection(option) is Reaction.NONE
    assert idle.state is State.SWITCHED_ON and idle.warning is warns


def test_a_quick_stop_under_way_is_not_stopped_again() -> None:
    stage = stage_in(State.QUICK_STOP_ACTIVE)
    assert stage.abort_connection(cia402.ABORT_QUICK_STOP) is Reaction.NONE
    assert stage.state is State.QUICK_STOP_ACTIVE


def test_enable_held_keeps_the_stage_from_operation_enabled() -> None:
    stage = stage_in(State.SWITCHED_ON)
    stage.enable_held = True
    assert stage.write_controlword(ENABLE) is Reaction.NONE
    assert stage.state is State.SWITCHED_ON
    stage.enable_held = False
    assert stage.write_controlword(ENABLE) is Reaction.ENABLED


def test_power_up_forgets_everything_but_what_holds_the_power_off() -> None:
    stage = stage_in(State.FAULT)
    stage.fault_persists, stage.warning, stage.enable_held = True, True, True
    stage.power_up()
    assert (stage.state, stage.controlword, stage.fault_code) == (State.SWITCH_ON_DISABLED, 0, 0)
    assert not stage.fault_persists and not stage.warning and stage.enable_held


@pytest.mark.parametrize("state", [s for s in State if s is not State.UNKNOWN
                                   and s is not State.NOT_READY_TO_SWITCH_ON])
@pytest.mark.parametrize("warning", [False, True])
def test_the_statusword_shows_the_state(state: State, warning: bool) -> None:
    stage = stage_in(state)
    stage.warning = warning
    sw = stage.statusword()
    assert decode_state(sw) is state
    assert sw & cia402.SW_REMOTE
    assert bool(sw & cia402.SW_WARNING) is warning
    assert not sw & (cia402.SW_TARGET_REACHED | cia402.SW_INTERNAL_LIMIT | cia402.SW_OMS_12)


# ------------------------------------------------------------ property tests


@dataclass(frozen=True)
class Step:
    """One event a stage can meet: a controlword, a fault, the motors stopping, a
    lost master, a fault's cause going away, the power stage held off or released."""

    kind: str
    value: int = 0


WORDS = st.one_of(
    st.sampled_from([SHUTDOWN, SWITCH_ON, ENABLE, DISABLE_VOLTAGE, QUICK_STOP, 0x0B, 0x03,
                     FAULT_RESET, FAULT_RESET | ENABLE, ENABLE | cia402.CW_HALT]),
    st.integers(0, 0xFFFF),
)
STEPS = st.one_of(
    st.builds(Step, st.just("cw"), WORDS),
    st.builds(Step, st.just("cw"), WORDS),
    st.builds(Step, st.just("trip"), st.sampled_from([0x2310, 0x4210])),
    st.builds(Step, st.just("persist"), st.integers(0, 1)),
    st.builds(Step, st.just("settle")),
    st.builds(Step, st.just("abort"), st.integers(0, 4)),
    st.builds(Step, st.just("restored")),
    st.builds(Step, st.just("hold"), st.integers(0, 1)),
)


def run(stage: PowerStage, step: Step) -> Reaction:
    if step.kind == "cw":
        return stage.write_controlword(step.value)
    if step.kind == "trip":
        return stage.trip(step.value)
    if step.kind == "persist":
        stage.fault_persists = bool(step.value)
    elif step.kind == "settle":
        return stage.settle()
    elif step.kind == "abort":
        return stage.abort_connection(step.value)
    elif step.kind == "restored":
        stage.connection_restored()
    else:
        stage.enable_held = bool(step.value)
    return Reaction.NONE


@given(st.lists(STEPS, max_size=60), st.integers(0, 8))
def test_every_path_obeys_the_device_rules(steps: list[Step], option: int) -> None:
    stage = PowerStage(quick_stop_option=lambda: option)
    ready_since_off = False  # READY TO SWITCH ON seen since the power was last off
    for step in steps:
        before, word_before, persisted = stage.state, stage.controlword, stage.fault_persists
        reaction = run(stage, step)
        after = stage.state
        # A reaction is reported exactly when the state changed.
        assert (reaction is Reaction.NONE) is (after is before)
        if after is State.OPERATION_ENABLED and before is not after:
            # Into OPERATION ENABLED only through the switch-on sequence (or back from a
            # quick stop the drive stays in), never with the power stage held off.
            assert reaction is Reaction.ENABLED and step.kind == "cw"
            assert not stage.enable_held
            assert before in (State.READY_TO_SWITCH_ON, State.SWITCHED_ON,
                              State.QUICK_STOP_ACTIVE)
            if before is State.QUICK_STOP_ACTIVE:
                assert option in STAY_IN_QUICK_STOP
            else:
                assert ready_since_off
            if before is State.READY_TO_SWITCH_ON:  # 3 and 4 at once: switched on too
                assert step.value & 0x8F == 0x0F
        if before is State.FAULT and after is not State.FAULT:
            # Out of FAULT only by a rising edge of bit 7, only if the cause is gone.
            assert step.kind == "cw" and reaction is Reaction.RESET
            assert step.value & FAULT_RESET and not word_before & FAULT_RESET
            assert not persisted
            assert after is State.SWITCH_ON_DISABLED and stage.fault_code == 0
        if before is State.FAULT_REACTION_ACTIVE and after is not before:
            assert step.kind == "settle" and after is State.FAULT
        if reaction is Reaction.FAULT:
            assert after in (State.FAULT, State.FAULT_REACTION_ACTIVE) and stage.fault_code
        if after in (State.SWITCH_ON_DISABLED, State.FAULT, State.FAULT_REACTION_ACTIVE):
            ready_since_off = False
        elif after is State.READY_TO_SWITCH_ON:
            ready_since_off = True
        assert decode_state(stage.statusword()) is after
        assert bool(stage.statusword() & cia402.SW_WARNING) is stage.warning


@given(st.lists(STEPS, max_size=40), st.integers(0, 8), st.sampled_from(
    [State.OPERATION_ENABLED, State.SWITCH_ON_DISABLED]))
def test_the_host_walk_reaches_its_goal_from_wherever_the_stage_is(
        steps: list[Step], option: int, goal: State) -> None:
    """What the host side does (cia402.command_towards, a fault reset as a clean edge)
    takes the simulated stage to the goal in a few words, waiting out a fault reaction,
    unless the fault persists or the power stage is held off."""
    stage = PowerStage(quick_stop_option=lambda: option)
    for step in steps:
        run(stage, step)
    stage.fault_persists = stage.enable_held = False
    for _ in range(8):
        if stage.state is goal:
            break
        command = command_towards(stage.state, goal)
        if command is None:  # a fault reaction: the motors come to a stop
            assert stage.state is State.FAULT_REACTION_ACTIVE
            stage.settle()
        elif command is Command.FAULT_RESET:
            for word in cia402.fault_reset_sequence(stage.controlword):
                stage.write_controlword(word)
        else:
            stage.write_controlword(apply_command(stage.controlword, command))
    assert stage.state is goal


# ---------------------------------------------------------------- acting on arrival


@given(words=st.lists(st.sampled_from([SHUTDOWN, SWITCH_ON, ENABLE, DISABLE_VOLTAGE,
                                       QUICK_STOP, ENABLE | cia402.CW_HALT]), max_size=30))
def test_a_stage_acting_on_arrival_runs_only_after_a_repeat_in_operation_enabled(
        words: list[int]) -> None:
    """ros2_canopen's fake slave: the states as any drive's, but in OPERATION ENABLED its
    motors start only at a controlword that arrives there asking for it (enable
    operation, halted or not); a drive that does not act on arrival runs at once."""
    lazy = stage_in(State.SWITCH_ON_DISABLED)
    lazy.on_arrival = True
    eager = stage_in(State.SWITCH_ON_DISABLED)
    arrived_enabled = False
    for word in words:
        was = lazy.state
        lazy.write_controlword(word)
        eager.write_controlword(word)
        assert lazy.state is eager.state  # the states do not change
        if lazy.state is not State.OPERATION_ENABLED:
            arrived_enabled = False
        elif was is State.OPERATION_ENABLED and word & 0x8F == ENABLE:
            arrived_enabled = True
        if lazy.state is State.OPERATION_ENABLED:
            assert lazy.running == arrived_enabled
            assert eager.running


def test_the_enable_command_again_starts_the_motors() -> None:
    stage = stage_in(State.SWITCHED_ON)
    stage.on_arrival = True
    assert stage.write_controlword(ENABLE) is Reaction.ENABLED
    assert stage.state is State.OPERATION_ENABLED and not stage.running
    assert stage.write_controlword(ENABLE) is Reaction.STATE  # the motors follow it now
    assert stage.running
    assert stage.write_controlword(ENABLE) is Reaction.NONE


_EVENTS = st.one_of(
    st.tuples(st.just("write"), st.sampled_from([SHUTDOWN, SWITCH_ON, ENABLE, DISABLE_VOLTAGE,
                                                  QUICK_STOP, FAULT_RESET, 0x00,
                                                  ENABLE | cia402.CW_HALT])),
    st.tuples(st.sampled_from(["trip", "held", "released", "sto", "sto off", "settle",
                               "abort", "arrival", "power up"]), st.just(0)))


@given(events=st.lists(_EVENTS, max_size=60), option=st.sampled_from([2, 6]))
def test_a_repeated_word_taken_as_idle_changes_nothing(events: list[tuple[str, int]],
                                                        option: int) -> None:
    """The simulated drive skips a controlword written again when :meth:`idle` says it
    would change nothing: whatever happened in between (faults, a held power stage, safe
    torque off, a quick stop settling, acting on arrival), a stage that skips those and
    one that acts on every write stay alike."""
    every, skipping = (PowerStage(quick_stop_option=lambda: option) for _ in range(2))
    for kind, word in events:
        for stage in (every, skipping):
            if kind == "write":
                if stage is skipping and stage.idle(word):
                    continue
                stage.write_controlword(word)
            elif kind == "trip":
                stage.trip(0x2310)
            elif kind in ("held", "released"):
                stage.enable_held = kind == "held"
            elif kind in ("sto", "sto off"):
                stage.safe_torque_off(kind == "sto")
            elif kind == "settle":
                stage.settle()
            elif kind == "abort":
                stage.abort_connection(cia402.ABORT_QUICK_STOP)
            elif kind == "arrival":
                stage.on_arrival = not stage.on_arrival
            else:
                stage.power_up()
        assert (skipping.state, skipping.running, skipping.controlword, skipping.statusword()) \
            == (every.state, every.running, every.controlword, every.statusword())
