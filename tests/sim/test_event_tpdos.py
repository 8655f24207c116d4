"""The event TPDOs' check of a simulated drive (omnican.sim.process_data.ProcessData.events):
a TPDO that maps only objects the device's stamp covers (statusword, mode display, error
code) is made again only when the stamp changed; the frames sent, and when, are the ones
a check that makes every TPDO at every tick sends."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Any

import canopen
import pytest
from canopen.sdo import SdoAbortedError
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from omnican import WHEEL_EDS
from omnican.clock import SimClock
from omnican.errors import OmnicanError
from omnican.io.lockstep import LockstepBus
from omnican.protocol.object_map import AxisObjects, Obj
from omnican.sim import SimulatedDrive, process_data
from omnican.sim.axis import Motion
from omnican.sim.health import EstopInput
from tests.support.helpers import VENDOR_EDS, lockstep_rig
from tests.support.sim_steps import Frame, act, record_drive_frames

# One step of a run: what happens, then how long the base runs on (s).
_ACTIONS = st.one_of(
    st.tuples(st.just("drive"), st.sampled_from([(0.3, 0.0, 0.0), (0.0, 0.2, 0.5),
                                                 (-0.2, 0.1, -0.4), (0.0, 0.0, 0.0)])),
    st.tuples(st.just("fault"), st.integers(0, 2)),
    st.tuples(st.just("estop"), st.booleans()),
    st.tuples(st.just("following"), st.integers(0, 2), st.booleans()),
    st.tuples(st.just("jam"), st.integers(0, 2), st.booleans()),
    st.tuples(st.just("push"), st.integers(0, 2), st.sampled_from([0.0, 0.05, -0.2])),
    st.tuples(st.just("window"), st.integers(0, 2), st.sampled_from([1, 20, 500])),
    st.tuples(st.just("mode"), st.integers(0, 2), st.sampled_from([3, 9])),
    st.tuples(st.just("stop_heartbeat"), st.integers(0, 2)),
    st.tuples(st.just("recover"),),
    st.tuples(st.just("halt"),),
)
_STEPS = st.lists(st.tuples(_ACTIONS, st.sampled_from([0.0, 0.01, 0.03, 0.2, 0.6])),
                  min_size=1, max_size=8)


def _run(channel: str, steps: list[tuple[tuple[Any, ...], float]]) -> tuple[list[Frame], int]:
    """Every frame the simulated drives send (time, COB-ID, data) through ``steps``,
    and how many of their event TPDOs the stamp covers."""
    frames: list[Frame] = []
    with lockstep_rig(channel) as (clock, sim, base):
        record_drive_frames(sim, clock, frames)
        clock.sleep(0.1)
        for action, dt in steps:
            with contextlib.suppress(OmnicanError):
                act(action, sim, base)
            clock.sleep(dt)
        covered = sum(made is not None for drive in sim.drives
                      for _, _, made in drive.comm.pdos._on_event)
    return frames, covered


@contextlib.contextmanager
def _every_tpdo_made_at_every_check() -> Iterator[None]:
    """The check as it was: no TPDO covered by the stamp, each made at every tick."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(process_data.ProcessData, "_covered", lambda self, tpdo: False)
        yield


