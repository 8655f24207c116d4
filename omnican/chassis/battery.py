"""The battery, as the drives' DC link shows it: a low-voltage warning and a cutoff,
each with hysteresis and a delay.

A threshold counts once the voltage has stayed below it for ``delay_s`` (a sag while
the wheels accelerate does not), and clears once the voltage is back above it by
``hysteresis_v`` (no flicker around it). The cutoff, once reached, holds until the
voltage is back above ``cutoff_v + hysteresis_v``: the base may not be recovered
before. An unknown voltage (no drive reporting one) changes nothing and restarts the
delays. The voltage of the base is the median of its drives' (one drive's bad reading
moves nothing). Pure: no I/O, no clock.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from omnican.config import PowerSettings


def base_voltage(volts: Iterable[float | None]) -> float | None:
    """The median of the drives' DC link voltages that are known (None: none is)."""
    known = sorted(v for v in volts if v is not None)
    if not known:
        return None
    mid = len(known) // 2
    return known[mid] if len(known) % 2 else 0.5 * (known[mid - 1] + known[mid])


@dataclass
class _Threshold:
    level: float | None
    active: bool = False
    below_since: float | None = None

    def update(self, now: float, volts: float, delay_s: float, hysteresis_v: float) -> bool:
        """True when it became active at this update."""
        if self.level is None:
            return False
        if self.active:
            if volts >= self.level + hysteresis_v:
                self.active, self.below_since = False, None
            return False
        if volts >= self.level:
            self.below_since = None
            return False
        if self.below_since is None:
            self.below_since = now
        if now - self.below_since >= delay_s:
            self.active = True
            return True
        return False


class BatteryMonitor:
    """Warning and cutoff of one base (see the module docstring)."""

    def __init__(self, settings: PowerSettings) -> None:
        self.settings = settings
        self._warn = _Threshold(settings.warn_v)
        self._cutoff = _Threshold(settings.cutoff_v)
        self.volts: float | None = None  # as of the last update

    @property
    def low(self) -> bool:
        """Below the warning level (for delay_s), not yet back above it + hysteresis."""
        return self._warn.active or self._cutoff.active

    @property
    def cut(self) -> bool:
        """Below the cutoff (for delay_s), not yet back above it + hysteresis."""
        return self._cutoff.active

    def update(self, now: float, volts: float | None) -> bool:
        """The voltage at ``now``; True when the cutoff was reached at this update."""
        self.volts = volts
        s = self.settings
        if volts is None:
            self._warn.below_since = self._cutoff.below_since = None
            return False
        self._warn.update(now, volts, s.delay_s, s.hysteresis_v)
        return self._cutoff.update(now, volts, s.delay_s, s.hysteresis_v)

    def warning(self) -> str | None:
        """The warning the status shows while low, else None."""
        if not self.low or self.volts is None:
            return None
        s = self.settings
        if self.cut and s.cutoff_v is not None:
            return (f"battery {self.volts:.1f} V: below the cutoff {s.cutoff_v:g} V; recover "
                    f"once it is above {s.cutoff_v + s.hysteresis_v:g} V (charge it)")
        return f"battery low: {self.volts:.1f} V (warning below {s.warn_v:g} V)"

    def cutoff_reason(self) -> str:
        s = self.settings
        volts = f"{self.volts:.1f} V" if self.volts is not None else "unknown"
        return (f"battery low: {volts} below the cutoff {s.cutoff_v:g} V (power.cutoff_v) for "
                f"{s.delay_s:g} s")
