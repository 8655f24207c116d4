"""A lossy link for lock-step simulation: the host on one in-process channel, the
simulated drives on another, and between them a bridge that loses frames at random
(seeded, so a run is the same every time) or the ones a rule picks.

For testing what a real bus does to a base (noise, a loose connector): SDO requests
and answers, NMT commands, boot-ups, PDOs and heartbeats are all lost alike.
"""

from __future__ import annotations

import random
from collections.abc import Callable
from dataclasses import dataclass, field

import can

from omnican.clock import SimClock
from omnican.io.lockstep import LockstepBus

TO_DRIVES, TO_HOST = "to_drives", "to_host"

#: (frame, TO_DRIVES or TO_HOST) -> True to drop it
DropRule = Callable[[can.Message, str], bool]


@dataclass
class LinkStats:
    passed: int = 0
    lost: int = 0  # at random
    dropped: int = 0  # by a rule


@dataclass
class LossyLink:
    """Joins ``host_channel`` and ``drive_channel`` on ``clock``: every frame crosses
    unless the random loss (probability ``loss``, each way) or one of ``rules`` takes it.
    A context manager; :meth:`close` leaves both channels."""

    clock: SimClock
    host_channel: str
    drive_channel: str
    loss: float = 0.0
    seed: int = 0
    rules: list[DropRule] = field(default_factory=list)
    stats: LinkStats = field(default_factory=LinkStats)

    def __post_init__(self) -> None:
        if not 0.0 <= self.loss < 1.0:
            raise ValueError(f"loss must be a probability below 1, got {self.loss}")
        self._rng = random.Random(self.seed)
        self._host_side = LockstepBus(self.host_channel, self.clock)
        self._drive_side = LockstepBus(self.drive_channel, self.clock)
        self._host_side.set_receiver(lambda m: self._cross(m, self._drive_side, TO_DRIVES))
        self._drive_side.set_receiver(lambda m: self._cross(m, self._host_side, TO_HOST))

    def _cross(self, msg: can.Message, out: LockstepBus, direction: str) -> None:
        if self.rules and any(rule(msg, direction) for rule in self.rules):
            self.stats.dropped += 1
            return
        if self.loss and self._rng.random() < self.loss:
            self.stats.lost += 1
            return
        self.stats.passed += 1
        out.send(msg)

    def close(self) -> None:
        self._host_side.shutdown()
        self._drive_side.shutdown()

    def __enter__(self) -> LossyLink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