@settings(max_examples=25, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(steps=_STEPS)
def test_the_frames_sent_are_those_of_a_check_that_makes_every_tpdo(
        channel: str, steps: list[tuple[tuple[Any, ...], float]]) -> None:
    """Faults, an e-stop, following errors, jammed and pushed wheels, a new velocity
    window or mode, a lost heartbeat, recovering and halting, driving between them:
    the drives send the same frames at the same instants with the stamp as without."""
    stamped, covered = _run(f"{channel}-stamped", steps)
    with _every_tpdo_made_at_every_check():
        every, uncovered = _run(f"{channel}-every", steps)
    assert covered == 3 and uncovered == 0  # the demo base's statusword TPDO, per drive
    assert stamped == every


def test_a_drive_standing_still_makes_no_statusword_again(
        channel: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """Enabled and standing still, the host writing its controlword and targets every
    cycle: nothing the statusword TPDO maps changes, and the check reads none of it
    again (it read the motion's statusword bits at every tick); a new velocity does."""
    calls = [0]
    real = Motion.status_bits

    def counted(self: Motion, group: Any) -> int:
        calls[0] += 1
        return real(self, group)

    monkeypatch.setattr(Motion, "status_bits", counted)
    with lockstep_rig(channel) as (clock, _sim, base):
        clock.sleep(0.5)  # enabled, standing
        assert all(w.online for w in base.wheels)
        calls[0] = 0
        clock.sleep(1.0)  # 100 ticks per drive
        assert calls[0] == 0
        base.set_velocity(0.2, 0.0, 0.0)
        clock.sleep(0.2)
        assert calls[0] > 0


# ---------------------------------------------------------------- the stamp itself

_CONTROLWORDS = [0x00, 0x02, 0x06, 0x07, 0x0F, 0x10F, 0x80]
_CHANGES = st.lists(st.one_of(
    st.tuples(st.just("controlword"), st.sampled_from(_CONTROLWORDS)),
    st.tuples(st.just("target"), st.sampled_from([0, 40, -300, 5000, 10**6])),
    st.tuples(st.just("mode"), st.sampled_from([3, 9])),
    st.tuples(st.just("window"), st.sampled_from([1, 10, 2000])),
    st.tuples(st.just("max_velocity"), st.sampled_from([0, 100])),
    st.tuples(st.just("time"), st.sampled_from([0.0, 0.001, 0.01, 0.05, 0.5])),
    st.tuples(st.just("fault"),),
    st.tuples(st.just("estop"), st.booleans()),
    st.tuples(st.just("following"), st.booleans()),
    st.tuples(st.just("jam"), st.booleans()),
    st.tuples(st.just("push"), st.sampled_from([0.0, 0.1, -0.5])),
    st.tuples(st.just("abort"), st.sampled_from([0, 1, 2, 3])),
    st.tuples(st.just("restored"),),
    st.tuples(st.just("boot"),),
), min_size=1, max_size=30)


def _change(drive: Any, clock: Any, change: tuple[Any, ...], axis: int) -> None:
    """One change to a simulated drive, made as the drive's own code makes it (objects
    written as an SDO download writes them, time passing as its housekeeping sees it)."""
    kind, *args = change
    objs = AxisObjects(drive.dictionary, axis)

    def write(where: Obj | int, value: int) -> None:
        if isinstance(where, Obj):
            entry = objs.get(where)
            if entry is None:
                return
            key = (entry.index, entry.subindex)
        elif where in drive.dictionary:
            key = (where, 0)
        else:
            return
        var = drive.node._find_object(*key)
        with contextlib.suppress(SdoAbortedError, ValueError, OverflowError):
            drive.node.sdo.download(*key, var.encode_raw(value))

    with drive.lock:
        if kind == "controlword":
            write(Obj.CONTROLWORD, args[0])
        elif kind == "target":
            write(Obj.TARGET_VELOCITY, args[0])
        elif kind == "mode":
            write(Obj.MODE, args[0])
        elif kind == "window":
            write(0x606D, args[0])
        elif kind == "max_velocity":
            write(Obj.MAX_PROFILE_VELOCITY, args[0])
        elif kind == "time":
            clock.sleep(args[0])
            drive.device.advance(clock.now())
        elif kind == "fault":
            drive.inject_fault(axis=axis)
        elif kind == "estop":
            drive.estop(args[0])
        elif kind == "following":
            (drive.inject_following_error if args[0] else drive.clear_following_error)(axis=axis)
        elif kind == "jam":
            (drive.jam if args[0] else drive.free)(axis=axis)
        elif kind == "push":
            drive.push(args[0], axis=axis)
        elif kind == "abort":  # 6007h's option, then the master lost
            write(Obj.ABORT_OPTION, args[0])
            drive.device.abort_connection()
        elif kind == "restored":
            drive.device.connection_restored()
        else:
            drive.device.booted(reset_node=True)


@settings(max_examples=200, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(eds=st.sampled_from([WHEEL_EDS, *sorted(VENDOR_EDS.glob("*.eds"))]),
       on_statusword=st.booleans(), axis=st.integers(0, 1), changes=_CHANGES)
# Enabled, a target beyond the maximum profile velocity (607Fh) written: the first look
# finds the command to recompute (the internal limit bit follows), the second, at the
# same instant, reads it as recomputed.
@example(eds=WHEEL_EDS, on_statusword=False, axis=0,
         changes=[("mode", 3), ("controlword", 6), ("controlword", 7), ("controlword", 0x0F),
                  ("max_velocity", 100), ("time", 0.01), ("target", 10**6), ("time", 0.0)])
# Enabled and at its target, then halted (controlword bit 8).
@example(eds=WHEEL_EDS, on_statusword=True, axis=0,
         changes=[("mode", 3), ("controlword", 6), ("controlword", 7), ("controlword", 0x0F),
                  ("target", 40), ("time", 0.5), ("controlword", 0x10F), ("time", 0.0)])
def test_an_unchanged_stamp_is_an_unchanged_statusword(
        channel: str, eds: Any, on_statusword: bool, axis: int,
        changes: list[tuple[Any, ...]]) -> None:
    """Whatever changes in a drive (its power stage, mode, targets, window, time and the
    motors, faults, the e-stop, wired to the statusword or not, following errors, jammed
    and pushed wheels, a lost master, a reboot), of two looks at it with one stamp
    between, the second reads every object the stamp covers as the first did: the
    event check may send the frame it made at the first."""
    clock = SimClock()
    estop = EstopInput(index=0x6041, bit=14) if on_statusword else None
    network = canopen.Network()  # sends only: a bus, no Notifier thread to stop
    network.bus = LockstepBus(f"{channel}-{eds.stem}", clock)
    try:
        with SimulatedDrive(network, 9, eds, clock=clock, estop_input=estop,
                            counts_per_unit=4.0) as drive:
            device = drive.device
            axis = min(axis, drive.num_axes - 1)
            readers = list(device.stamped.values())
            assert readers and device.stamped.keys() <= drive.comm.readers.keys()
            last: tuple[object, list[int]] | None = None
            for change in changes:
                _change(drive, clock, change, axis)
                with drive.lock:
                    stamp = device.event_stamp()  # first, as the check takes it
                    values = [read() for read in readers]
                if last is not None and last[0] == stamp:
                    assert values == last[1], change
                last = (stamp, values)
    finally:
        network.bus.shutdown()
