"""Encoder counters as continuous travel; the window measured speeds average over.

Shared by the control loop (``drive``/``chassis``) and the recording decoder
(``replay``), so both read a recording's counters the same way.

Pure module: no I/O.
"""

from __future__ import annotations

#: Measured wheel speeds and body twist average over this window (s).
SPEED_WINDOW_S = 0.1


def fold_counter(counts: float, last_raw: int | None, raw: int, bits: int) -> float:
    """Continuous counts after the raw sample ``raw`` of a ``bits``-wide counter.

    The step from ``last_raw`` is taken modulo the counter span, as the shortest way
    round (so a wrap is not a jump); without a previous sample (``last_raw`` None:
    the first sample or the first after a reboot) the counts stay where they are."""
    if last_raw is None:
        return counts
    span = 1 << bits
    return counts + ((raw - last_raw + span // 2) % span - span // 2)
