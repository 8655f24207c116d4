"""Devices simulated in this process that a base's control loop runs itself.

Simulated drives on an in-process ``virtual`` channel normally run on threads of their
own (housekeeping, and python-can's Notifier receiving their frames). Beside a busy
desktop those threads, at normal priority and sharing the interpreter's lock with
everything else in the process, can fall behind by more than a heartbeat-consumer time
while the control loop, at real-time priority, keeps its rate: the base then stops for a
heartbeat that real drives, separate hardware, would have sent on time.

Devices that offer themselves here (:func:`offer`, keyed by their channel) are run by
the control loop of the first base that opens that channel in real time
(:func:`claim`): on the loop's thread, each cycle, :meth:`Stepped.tick` before the cycle
reads the bus (their timers: heartbeats, and their consumers watching the host, so a
host that stalled finds its drives already reacting, as real drives would) and
:meth:`Stepped.drain` after it (the cycle's frames answered at once). Their threads stop
while the loop runs them and come back when it ends (:meth:`Stepped.begin`,
:meth:`Stepped.end`). They are then exactly as steady as the loop.
"""

from __future__ import annotations

import threading
from collections.abc import Mapping
from typing import Any, Protocol


class Stepped(Protocol):
    """What a control loop calls on devices it runs (all on the loop's thread)."""

    def begin(self) -> None:
        """The loop runs them from now on: their own threads stop."""

    def tick(self, now: float) -> None:
        """Their timers at ``now`` (before the cycle reads the bus)."""

    def drain(self) -> None:
        """Every frame that reached them, handled (after the cycle sent its own)."""

    def end(self) -> None:
        """The loop ends: their own threads again."""


_offered: dict[str, Stepped] = {}
_claimed: set[int] = set()
_lock = threading.Lock()


def offer(channel: str, devices: Stepped) -> None:
    """``devices`` on the in-process virtual ``channel`` may be run by a base's loop."""
    with _lock:
        _offered[channel] = devices


def withdraw(channel: str, devices: Stepped) -> None:
    with _lock:
        if _offered.get(channel) is devices:
            del _offered[channel]


def claim(bus_kwargs: Mapping[str, Any] | None) -> Stepped | None:
    """The devices offered on the bus ``bus_kwargs`` names (a virtual channel), for one
    loop to run; None when none are, or another loop already runs them."""
    if not bus_kwargs or bus_kwargs.get("interface") != "virtual":
        return None
    with _lock:
        devices = _offered.get(str(bus_kwargs.get("channel")))
        if devices is None or id(devices) in _claimed:
            return None
        _claimed.add(id(devices))
        return devices


def release(devices: Stepped) -> None:
    """The loop that claimed ``devices`` no longer runs them."""
    with _lock:
        _claimed.discard(id(devices))
