"""What one control cycle costs, side by side with its floor and a plain canopen loop.

For each rate (default 100 Hz and 1 kHz), in the same run:

* floor: python-can's own cost per frame on the virtual bus (send with one receiver,
  and receive), and an idle sleeper thread that only wakes at the rate: its CPU per
  cycle and its late fraction (this machine's timer tail);
* omnican: a Chassis against three simulated drives in this process, host CPU per
  cycle counted over every thread omnican's host side runs (control loop, Notifier,
  reconnect, recorder), late cycles, SYNC period jitter; with and without recording;
* plain canopen: the same cycle written with canopen's PdoMap and SYNC calls;
* minimal: the same frames and odometry hand-written with nothing else (no state
  machines, health checks, limiter, status or recording): Python's floor for this cycle
  on this machine, and so the best ratio to plain canopen any Python loop can show here;
* lock-step: the same Chassis and drives on a simulated clock, one thread, no waits;
  the time of omnican's host side (control cycle, its sends, its receive handlers)
  counted apart from the simulated drives'. No wake-ups and no thread beside it: the
  steadiest figure to compare commits by; the threaded figures above move by 30 %
  from one day to the next on a shared VM.

SYNC times are the bus timestamps the simulated drives' network sees (no extra
receiver on the channel: a receiver would make every send copy each frame once more);
the period jitter of a loop is that of its SYNCs, the sleeper's that of its wake-ups
(the floor under any loop's jitter on this machine).
A cycle is late when it starts more than a fifth of a period after its tick.

Run: ``python bench/bench_cycle.py`` (about a minute); ``--quick``; ``--rates 1000``;
``--record mcap`` (or log, blf); pinned to one core: ``taskset -c 0 python bench/...``.
Prints one JSON object per line, then a table.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import statistics
import struct
import tempfile
import threading
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import can
import canopen
import numpy as np
from bench_chassis import config, notifier_threads, percentile, thread_cpu

from omnican import Chassis
from omnican.clock import SimClock
from omnican.io.lockstep import LockstepBus
from omnican.record.recording import FileRecording
from omnican.sim import SimulatedBase

LATE = 0.2  # of a period
ROWS: list[dict[str, Any]] = []


def emit(**fields: Any) -> None:
    ROWS.append(fields)
    print(json.dumps(fields), flush=True)


def sleep_to_next_tick(tick: float, period: float) -> float:
    """Sleep to the tick after ``tick`` and return it; far behind, start again from now
    rather than burst to catch up (as omnican's loop does)."""
    tick += period
    delay = tick - time.monotonic()
    if delay < -period:
        return time.monotonic()
    if delay > 0:
        time.sleep(delay)
    return tick


def jitter(stamps: list[float], rate_hz: float) -> dict[str, float]:
    periods = np.diff(np.asarray(stamps))
    dev = np.abs(periods - 1.0 / rate_hz) * 1e6
    return {"sync_jitter_us_p50": round(percentile(dev, 50), 1),
            "sync_jitter_us_p99": round(percentile(dev, 99), 1),
            "sync_jitter_us_max": round(float(dev.max()) if dev.size else math.nan, 1)}


# ---------------------------------------------------------------- floor


def virtual_bus_cost() -> tuple[float, float]:
    """CPU microseconds per frame: send (one receiver on the channel), receive."""
    channel = f"bench-floor-{uuid.uuid4().hex[:8]}"
    n = 20000
    with can.Bus(interface="virtual", channel=channel) as tx, \
            can.Bus(interface="virtual", channel=channel) as rx:
        msg = can.Message(arbitration_id=0x301, data=bytes(4), is_extended_id=False)
        msg.data = bytes(4)  # type: ignore[assignment]  # as omnican sends: bytes copy for free
        t0 = time.thread_time()
        for _ in range(n):
            tx.send(msg)
        send = (time.thread_time() - t0) / n * 1e6
        t0 = time.thread_time()
        got = 0
        while rx.recv(0) is not None:
            got += 1
        recv = (time.thread_time() - t0) / max(got, 1) * 1e6
    return send, recv


def idle_sleeper(rate_hz: float, seconds: float) -> tuple[float, float, list[float]]:
    """(CPU us per cycle, late fraction, wake-up times) of a thread that only sleeps to
    each tick: the floor of a loop's CPU, of its late cycles, and of its period jitter."""
    period = 1.0 / rate_hz
    out: dict[str, float] = {}
    wakes: list[float] = []

    def run() -> None:
        cycles = late = 0
        next_t = time.monotonic()
        end = next_t + seconds
        cpu0 = time.thread_time()
        while next_t < end:
            now = time.monotonic()
            wakes.append(now)
            if now - next_t > period * LATE:
                late += 1
            cycles += 1
            next_t = sleep_to_next_tick(next_t, period)
        out["cpu"] = (time.thread_time() - cpu0) / cycles * 1e6
        out["late"] = late / cycles

    t = threading.Thread(target=run, name="bench-sleeper")
    t.start()
    t.join()
    return out["cpu"], out["late"], wakes


# ---------------------------------------------------------------- omnican


def host_threads(base: Chassis, sim_network: canopen.Network) -> list[threading.Thread]:
    """Every live thread of the host side (not the simulator's)."""
    sim_readers = set(getattr(sim_network.notifier, "_readers", []) or [])
    out = []
    for t in threading.enumerate():
        if t is threading.main_thread() or t in sim_readers:
            continue
        if t.name.startswith("omnican-sim") or t.name.startswith("bench-"):
            continue
        if t.name.startswith("omnican") or t.name.startswith("Notifier"):
            out.append(t)
    return out


def omnican_loop(rate_hz: float, seconds: float, record: str | None) -> None:
    cfg = config(rate_hz)
    stamps: list[float] = []
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"run.{record}" if record else None
        with SimulatedBase.from_config(cfg) as sim, Chassis.open(
                cfg, record=FileRecording(path) if path else None) as base:
            sim.network.subscribe(0x80, lambda cid, data, ts: stamps.append(ts))
            time.sleep(0.3)
            threads = host_threads(base, sim.network)
            cpu0 = {t: thread_cpu(t) for t in threads}
            cycles0, late0 = base.status.cycles, base._runner.late
            stamps.clear()
            t0 = time.monotonic()
            end = t0 + seconds
            while time.monotonic() < end:
                base.set_velocity(0.3 * math.sin(time.monotonic()), 0.1, 0.2)
                time.sleep(0.01)
            elapsed = time.monotonic() - t0
            cycles = base.status.cycles - cycles0
            late = base._runner.late - late0
            cpu = sum(thread_cpu(t) - c for t, c in cpu0.items() if t.is_alive())
            names = sorted({t.name.split(" for ")[0] for t in threads})
            sync = list(stamps)
    emit(bench="omnican", rate_hz=rate_hz, record=record or "-",
         achieved_hz=round(cycles / elapsed, 1),
         host_cpu_us_per_cycle=round(cpu / max(cycles, 1) * 1e6, 1),
         late_fraction=round(late / max(cycles, 1), 4), threads=names, **jitter(sync, rate_hz))


# ---------------------------------------------------------------- plain canopen


@contextlib.contextmanager
def enabled_canopen_nodes(cfg: Any) -> Iterator[tuple[canopen.Network, list[canopen.RemoteNode]]]:
    """A canopen network on the config's bus with every drive in velocity mode, its PDO
    maps read, started and enabled: where the hand-written loops below begin. On exit
    the drives are disabled and the network disconnected."""
    net = canopen.Network()
    net.NOTIFIER_CYCLE = 0.1
    net.connect(**cfg.bus)
    nodes = []
    for w in cfg.wheels:
        node = canopen.RemoteNode(w.node_id, str(w.eds))
        net.add_node(node)
        node.sdo[0x6060].raw = 3
        node.tpdo.read()
        node.rpdo.read()
        nodes.append(node)
    net.nmt.state = "OPERATIONAL"
    time.sleep(0.05)
    for node in nodes:
        for cw in (6, 7, 15):
            node.rpdo[1]["Controlword"].raw = cw
            node.rpdo[1].transmit()
            time.sleep(0.01)
    try:
        yield net, nodes
    finally:
        for node in nodes:
            node.rpdo[1]["Controlword"].raw = 0
            node.rpdo[1].transmit()
        net.disconnect()


def run_hand_loop(loop: Any, name: str, rate_hz: float, seconds: float, stop: threading.Event,
                  counters: dict[str, int], stamps: list[float],
                  more_threads: Any = lambda: []) -> tuple[dict[str, int], dict[str, Any]]:
    """Run a hand-written ``loop`` (it ends when ``stop`` is set) on a thread of its own
    and measure it for ``seconds`` after 0.3 s to settle: (the change of each of its
    ``counters``, the figures to emit: rate, CPU per cycle of its thread and of
    ``more_threads()``, late cycles, SYNC jitter from ``stamps``)."""
    t = threading.Thread(target=loop, name=name)
    t.start()
    time.sleep(0.3)
    threads = [t, *more_threads()]
    before = dict(counters)
    cpu0 = sum(thread_cpu(x) for x in threads)
    stamps.clear()
    t0 = time.monotonic()
    time.sleep(seconds)
    counted = {k: v - before[k] for k, v in counters.items()}
    cpu = sum(thread_cpu(x) for x in threads) - cpu0
    elapsed = time.monotonic() - t0
    sync = list(stamps)
    stop.set()
    t.join()
    cycles = max(counted["cycles"], 1)
    return counted, {"achieved_hz": round(counted["cycles"] / elapsed, 1),
                     "host_cpu_us_per_cycle": round(cpu / cycles * 1e6, 1),
                     "late_fraction": round(counted["late"] / cycles, 4),
                     **jitter(sync, rate_hz)}


def plain_canopen(rate_hz: float, seconds: float) -> None:
    """The same cycle with canopen's PdoMap calls: targets, SYNC, positions, odometry."""
    cfg = config(rate_hz)
    assert cfg.bus is not None
    kin = cfg.kinematics()
    stamps: list[float] = []
    with SimulatedBase.from_config(cfg) as sim, enabled_canopen_nodes(cfg) as (net, nodes):
        sim.network.subscribe(0x80, lambda cid, data, ts: stamps.append(ts))
        stop = threading.Event()
        counters = {"cycles": 0, "late": 0}

        def loop() -> None:
            period = 1.0 / rate_hz
            nxt = time.monotonic()
            last = None
            while not stop.is_set():
                if time.monotonic() - nxt > period * LATE:
                    counters["late"] += 1
                speeds = kin.to_wheel_speeds_array(np.array([[0.2, 0.1, 0.3]]))[0]
                for node, w, v in zip(nodes, cfg.wheels, speeds, strict=True):
                    node.rpdo[2]["Target velocity"].raw = round(v * w.velocity_scale)
                    node.rpdo[2].transmit()
                net.sync.transmit()
                pos = [node.tpdo[2]["Position actual value"].raw for node in nodes]
                travel = np.array(pos) / cfg.wheels[0].position_scale
                if last is not None:
                    kin.to_twist(travel - last)
                last = travel
                counters["cycles"] += 1
                nxt = sleep_to_next_tick(nxt, period)

        _, figures = run_hand_loop(loop, "plain-canopen-loop", rate_hz, seconds, stop, counters,
                                   stamps, lambda: notifier_threads(net))
    emit(bench="plain_canopen", rate_hz=rate_hz, **figures)


def minimal_loop(rate_hz: float, seconds: float) -> None:
    """Python's floor for this cycle: the same frames and odometry hand-written with
    nothing else (the issue's throwaway prototype): prebuilt messages refilled with
    ``bytes`` from a precompiled ``struct``, the bus drained with ``recv(0)`` and
    dispatched by COB-ID on the loop thread (no Notifier), plain floats, ``time.sleep``.
    No health checks, state machines, limiter, status or recording: what omnican adds
    on top of this is what it costs beyond the floor."""
    cfg = config(rate_hz)
    kin = cfg.kinematics()
    rows = kin.rows
    fwd = kin.forward_rows
    stamps: list[float] = []
    with SimulatedBase.from_config(cfg) as sim, enabled_canopen_nodes(cfg) as (net, nodes):
        sim.network.subscribe(0x80, lambda cid, data, ts: stamps.append(ts))
        assert net.notifier is not None and net.bus is not None
        net.notifier.stop(1.0)
        bus = net.bus
        targets = []
        slots: dict[int, tuple[int, int, float]] = {}
        pack = struct.Struct("<i").pack
        for i, (node, w) in enumerate(zip(nodes, cfg.wheels, strict=True)):
            var = node.rpdo[2]["Target velocity"]
            msg = can.Message(arbitration_id=node.rpdo[2].cob_id, is_extended_id=False,
                              data=bytes(node.rpdo[2].data))
            targets.append((msg, pack, var.offset // 8, w.velocity_scale,
                            bytearray(node.rpdo[2].data)))
            pos = node.tpdo[2]["Position actual value"]
            slots[node.tpdo[2].cob_id] = (i, pos.offset // 8, w.position_scale)
        unpack = struct.Struct("<i").unpack_from
        sync_msg = can.Message(arbitration_id=0x80, is_extended_id=False, data=b"")
        stop = threading.Event()
        counters = {"cycles": 0, "late": 0, "samples": 0}
        pose = [0.0, 0.0, 0.0]

        def loop() -> None:
            period = 1.0 / rate_hz
            nxt = time.monotonic()
            travel = [0.0] * len(nodes)
            last: list[float] | None = None
            recv = bus.recv
            send = bus.send
            while not stop.is_set():
                if time.monotonic() - nxt > period * LATE:
                    counters["late"] += 1
                while (m := recv(0)) is not None:
                    slot = slots.get(m.arbitration_id)
                    if slot is not None:
                        travel[slot[0]] = unpack(m.data, slot[1])[0] / slot[2]
                        counters["samples"] += 1
                if last is not None:
                    dx = dy = dw = 0.0
                    for k, (t, t0) in enumerate(zip(travel, last, strict=True)):
                        d = t - t0
                        dx += fwd[0][k] * d
                        dy += fwd[1][k] * d
                        dw += fwd[2][k] * d
                    c, s_ = math.cos(pose[2]), math.sin(pose[2])
                    pose[0] += c * dx - s_ * dy
                    pose[1] += s_ * dx + c * dy
                    pose[2] += dw
                last = list(travel)
                for (msg, pack, off, scale, buf), (a, b, c_) in zip(targets, rows, strict=True):
                    buf[off:off + 4] = pack(round((a * 0.2 + b * 0.1 + c_ * 0.3) * scale))
                    msg.data = bytes(buf)  # type: ignore[assignment]  # copied for free
                    send(msg)
                send(sync_msg)
                counters["cycles"] += 1
                nxt = sleep_to_next_tick(nxt, period)

        counted, figures = run_hand_loop(loop, "minimal-loop", rate_hz, seconds, stop,
                                         counters, stamps)
        truth = sim.true_pose
    # Proof that it did the work: a position sample from every wheel each cycle, and its
    # pose where the simulator's true pose is (within the motion since its last sample).
    emit(bench="minimal", rate_hz=rate_hz, **figures,
         samples_per_cycle=round(counted["samples"] / max(counted["cycles"], 1), 2),
         odometry_error_mm=round(math.hypot(pose[0] - truth.x, pose[1] - truth.y) * 1e3, 2))


# ---------------------------------------------------------------- lock-step


class _Attribution:
    """Time on one thread split between owners, nested calls counted to the inner
    owner: a SYNC the host sends runs the simulated drives inside the send, and their
    TPDOs run the host's handlers inside the drives' send."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self._stack: list[list[Any]] = []

    def wrap(self, owner: str, fn: Any) -> Any:
        clock = time.perf_counter  # one thread that never waits: wall time is CPU time
        stack, seconds = self._stack, self.seconds
        seconds.setdefault(owner, 0.0)

        def run(*args: Any, **kwargs: Any) -> Any:
            now = clock()
            if stack:
                outer = stack[-1]
                seconds[outer[0]] += now - outer[1]
            stack.append([owner, now])
            try:
                return fn(*args, **kwargs)
            finally:
                end = clock()
                inner = stack.pop()
                seconds[inner[0]] += end - inner[1]
                if stack:
                    stack[-1][1] = end
        return run


def lockstep_cycle(rate_hz: float, seconds: float) -> None:
    """Time per simulated cycle on one thread: omnican's host side (the control cycle and
    its receive handlers, its sends included) apart from the simulated drives. The
    median cycle: a shared machine's preemptions land in a few cycles' wall time."""
    cfg = config(rate_hz)
    acct = _Attribution()
    clock = SimClock()
    host_at_cycle_end: list[float] = []
    with SimulatedBase.from_config(cfg, clock=clock) as sim, \
            Chassis.open(cfg, clock=clock) as base:
        clock.sleep(0.3)
        sim_bus, host_bus = sim.network.bus, base.bus.network.bus
        assert isinstance(sim_bus, LockstepBus) and isinstance(host_bus, LockstepBus)
        sim_bus.set_receiver(acct.wrap("sim", sim_bus._receiver))
        host_bus.set_receiver(acct.wrap("host", host_bus._receiver))
        ticks = sim.scheduler._ticks
        ticks[:] = [acct.wrap("sim", tick) for tick in ticks]
        cycle = acct.wrap("host", base._runner.cycle)

        def counted(now: float) -> None:
            cycle(now)
            host_at_cycle_end.append(acct.seconds["host"])

        base._runner.cycle = counted
        cycles0 = base.status.cycles
        t0 = time.perf_counter()
        for k in range(int(seconds / 0.01)):
            base.set_velocity(0.3 * math.sin(k * 0.01), 0.1, 0.2)
            clock.sleep(0.01)
        total = time.perf_counter() - t0
        cycles = base.status.cycles - cycles0
    per_cycle = np.diff(np.asarray(host_at_cycle_end)) * 1e6
    emit(bench="lockstep", rate_hz=rate_hz,
         host_cpu_us_per_cycle=round(percentile(per_cycle, 50), 1),
         host_us_per_cycle_mean=round(float(per_cycle.mean()), 1),
         all_us_per_cycle_mean=round(total / cycles * 1e6, 1), late_fraction=0.0)


# ---------------------------------------------------------------- report


def table() -> None:
    print()
    print(f"{'rate':>6} {'what':<22} {'CPU us/cycle':>12} {'late':>7} "
          f"{'period jitter p50/p99 us':>25}")
    for r in ROWS:
        if r["bench"] not in ("omnican", "plain_canopen", "minimal", "sleeper", "lockstep"):
            continue
        what = ("omnican lock-step" if r["bench"] == "lockstep" else r["bench"]) + (f" +rec {r['record']}" if r.get("record", "-") != "-" else "")
        jit = (f"{r['sync_jitter_us_p50']:.0f} / {r['sync_jitter_us_p99']:.0f}"
               if "sync_jitter_us_p50" in r else "-")
        print(f"{r['rate_hz']:>6.0f} {what:<22} {r['host_cpu_us_per_cycle']:>12.1f} "
              f"{r['late_fraction']:>7.2%} {jit:>25}")
    for rate in sorted({r["rate_hz"] for r in ROWS if "rate_hz" in r}):
        om = [r for r in ROWS if r["bench"] == "omnican" and r["rate_hz"] == rate
              and r["record"] == "-"]
        pc = [r for r in ROWS if r["bench"] == "plain_canopen" and r["rate_hz"] == rate]
        rec = [r for r in ROWS if r["bench"] == "omnican" and r["rate_hz"] == rate
               and r["record"] != "-"]
        mn = [r for r in ROWS if r["bench"] == "minimal" and r["rate_hz"] == rate]
        if om and pc:
            print(f"{rate:>6.0f} omnican is {pc[0]['host_cpu_us_per_cycle'] / om[0]['host_cpu_us_per_cycle']:.2f}x "
                  "cheaper than plain canopen", end="")
            if mn:
                print(f" (the minimal loop {pc[0]['host_cpu_us_per_cycle'] / mn[0]['host_cpu_us_per_cycle']:.2f}x)",
                      end="")
            if rec:
                extra = rec[0]["host_cpu_us_per_cycle"] / om[0]["host_cpu_us_per_cycle"] - 1
                print(f"; recording adds {extra:+.0%}", end="")
            print()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="2 s per run instead of 5")
    parser.add_argument("--rates", default="100,1000", help="comma-separated rates in Hz")
    parser.add_argument("--record", default="log", help="recording format to compare "
                        "(log, blf, mcap; '' for none)")
    args = parser.parse_args()
    seconds = 2.0 if args.quick else 5.0
    rates = [float(r) for r in args.rates.split(",")]
    cpus = sorted(os.sched_getaffinity(0))
    send, recv = virtual_bus_cost()
    emit(bench="floor.virtual_bus", send_us_per_frame=round(send, 2),
         recv_us_per_frame=round(recv, 2), cpus=cpus)
    for rate in rates:
        cpu, late, wakes = idle_sleeper(rate, seconds)
        emit(bench="sleeper", rate_hz=rate, host_cpu_us_per_cycle=round(cpu, 1),
             late_fraction=round(late, 4), **jitter(wakes, rate))
        omnican_loop(rate, seconds, None)
        if args.record:
            omnican_loop(rate, seconds, args.record)
        plain_canopen(rate, seconds)
        minimal_loop(rate, seconds)
        lockstep_cycle(rate, seconds)
    table()
    print(f"\nfloor: virtual bus {send:.1f} us per frame sent, {recv:.1f} us received; "
          f"cpus {cpus}; median late of sleepers "
          f"{statistics.median(r['late_fraction'] for r in ROWS if r['bench'] == 'sleeper'):.2%}")


if __name__ == "__main__":
    main()
