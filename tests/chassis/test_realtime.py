"""The control loop ahead of a busy machine (issue 30 item 5): its thread, and only its
thread, at real-time priority where the process may (``chassis.rt_priority``), a note
once where not, and what start-up allocated frozen out of the garbage collector while
the base runs. Figures (late cycles, gaps, heartbeat trips beside CPU hogs) are
bench/bench_rt.py's."""

from __future__ import annotations

import gc
import logging
import os
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from omnican import Chassis, ConfigError, load_config
from omnican.chassis import realtime
from omnican.chassis.runner import ThreadRunner
from omnican.sim import SimulatedBase
from tests.config.test_config import GOOD, write
from tests.support.helpers import sim_config, wait_for

ROOT = Path(__file__).resolve().parents[2]
FIFO = getattr(os, "SCHED_FIFO", -1)


def _may_run_realtime() -> str | None:
    """Why this process may not run a thread SCHED_FIFO (None: it may)."""
    if not hasattr(os, "sched_setscheduler"):
        return "no sched_setscheduler on this platform"
    why: list[str] = []

    def probe() -> None:
        try:
            os.sched_setscheduler(0, FIFO, os.sched_param(1))
        except OSError as exc:
            why.append(f"SCHED_FIFO not permitted here ({exc.strerror}): run as root or "
                       "with CAP_SYS_NICE")

    t = threading.Thread(target=probe)  # a thread of its own: it ends, nothing keeps it
    t.start()
    t.join()
    return why[0] if why else None


NOT_PERMITTED = _may_run_realtime()
needs_realtime = pytest.mark.skipif(NOT_PERMITTED is not None, reason=str(NOT_PERMITTED))


def fifo_threads(pid: int | str = "self") -> dict[int, int]:
    """Native id -> SCHED_FIFO priority of every thread of process ``pid`` that runs so."""
    out = {}
    for name in os.listdir(f"/proc/{pid}/task"):
        tid = int(name)
        try:
            if realtime.policy_of(tid) == FIFO:
                out[tid] = os.sched_getparam(tid).sched_priority
        except ProcessLookupError:  # it ended meanwhile
            continue
    return out


def loop_thread(base: Chassis) -> int:
    """The native id of ``base``'s loop thread."""
    runner = base._runner
    assert isinstance(runner, ThreadRunner)
    native_id = runner.thread.native_id
    assert native_id is not None
    return native_id


