"""A shared bus for the tests: the host on one lock-step channel, the drives on another,
and between them a bridge that loses frames (at random, seeded, or the ones a test
picks); plus other senders on the host's side (another master, a battery management
system with 29-bit ids).

Everything runs on the caller's thread in simulated time, so a scenario with 5 % frame
loss is the same on every run and on a loaded machine."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import can

from omnican.clock import SimClock
from omnican.io.lockstep import LockstepBus
from omnican.sim.link import DropRule, LossyLink


class Sender:
    """Another device on the host's side of the bus (a master, a BMS): sends frames now,
    or every ``period_s`` on the clock, and records what reaches it."""

    def __init__(self, clock: SimClock, channel: str) -> None:
        self.clock = clock
        self.bus = LockstepBus(channel, clock)
        self.received: list[can.Message] = []
        self.bus.set_receiver(self.received.append)
        self._tasks: list[object] = []

    def send(self, can_id: int, data: bytes, extended: bool = False) -> None:
        self.bus.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=extended))

    def every(self, period_s: float, can_id: int, data: bytes | Callable[[], bytes],
              extended: bool = False) -> object:
        def step(_now: float) -> None:
            self.send(can_id, data() if callable(data) else data, extended)

        task = self.clock.every(period_s, step)
        self._tasks.append(task)
        return task

    def stop(self) -> None:
        for task in self._tasks:
            self.clock.cancel(task)
        self._tasks.clear()

    def close(self) -> None:
        self.stop()
        self.bus.shutdown()


@contextmanager
def shared_bus(host_channel: str, loss: float = 0.0, seed: int = 0
               ) -> Iterator[tuple[SimClock, LossyLink, Sender, str]]:
    """(clock, bridge, another sender on the host's side, the drives' channel)."""
    clock = SimClock()
    drive_channel = f"{host_channel}-drives"
    bridge = LossyLink(clock, host_channel, drive_channel, loss=loss, seed=seed)
    sender = Sender(clock, host_channel)
    try:
        yield clock, bridge, sender, drive_channel
    finally:
        sender.close()
        bridge.close()


def heartbeats_of(node_id: int) -> Callable[[can.Message], bool]:
    def match(msg: can.Message) -> bool:
        return not msg.is_extended_id and msg.arbitration_id == 0x700 + node_id

    return match


def drop_next(match: Callable[[can.Message], bool], count: int, direction: str,
              after_s: float, clock: SimClock) -> DropRule:
    """A rule that drops the first ``count`` frames ``match`` picks going ``direction``,
    from ``after_s`` on the clock."""
    left = [count]

    def rule(msg: can.Message, way: str) -> bool:
        if way != direction or left[0] <= 0 or clock.now() < after_s or not match(msg):
            return False
        left[0] -= 1
        return True

    return rule


def bus_args(channel: str) -> dict[str, Any]:
    return {"interface": "virtual", "channel": channel}
