"""Issue 30.2: an interlock (the battery's cutoff, the e-stop, a bus-off controller) holds
whatever arrives while recover() runs. recover() asks first on the caller's thread; the
loop may run cycles before the latch is cleared on its thread, and any stop reason may
arrive then: each test puts one there (the caller's check is wrapped to run the
simulation for a while after it answered), in lock-step against the simulator."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import can
import pytest

from omnican import Chassis
from omnican.clock import SimClock
from omnican.errors import DriveError
from omnican.io.lockstep import LockstepBus
from omnican.protocol import can_state as cs
from omnican.sim import SimulatedBase
from tests.support.helpers import drive_for, lockstep_rig, wait_for


@pytest.fixture
def rig(channel: str) -> Iterator[tuple[SimClock, SimulatedBase, Chassis, LockstepBus]]:
    with lockstep_rig(channel) as (clock, sim, base):
        other = LockstepBus(channel, clock)  # another device on the bus, the kernel's frames
        try:
            yield clock, sim, base, other
        finally:
            other.shutdown()


def frame(bus: LockstepBus, can_id: int, data: bytes, error: bool = False) -> None:
    bus.send(can.Message(arbitration_id=can_id, data=data.ljust(8, b"\0") if error else data,
                         is_error_frame=error, is_extended_id=False))


#: Stop reasons, each as the simulator (or another device on the bus) makes it happen.
STOPS: dict[str, Callable[[SimulatedBase, LockstepBus], None]] = {
    "none": lambda sim, bus: None,
    "heartbeat EMCY": lambda sim, bus: sim.drives[0].inject_fault(0x8130),
    "over-current fault": lambda sim, bus: sim.drives[1].inject_fault(0x2310),
    "heartbeat lost": lambda sim, bus: sim.drives[1].stop_heartbeat(),
    "reboot": lambda sim, bus: sim.drives[2].reboot(),
    "another master's NMT": lambda sim, bus: frame(bus, 0x000, bytes([0x80, 1])),
    "e-stop": lambda sim, bus: sim.estop(True),
    "bus-off": lambda sim, bus: frame(bus, cs.ERR_BUSOFF, b"", error=True),
    "pushed wheel": lambda sim, bus: sim.drives[0].push(0.2),
}


def in_the_window(base: Chassis, then: Callable[[], None]) -> None:
    """recover()'s first check answers as it would, then ``then`` runs (the loop thread
    going on meanwhile) before recover() asks the loop to clear the stop."""
    monitor = base._supervisor.checks
    check = monitor.recover_refused
    calls: list[str | None] = []

    def refused() -> str | None:
        answer = check()
        if not calls:
            calls.append(answer)
            then()
        return answer

    monitor.recover_refused = refused  # type: ignore[method-assign]


def never_runs(clock: SimClock, sim: SimulatedBase, base: Chassis) -> None:
    """Commanded to drive for a second, the base stays held stopped."""
    end = clock.now() + 1.0
    while clock.now() < end:
        base.set_velocity(0.2, 0.0, 0.0)
        clock.sleep(0.02)
        st = base.status
        assert not st.enabled and st.stopped_reason is not None, st


@pytest.mark.parametrize("stop", list(STOPS))
def test_recover_is_refused_when_the_cutoff_is_reached_while_it_runs(
        rig: tuple[SimClock, SimulatedBase, Chassis, LockstepBus], stop: str) -> None:
    """As found: the drives' heartbeat EMCYs stopped the base, the battery below its cutoff;
    recover pressed before the cutoff's delay ran out, the cutoff reached (and another stop
    reason arriving) before the loop cleared the stop."""
    clock, sim, base, other = rig
    drive_for(base, 0.5, vx=0.2)
    sim.drives[0].inject_fault(0x8130)
    assert wait_for(lambda: base.status.stopped_reason is not None, 1.0, clock=clock)
    sim.drives[0].clear_fault()
    sim.set_battery(19.0)
    monitor = base._supervisor.checks
    assert monitor.battery is not None and not monitor.battery.cut  # its delay runs

    def meanwhile() -> None:
        STOPS[stop](sim, other)
        assert wait_for(lambda: monitor.battery is not None and monitor.battery.cut, 2.0,
                        clock=clock)
        clock.sleep(0.1)

    in_the_window(base, meanwhile)
    # (An e-stop or a bus-off is the refusal's first reason, before the battery.)
    with pytest.raises(DriveError, match=r"recover refused: (battery 19.0 V: below the cutoff"
                                         r"|e-stop pressed|the CAN controller is bus-off)"):
        base.recover()
    never_runs(clock, sim, base)
    assert base.status.battery == "cutoff"


@pytest.mark.parametrize(("interlock", "refusal"), [
    ("e-stop", "recover refused: e-stop pressed"),
    ("bus-off", "recover refused: the CAN controller is bus-off")])
@pytest.mark.parametrize("stop", ["none", "heartbeat EMCY", "reboot"])
def test_recover_is_refused_when_an_interlock_comes_while_it_runs(
        rig: tuple[SimClock, SimulatedBase, Chassis, LockstepBus], interlock: str,
        refusal: str, stop: str) -> None:
    clock, sim, base, other = rig
    drive_for(base, 0.5, vx=0.2)
    sim.drives[1].inject_fault(0x2310)
    assert wait_for(lambda: base.status.stopped_reason is not None, 1.0, clock=clock)
    sim.drives[1].clear_fault()

    def meanwhile() -> None:
        STOPS[stop](sim, other)
        STOPS[interlock](sim, other)
        clock.sleep(0.5)

    in_the_window(base, meanwhile)
    with pytest.raises(DriveError, match=refusal):
        base.recover()
    never_runs(clock, sim, base)