@pytest.fixture
def note_again(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """The process has not said its "not permitted" note yet."""
    monkeypatch.setattr(realtime, "_noted", False)
    yield


# ---------------------------------------------------------------- the config key


@pytest.mark.parametrize(("value", "message"), [
    ("-1", r"chassis\.rt_priority: must be 0 \(normal priority\) or a SCHED_FIFO priority "
           r"1-99, got -1"),
    ("100", r"chassis\.rt_priority: must be 0 \(normal priority\) or a SCHED_FIFO priority "
            r"1-99, got 100"),
    ("2.5", r"chassis\.rt_priority: must be int, got 2\.5"),
    ("true", r"chassis\.rt_priority: must be a number, got True"),
    ('"high"', r"chassis\.rt_priority: must be int, got 'high'"),
])
def test_rt_priority_out_of_range_is_refused_with_its_range(tmp_path: Path, value: str,
                                                            message: str) -> None:
    text = GOOD.replace("rate_hz = 100", f"rate_hz = 100\nrt_priority = {value}")
    with pytest.raises(ConfigError, match=message):
        load_config(write(tmp_path, text))


def test_rt_priority_defaults_on_and_takes_0_to_99(tmp_path: Path) -> None:
    assert load_config(write(tmp_path, GOOD)).chassis.rt_priority == 50
    for value in (0, 1, 99):
        text = GOOD.replace("rate_hz = 100", f"rate_hz = 100\nrt_priority = {value}")
        assert load_config(write(tmp_path, text)).chassis.rt_priority == value


def test_check_config_refuses_a_priority_out_of_range_in_one_line(tmp_path: Path) -> None:
    p = write(tmp_path, GOOD.replace("rate_hz = 100", "rate_hz = 100\nrt_priority = 120"))
    out = subprocess.run([sys.executable, "-m", "omnican", "check-config", str(p)],
                         capture_output=True, text=True, timeout=60, check=False,
                         env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert out.returncode == 2
    assert out.stderr.strip().splitlines() == [
        f"omnican: error: {p}: chassis.rt_priority: must be 0 (normal priority) or a SCHED_FIFO "
        "priority 1-99, got 120"]


# ---------------------------------------------------------------- the loop thread


@needs_realtime
def test_the_loop_thread_alone_runs_real_time(channel: str) -> None:
    """In a process that may: the loop thread runs SCHED_FIFO at chassis.rt_priority,
    every other thread (the simulated drives', this one) at normal priority, and so
    does a thread the loop starts (a re-configuration, a bus reconnect)."""
    cfg = sim_config(channel, rt_priority=42)
    started: dict[str, int] = {}

    def child() -> None:
        started["policy"] = realtime.policy_of(0)

    def start_child() -> None:  # runs on the loop thread
        started["parent"] = realtime.policy_of(0)
        t = threading.Thread(target=child, name="started-by-the-loop")
        t.start()
        t.join()

    with SimulatedBase.from_config(cfg), Chassis.open(cfg) as base:
        loop = loop_thread(base)
        assert fifo_threads() == {loop: 42}
        assert base._runner.realtime
        base._loop.call_soon(start_child)
        assert wait_for(lambda: "policy" in started, 5.0)
        assert started == {"parent": FIFO, "policy": os.SCHED_OTHER}
        assert realtime.policy_of(0) == os.SCHED_OTHER  # the caller's thread too
    assert fifo_threads() == {}


@needs_realtime
def test_rt_priority_0_leaves_the_loop_at_normal_priority(channel: str) -> None:
    cfg = sim_config(channel, rt_priority=0)
    with SimulatedBase.from_config(cfg), Chassis.open(cfg) as base:
        assert base.status.enabled
        assert not base._runner.realtime
        assert fifo_threads() == {}


@needs_realtime
def test_omnican_drive_runs_its_loop_thread_alone_real_time() -> None:
    """Seen from outside, in another process: `omnican drive --sim` (the simulated drives
    in its own process, on threads of their own) has one SCHED_FIFO thread, at the
    default priority, for as long as it runs."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "omnican", "drive", "--sim", "--vx", "0.1", "--duration", "3"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        seen: list[dict[int, int]] = []

        def fifo_seen() -> bool:
            try:
                threads = fifo_threads(proc.pid)
            except FileNotFoundError:  # it ended
                return True
            if threads:
                seen.append(threads)
            return len(seen) >= 20 or proc.poll() is not None

        assert wait_for(fifo_seen, 60.0, step=0.05)
        assert seen, "no thread of omnican drive ever ran SCHED_FIFO"
        assert all(list(s.values()) == [50] for s in seen), seen
        assert len({tid for s in seen for tid in s}) == 1, seen  # the same thread throughout
        _, err = proc.communicate(timeout=60)
        assert proc.returncode == 0, err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()


def test_a_process_that_may_not_says_so_once_and_runs(channel: str, note_again: None,
                                                      monkeypatch: pytest.MonkeyPatch,
                                                      caplog: pytest.LogCaptureFixture) -> None:
    """No permission (an ordinary user): the base runs at normal priority, and the log
    says why, in one line, once however often a base opens."""
    calls: list[int] = []

    def refuse(pid: int, policy: int, param: object) -> None:
        calls.append(policy)
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    cfg = sim_config(channel)
    caplog.set_level(logging.INFO, logger="omnican.chassis")
    with SimulatedBase.from_config(cfg):
        for _ in range(2):
            with Chassis.open(cfg) as base:
                assert base.status.enabled
                assert not base._runner.realtime
                assert realtime.policy_of(loop_thread(base)) == os.SCHED_OTHER
    assert len(calls) == 2 and all(p & FIFO for p in calls)  # each base asked
    notes = [r for r in caplog.records if "control loop at normal priority" in r.getMessage()]
    assert len(notes) == 1
    assert notes[0].levelno == logging.INFO
    assert notes[0].getMessage() == (
        "control loop at normal priority: real-time priority not permitted (run as root, "
        "give the program CAP_SYS_NICE, or raise RLIMIT_RTPRIO to 50); "
        "chassis.rt_priority = 0 asks for none")


# ---------------------------------------------------------------- the garbage collector


def test_startup_is_frozen_out_of_the_collector_while_the_base_runs(channel: str) -> None:
    """Once the base is enabled what start-up made is frozen (a collection while the loop
    runs walks only what came since); closed, it is given back to the collector."""
    before = gc.get_freeze_count()  # 0 unless something else froze the heap
    ours = before == 0 and realtime._frozen_by_us == 0
    cfg = sim_config(channel)
    with SimulatedBase.from_config(cfg), Chassis.open(cfg) as base:
        # the object dictionaries, the PDO maps, the libraries
        assert gc.get_freeze_count() > before + 10_000
        assert base.status.enabled
    if ours:
        assert gc.get_freeze_count() == 0
