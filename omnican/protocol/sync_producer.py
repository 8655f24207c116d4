"""The SYNC producer in the standard's words, and how long the kernel may send it alone.

CiA 301's SYNC carries no data, or, when the producer's synchronous counter overflow
value (object 1019h) is 2-240, one byte: a counter that runs 1, 2, ... up to that value
and starts at 1 again. :func:`counter_payloads` is that sequence, one SYNC's data each.

Where the kernel sends SYNC (the SocketCAN broadcast manager, :mod:`omnican.io.kernel_sync`)
it cycles through those payloads itself, one a period, so the counter needs no thread.
It sends only a bounded count of them after the control loop last said it is alive
(:func:`hold_count`): a hung loop stops SYNC within that count, as a dead process
(whose socket closes) stops it at once. ``[bus] sync`` chooses who sends SYNC
(:func:`sync_mode`).
"""

from __future__ import annotations

import math
from typing import Literal

SYNC_COUNTER_OVERFLOW_OBJECT = 0x1019
COUNTER_MIN, COUNTER_MAX = 2, 240  # 1019h: 0 (no counter) or 2-240; 1 and 241-255 reserved

#: How long the kernel goes on sending SYNC after the loop last re-armed it (s): long
#: enough that a loop several cycles late (a collection, a busy CPU, another thread
#: holding the GIL) keeps SYNC on time, short beside the drives' heartbeat-consumer time
#: (350 ms by default), which is what stops a base whose host hangs.
HOLD_S = 0.1
HOLD_MIN = 2  # SYNCs: the next one on time even when the loop runs a cycle late

#: ``[bus] sync``'s values: the kernel where the bus is SocketCAN (auto), or the loop.
SYNC_MODES = ("auto", "kernel", "loop")
SyncMode = Literal["kernel", "loop"]


def counter_payloads(overflow: int) -> tuple[bytes, ...]:
    """The data of consecutive SYNCs, one cycle of them: ``(b"",)`` without a counter
    (``overflow`` 0), else ``b"\\x01"`` to ``bytes([overflow])``."""
    if overflow == 0:
        return (b"",)
    if not COUNTER_MIN <= overflow <= COUNTER_MAX:
        raise ValueError(f"SYNC counter overflow value: 0 or {COUNTER_MIN}-{COUNTER_MAX}, "
                         f"not {overflow}")
    return tuple(bytes([n]) for n in range(1, overflow + 1))


def hold_count(period_s: float, hold_s: float = HOLD_S) -> int:
    """How many SYNCs the kernel sends after each re-arm: ``hold_s`` worth of periods,
    at least :data:`HOLD_MIN`."""
    if not period_s > 0:
        raise ValueError(f"period: a positive number of seconds, not {period_s}")
    # The small tolerance keeps 0.05 s at 100 Hz at 5, not 6 (0.05 / 0.01 = 5.000000001).
    return max(HOLD_MIN, math.ceil(hold_s / period_s - 1e-9))


def expired(seen_since_arm: int, hold: int) -> bool:
    """Whether the kernel has sent every SYNC it was armed for: ``seen_since_arm`` SYNCs
    came back since the last (re-)arm of ``hold``. Its timer then no longer runs, and a
    re-arm alone would not start it again: it must be started anew (one SYNC at once)."""
    return seen_since_arm >= hold


def sync_mode(setting: str, socketcan: bool) -> SyncMode:
    """Who sends SYNC: ``"kernel"`` (the broadcast manager: SocketCAN only) or
    ``"loop"`` (the control loop, after its RPDOs). ``setting`` is ``[bus] sync``;
    ``socketcan``: whether the bus is a SocketCAN interface."""
    if setting not in SYNC_MODES:
        raise ValueError(f"sync: one of {', '.join(SYNC_MODES)}, not {setting!r}")
    if setting == "loop" or not socketcan:
        return "loop"
    return "kernel"
