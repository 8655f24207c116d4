"""``--sim``'s simulated drives run on the base's control loop (omnican.io.stepped): as
steady as the loop whatever the process's other threads get, and still honest about a
host that stalls."""

from __future__ import annotations

import hashlib
import os
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

import can
import pytest

from omnican import Chassis
from omnican.cli import build_parser
from omnican.cli.session import session
from omnican.protocol import heartbeat
from omnican.protocol.cia301 import EMCY_BASE, EMCY_HEARTBEAT, HEARTBEAT_BASE
from omnican.protocol.cia402 import State
from omnican.sim import SimulatedBase
from tests.support.helpers import sim_config, wait_for

PERIODS = 30  # heartbeat periods the drives must keep up through


def emcy_codes(frames: list[can.Message]) -> list[tuple[int, int]]:
    """(node id, EMCY code) of every EMCY frame among ``frames``."""
    return [(m.arbitration_id - EMCY_BASE, int.from_bytes(m.data[:2], "little"))
            for m in frames if EMCY_BASE < m.arbitration_id < EMCY_BASE + 0x80 and len(m.data) >= 2]


def received(bus: can.BusABC) -> list[can.Message]:
    """Every frame that reached ``bus`` (read after the fact: no thread of its own)."""
    out = []
    while (msg := bus.recv(0)) is not None:
        out.append(msg)
    return out


@contextmanager
def busy_machine() -> Iterator[None]:
    """Every core busy with threads of this process at normal priority (hashing large
    buffers: the interpreter's lock released meanwhile), and every simulator thread there
    is then (its housekeeping, python-can's receiving threads) on SCHED_IDLE: the extreme
    of threads at normal priority on a desktop a browser keeps busy. What the base's
    control loop does not run itself gets no CPU for as long as this lasts."""
    stop = threading.Event()
    block = bytes(1 << 20)

    def burn() -> None:
        while not stop.is_set():
            hashlib.sha256(block).digest()

    burners = [threading.Thread(target=burn, name="test-burner", daemon=True)
               for _ in range(os.cpu_count() or 2)]
    for t in burners:
        t.start()
    for t in threading.enumerate():
        if (t.name == "omnican-sim" or t.name.startswith("Notifier for bus")) and t.native_id:
            os.sched_setscheduler(t.native_id, os.SCHED_IDLE, os.sched_param(0))
    try:
        yield
    finally:
        stop.set()
        for t in burners:
            t.join()


@pytest.mark.skipif(not hasattr(os, "SCHED_IDLE"), reason="needs Linux's SCHED_IDLE")
def test_sims_drives_keep_their_heartbeats_while_the_processs_other_threads_get_no_cpu(
        channel: str) -> None:
    args = build_parser().parse_args(["drive", "--sim"])
    with session(args) as s:
        cfg = s.cfg
        period = cfg.chassis.heartbeat_ms / 1000.0
        watcher = can.Bus(interface="virtual", channel=cfg.bus["channel"])
        try:
            with Chassis.open(cfg) as base:
                assert wait_for(lambda: base.status.enabled, timeout=10.0)
                received(watcher)  # start-up's frames: not what is checked
                with busy_machine():
                    threading.Event().wait(PERIODS * period)  # this thread asks nothing
                    status = base.status
                frames = received(watcher)
                assert status.stopped_reason is None, status.stopped_reason
                assert status.enabled
            # The base's shutdown reached the drives: their own threads were back for it.
            assert all(d.state() is State.SWITCH_ON_DISABLED for d in s.sim.drives)
        finally:
            watcher.shutdown()
    assert not [c for c in emcy_codes(frames) if c[1] == EMCY_HEARTBEAT]
    for node in (1, 2, 3):  # each drive's heartbeat went on (the host's judgement above)
        assert any(m.arbitration_id == HEARTBEAT_BASE + node for m in frames)


def test_a_stalled_loop_still_trips_the_stepped_drives_consumer(channel: str) -> None:
    """The drives' timers run before the cycle reads the bus: a loop that stalls longer
    than their consumer time finds them reacting to the host's silence (EMCY 8130h, quick
    stop), as real drives would, not stepped along with it as if nothing happened."""
    cfg = sim_config(channel)
    c = cfg.chassis
    consumer_s = heartbeat.consumer_time_ms(c.heartbeat_ms, c.heartbeat_timeout_factor) / 1000
    watcher = can.Bus(interface="virtual", channel=channel)
    try:
        with SimulatedBase.from_config(cfg, stepped=True) as sim, Chassis.open(cfg) as base:
            assert wait_for(lambda: base.status.enabled and sim.stepping, timeout=10.0)
            received(watcher)
            base._call_soon(lambda: time.sleep(3 * consumer_s))  # the loop thread stalls
            assert wait_for(lambda: base.status.stopped_reason is not None,
                            timeout=10 * consumer_s + 5.0)
            frames = received(watcher)
    finally:
        watcher.shutdown()
    assert {(n, EMCY_HEARTBEAT) for n in (1, 2, 3)} <= set(emcy_codes(frames))


def test_stepped_drives_run_on_the_loop_and_get_their_threads_back(channel: str) -> None:
    cfg = sim_config(channel)
    with SimulatedBase.from_config(cfg, stepped=True) as sim:
        assert sim.scheduler.native_id is not None  # its own thread, before a base
        with Chassis.open(cfg) as base:
            assert wait_for(lambda: sim.stepping, timeout=5.0)
            assert sim.scheduler.native_id is None and sim.network.notifier is None
            base.set_velocity(0.1, 0.0, 0.0)
            assert wait_for(lambda: sim.true_twist.vx > 0.05, timeout=5.0)
        assert not sim.stepping
        assert sim.scheduler.native_id is not None and sim.network.notifier is not None
        # A second base on the channel runs them again.
        with Chassis.open(cfg):
            assert wait_for(lambda: sim.stepping, timeout=5.0)
    assert not sim.stepping


def test_a_simulator_for_another_process_runs_its_threads_at_the_loops_class(
        channel: str) -> None:
    """``omnican sim``'s drives (``rt_priority``): their housekeeping and receiving
    threads SCHED_FIFO where the process may, again after a loop ran them."""
    from omnican.chassis.realtime import policy_of

    cfg = sim_config(channel)
    with SimulatedBase.from_config(cfg, rt_priority=cfg.chassis.rt_priority) as sim:
        if sim.realtime_refused is not None:
            pytest.skip(f"real-time priority {sim.realtime_refused}")
        readers = [t for t in threading.enumerate() if t.name.startswith("Notifier for bus")
                   and channel in t.name]
        ids = [sim.scheduler.native_id] + [t.native_id for t in readers]
        assert len(ids) == 2 and all(ids)
        assert all(policy_of(i) == os.SCHED_FIFO for i in ids if i is not None)


def test_the_hubs_relays_run_what_omnican_sim_gives_them(channel: str) -> None:
    """Every frame between ``omnican sim``'s drives and the host passes the hub's relay
    threads: each calls ``on_thread`` first (``omnican sim`` gives them its drives'
    real-time priority there)."""
    from omnican.io.hub import LoopbackHub

    relays: set[int] = set()
    with LoopbackHub(channel, port=0, on_thread=lambda: relays.add(threading.get_ident())) \
            as hub:
        client = can.Bus(interface="remote", channel=hub.url)
        try:
            client.send(can.Message(arbitration_id=0x123, data=b"\x01", is_extended_id=False))
            assert wait_for(lambda: len(relays) == 2, timeout=10.0)  # both directions
        finally:
            client.shutdown()
