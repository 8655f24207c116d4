"""The battery monitor (omnican.chassis.battery), pure: thresholds with delay and hysteresis."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from omnican.chassis.battery import BatteryMonitor, base_voltage
from omnican.config import PowerSettings

POWER = PowerSettings(warn_v=22.0, cutoff_v=20.0, hysteresis_v=0.5, delay_s=1.0)
DT = 0.02


def feed(monitor: BatteryMonitor, volts: float | None, seconds: float, t0: float) -> tuple[
        float, list[float]]:
    """Hold ``volts`` for ``seconds`` from ``t0``; (the time after, cutoff times)."""
    cut = []
    t = t0
    for _ in range(round(seconds / DT)):
        if monitor.update(t, volts):
            cut.append(t)
        t += DT
    return t, cut


def test_a_sag_shorter_than_the_delay_does_nothing() -> None:
    m = BatteryMonitor(POWER)
    t, cut = feed(m, 24.0, 1.0, 0.0)
    t, cut = feed(m, 18.0, 0.9, t)  # accelerating hard: below both for 0.9 s
    t, more = feed(m, 24.0, 1.0, t)
    assert not cut and not more and not m.low and m.warning() is None


def test_low_warns_then_cuts_off_and_holds_until_charged_above_the_hysteresis() -> None:
    m = BatteryMonitor(POWER)
    t, cut = feed(m, 21.0, 1.1, 0.0)
    assert m.low and not m.cut and not cut
    assert m.warning() == "battery low: 21.0 V (warning below 22 V)"
    t, cut = feed(m, 19.5, 1.1, t)
    assert m.cut and len(cut) == 1
    assert "battery" in m.cutoff_reason() and "below the cutoff 20 V" in m.cutoff_reason()
    t, cut = feed(m, 20.3, 2.0, t)  # above the cutoff, within the hysteresis: still cut
    assert m.cut and not cut
    t, _ = feed(m, 20.6, 0.1, t)
    assert not m.cut and m.low  # above cutoff + hysteresis, still below the warning
    t, _ = feed(m, 22.6, 0.1, t)
    assert not m.low


def test_an_unknown_voltage_changes_nothing_and_restarts_the_delay() -> None:
    m = BatteryMonitor(POWER)
    t, _ = feed(m, 19.0, 0.8, 0.0)
    t, _ = feed(m, None, 0.5, t)
    t, cut = feed(m, 19.0, 0.8, t)
    assert not cut and not m.low


@given(volts=st.lists(st.floats(15.0, 30.0), min_size=1, max_size=400))
def test_it_never_flickers(volts: list[float]) -> None:
    """Between two changes of the cutoff state the voltage crossed the whole hysteresis."""
    m = BatteryMonitor(POWER)
    changes: list[tuple[bool, float]] = []
    state = False
    for k, v in enumerate(volts):
        m.update(k * DT, v)
        if m.cut != state:
            state = m.cut
            changes.append((state, v))
    for cut, v in changes:
        assert (v < 20.0) if cut else (v >= 20.5)


def test_the_base_voltage_is_the_median_of_what_is_known() -> None:
    assert base_voltage([24.0, None, 12.0, 23.8]) == 23.8
    assert base_voltage([None, None]) is None
