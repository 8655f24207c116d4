"""What a base offers the layers above it (omnican.chassis.sink): the cycle's one snapshot
sink, the attachments closed with the base, a recording opened by the base. In lock-step
(simulated time): no wall-clock timing."""

from __future__ import annotations

import itertools
from dataclasses import replace
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from omnican import Chassis
from omnican.chassis.sink import Attachments
from omnican.chassis.state import Snapshot
from omnican.clock import SimClock
from omnican.errors import ConfigError
from omnican.record.recording import FileRecording
from omnican.sim import SimulatedBase
from omnican.telemetry.attach import feed_of
from tests.support.helpers import drive_for, sim_config


class Collect:
    """A snapshot sink that keeps what it is offered."""

    def __init__(self) -> None:
        self.offered: list[Snapshot] = []

    def offer(self, snapshot: Snapshot) -> None:
        self.offered.append(snapshot)


class Closes:
    """An attachment that notes when it is closed, and with what."""

    def __init__(self, name: str, log: list[tuple[str, object]], fail: bool = False) -> None:
        self.name, self.log, self.fail = name, log, fail

    def close(self, last: Snapshot | None = None) -> None:
        self.log.append((self.name, last))
        if self.fail:
            raise RuntimeError(f"{self.name} failed to close")


def test_the_cycle_offers_every_nth_snapshot_to_its_sink(channel: str) -> None:
    cfg = sim_config(channel)
    clock = SimClock()
    sink = Collect()
    with SimulatedBase.from_config(cfg, clock=clock), \
            Chassis.open(cfg, clock=clock) as base:
        drive_for(base, 0.1, vx=0.1)
        assert sink.offered == []  # none attached: nothing offered
        base.offer_snapshots(sink, every=4)
        with pytest.raises(ValueError, match="one sink"):
            base.offer_snapshots(Collect(), every=2)  # it would take the first one's place
        clock.sleep(0.3)
        cycles = [s.status.cycles for s in sink.offered]
        assert len(cycles) >= 5
        assert all(c % 4 == 0 for c in cycles)
        assert all(b - a == 4 for a, b in itertools.pairwise(cycles))
        base.offer_snapshots(None)
        count = len(sink.offered)
        clock.sleep(0.2)
        assert len(sink.offered) == count  # detached: no more
        with pytest.raises(ValueError, match="every"):
            base.offer_snapshots(sink, every=0)


def test_the_telemetry_is_one_feed_attached_on_first_use_and_closed_with_the_base(
        channel: str) -> None:
    cfg = sim_config(channel)
    clock = SimClock()
    with SimulatedBase.from_config(cfg, clock=clock), \
            Chassis.open(cfg, clock=clock) as base:
        assert base.attachments.get("telemetry") is None  # nothing made until asked for
        feed = feed_of(base)
        assert feed_of(base) is feed
        log: list[tuple[str, object]] = []
        base.attachments.add("after the feed", Closes("after the feed", log))
    assert log == [("after the feed", base._loop.snapshot)]  # with the last snapshot
    with pytest.raises(RuntimeError, match="closed"):
        feed.add(Collect())  # type: ignore[arg-type]  # the feed was closed with the base
    with pytest.raises(RuntimeError, match="closed"):
        feed_of(base)


@given(st.lists(st.text(min_size=1, max_size=4), unique=True, max_size=8),
       st.sets(st.integers(0, 7)))
def test_attachments_close_the_last_attached_first_whatever_fails(
        names: list[str], failing: set[int]) -> None:
    log: list[tuple[str, object]] = []
    attached = Attachments()
    for i, name in enumerate(names):
        attached.add(name, Closes(name, log, fail=i in failing))
    for name in names:
        with pytest.raises(ValueError, match="already"):
            attached.add(name, Closes(name, log))
    attached.close(None)
    assert [name for name, _ in log] == names[::-1]
    attached.close(None)  # idempotent
    assert len(log) == len(names)
    with pytest.raises(RuntimeError, match="closed"):
        attached.setdefault("x", lambda: Closes("x", log))


def test_setdefault_makes_an_attachment_once() -> None:
    log: list[tuple[str, object]] = []
    attached = Attachments()
    made: list[Closes] = []

    def make() -> Closes:
        made.append(Closes("feed", log))
        return made[-1]

    first = attached.setdefault("feed", make)
    assert attached.setdefault("feed", make) is first and len(made) == 1
    assert attached.get("feed") is first and attached.get("other") is None


def test_a_base_that_cannot_be_made_writes_no_recording(channel: str, tmp_path: Path) -> None:
    cfg = sim_config(channel)
    cfg = replace(cfg, wheels=(replace(cfg.wheels[0], eds=tmp_path / "missing.eds"),
                               *cfg.wheels[1:]))
    target = tmp_path / "run.log"
    with pytest.raises(ConfigError):
        Chassis.open(cfg, record=FileRecording(target))
    assert not target.exists()


def test_record_takes_a_recording_not_a_file_name(channel: str, tmp_path: Path) -> None:
    with pytest.raises(TypeError, match="FileRecording"):
        Chassis.open(sim_config(channel), record=tmp_path / "run.log")  # type: ignore[arg-type]
    assert not (tmp_path / "run.log").exists()
