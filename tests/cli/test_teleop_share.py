"""The terminal's keys beside Foxglove's clients (``teleop --foxglove-control``): the keys
hold control while they move the base and give it up when they let go; their idle zeros
neither stop nor block whoever drives then. Against a stand-in base on a simulated clock,
through the base's command sources as teleop uses them."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from omnican import Twist
from omnican.chassis.arbiter import CommandArbiter, CommandSource
from omnican.cli.teleop import refusal_note, share_command
from omnican.clock import SimClock


@dataclass(eq=False)
class StandInBase:
    clock: SimClock = field(default_factory=SimClock)
    calls: list[tuple[str, Any]] = field(default_factory=list)
    arbiter: CommandArbiter = field(default_factory=lambda: CommandArbiter(0.5))

    def command_source(self, name: str) -> CommandSource:
        return CommandSource(self, self.arbiter, name)

    def set_twist(self, twist: Twist) -> None:
        self.calls.append(("twist", twist))

    def stop(self) -> None:
        self.calls.append(("stop", None))


def test_the_keys_drive_while_they_move_and_let_go_when_idle() -> None:
    base = StandInBase()
    keys = base.command_source("the terminal's keys")
    client = base.command_source("Foxglove client 1")
    move = Twist(0.2, 0.0, 0.0)
    for _ in range(3):  # a key held: every command goes, the keys hold control
        assert share_command(keys, move) is None
        base.clock.sleep(0.05)
    assert keys.holder() == "the terminal's keys"
    assert client.drive(Twist(0.0, 0.0, 1.0)).refused_by == "the terminal's keys"
    assert share_command(keys, Twist()) is None  # let go: the base stops, control is free
    assert base.calls == [("twist", move)] * 3 + [("stop", None)]
    assert keys.holder() is None
    for _ in range(3):  # idle keys send nothing more
        base.clock.sleep(0.05)
        assert share_command(keys, Twist()) is None
    assert len(base.calls) == 4


def test_idle_keys_neither_stop_nor_block_a_client_that_drives() -> None:
    base = StandInBase()
    keys = base.command_source("the terminal's keys")
    client = base.command_source("Foxglove client 1")
    assert client.drive(Twist(0.0, 0.0, 1.0)).ok
    for _ in range(20):  # a second of idle keys beside the client's commands
        base.clock.sleep(0.05)
        assert share_command(keys, Twist()) is None
        assert client.drive(Twist(0.0, 0.0, 1.0)).ok
    assert ("stop", None) not in base.calls
    assert share_command(keys, Twist(0.2, 0.0, 0.0)) == "Foxglove client 1"  # refused


def test_keys_stopped_by_a_client_do_not_stop_the_next_driver() -> None:
    """The keys drove; a client's stop took control from them; another client drives
    meanwhile. The keys letting go then stops nothing (they no longer drive)."""
    base = StandInBase()
    keys = base.command_source("the terminal's keys")
    first, second = (base.command_source(f"Foxglove client {n}") for n in (1, 2))
    assert share_command(keys, Twist(0.2, 0.0, 0.0)) is None
    assert first.stop() == "the terminal's keys"
    assert share_command(keys, Twist(0.2, 0.0, 0.0)) == "Foxglove client 1"
    assert second.drive(Twist(0.0, 0.3, 0.0)).ok
    calls = len(base.calls)
    assert share_command(keys, Twist()) is None
    assert base.calls[calls:] == []
    assert second.holder() == "Foxglove client 2"


def test_the_dashboard_tells_who_stopped_the_keys_from_who_drives() -> None:
    """Issue 36 item 12: after a stop from the network (the fleet stop: a Zenoh ``~/stop``)
    the keys still held were refused, and the dashboard said the stopper "is driving".
    It drives nothing: it stopped the keys, which drive again once they let go."""
    base = StandInBase()
    keys = base.command_source("the terminal's keys")
    stopper = base.command_source("Zenoh service client 4844")
    publisher = base.command_source("Zenoh cmd_vel publisher 77")
    move = Twist(0.2, 0.0, 0.0)
    assert share_command(keys, move) is None  # the keys drive
    assert stopper.stop() == "the terminal's keys"  # a stop from the network
    refused = share_command(keys, move)  # the key still held
    assert refused == "Zenoh service client 4844"
    note = refusal_note(keys, refused)
    assert note == ("Zenoh service client 4844 stopped the terminal's keys: let go for "
                    "0.5 s to drive again")
    assert "is driving" not in note and keys.holder() is None
    base.clock.sleep(0.6)  # let go
    assert share_command(keys, Twist()) is None
    assert publisher.drive(Twist(0.0, 0.0, 0.5)).ok  # now someone does drive
    refused = share_command(keys, move)
    assert refused == "Zenoh cmd_vel publisher 77"
    assert refusal_note(keys, refused) == ("Zenoh cmd_vel publisher 77 is driving: space "
                                           "stops the base")
