"""SYNC period jitter on a real SocketCAN interface, and whether a cycle's targets
(RPDOs) still reach the bus before the SYNC they are meant for.

Needs a kernel with SocketCAN and ``vcan0`` up; ours has none, so run it in the guest:

    tools/vcan-vm/run-in-vcan-vm -- .venv/bin/python bench/bench_sync_jitter.py

Every frame is timestamped by the kernel (SO_TIMESTAMPNS) on a separate receiving
socket, so the figures are what the bus carried, not what the senders believed.
Schemes, each at 100 Hz and 1 kHz:

* ``loop``: the chassis's way. One Python thread paces itself with
  ``time.monotonic()`` and ``Event.wait``, sends the cycle's three RPDOs, then SYNC.
* ``bcm``: python-can's ``send_periodic`` on SocketCAN: the kernel's Broadcast
  Manager sends SYNC on its own timer; nothing else on the bus.
* ``bcm_tick``: BCM sends SYNC; the host loop waits for each SYNC it receives (its
  tick) and at once sends the RPDOs for the *next* SYNC, a whole period ahead.
* ``bcm_free``: BCM sends SYNC; the host loop keeps its own timer (what simply moving
  SYNC to ``send_periodic`` without changing the loop would give).
* ``omnican_loop``: omnican's own code, ``[bus] sync = "loop"``: a :class:`CanBus`, paced
  as :class:`~omnican.chassis.runner.ThreadRunner` paces the cycle (``time.sleep`` to
  the next period), three RPDOs then ``bus.sync()``.
* ``omnican_kernel``: omnican's own code, ``[bus] sync = "kernel"`` (the default on
  SocketCAN): ``bus.start_kernel_sync`` (the BCM, armed for a bounded count), and the
  loop of :class:`~omnican.chassis.runner.SyncRunner`: ``bus.wait_sync``, three RPDOs,
  ``bus.sync()`` (the re-arm).

The omnican schemes run their loop thread at SCHED_FIFO ``--rt`` (the chassis's default
``rt_priority``, 50; 0: normal priority) where the process may, as the chassis does.
``--hogs N`` runs N busy processes beside the measurement (a loaded robot computer);
``--cycles N`` sets how many cycles each run lasts (at both rates).

Printed per scheme and rate (one JSON object a line): SYNC frames seen, |period -
nominal| p50/p99/max (ms) and the mean slip (mean period - nominal, ms and %), and
for schemes with RPDOs the fraction of cycles whose RPDOs landed after the SYNC they
were meant for (``late``; for ``bcm_free``: SYNC periods that did not carry exactly one
cycle's RPDOs), with the host's reaction time for ``bcm_tick``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import socket
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import can
import numpy as np

SYNC = 0x080
RPDOS = (0x301, 0x302, 0x303)
CHANNEL = "vcan0"


@dataclass
class Capture:
    """Every SYNC and RPDO on the channel, with kernel receive timestamps."""

    channel: str
    frames: list[tuple[float, int, bytes]] = field(default_factory=list)

    def __post_init__(self) -> None:
        self._bus = can.Bus(interface="socketcan", channel=self.channel,
                            can_filters=[{"can_id": i, "can_mask": 0x7FF}
                                         for i in (SYNC, *RPDOS)])
        sock: socket.socket = self._bus.socket  # type: ignore[attr-defined]
        force = getattr(socket, "SO_RCVBUFFORCE", 33)
        try:  # never lose a frame to a full receive buffer while this thread lags
            sock.setsockopt(socket.SOL_SOCKET, force, 16 << 20)
        except OSError:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 16 << 20)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            msg = self._bus.recv(0.05)
            if msg is not None:
                self.frames.append((msg.timestamp, msg.arbitration_id, bytes(msg.data)))

    def close(self) -> list[tuple[float, int, bytes]]:
        time.sleep(0.2)  # the last frames
        self._stop.set()
        self._thread.join()
        self._bus.shutdown()
        return self.frames


def percentile(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else math.nan


def period_stats(frames: list[tuple[float, int, bytes]], period: float) -> dict[str, float]:
    t = [ts for ts, cob, _ in frames if cob == SYNC]
    periods = np.diff(t)[1:]  # the first period may straddle the start
    dev = np.abs(periods - period) * 1e3
    mean = float(np.mean(periods)) if len(periods) else math.nan
    return {
        "syncs": len(t),
        "abs_dev_p50_ms": round(percentile(list(dev), 50), 4),
        "abs_dev_p99_ms": round(percentile(list(dev), 99), 4),
        "abs_dev_max_ms": round(float(np.max(dev)) if len(dev) else math.nan, 4),
        "mean_slip_ms": round((mean - period) * 1e3, 4),
        "mean_slip_pct": round((mean - period) / period * 100, 2),
    }


def rpdo_frames(tag: int) -> list[can.Message]:
    data = struct.pack("<Q", tag)
    return [can.Message(arbitration_id=cob, data=data, is_extended_id=False) for cob in RPDOS]


def paced(period: float, seconds: float, cycle: Callable[[int], None]) -> None:
    """The chassis's pacing: ``cycle(k)`` every period on monotonic time + Event.wait,
    no burst to catch up after falling far behind."""
    stop = threading.Event()
    next_t = time.monotonic()
    end = next_t + seconds
    k = 0
    while next_t < end:
        k += 1
        cycle(k)
        next_t += period
        delay = next_t - time.monotonic()
        if delay < -period:
            next_t = time.monotonic()
            delay = 0.0
        if delay > 0:
            stop.wait(delay)


def run_loop(bus: can.BusABC, period: float, seconds: float) -> None:
    """The chassis's loop: the cycle's targets, then SYNC."""
    sync = can.Message(arbitration_id=SYNC, data=b"", is_extended_id=False)

    def cycle(k: int) -> None:
        for msg in rpdo_frames(k):
            bus.send(msg)
        bus.send(sync)

    paced(period, seconds, cycle)


def loop_late(frames: list[tuple[float, int, bytes]]) -> dict[str, float]:
    """``loop``: cycle k's RPDOs must all come before the k-th SYNC after the start."""
    late = cycles = 0
    syncs_seen = 0
    for _, cob, data in frames:
        if cob == SYNC:
            syncs_seen += 1
        elif cob == RPDOS[-1]:
            cycles += 1
            tag = struct.unpack("<Q", data)[0]
            if tag <= syncs_seen:  # SYNC number `tag` went out before its own targets
                late += 1
    return {"cycles": cycles, "late": late, "late_fraction": round(late / max(cycles, 1), 5)}


def run_bcm(bus: can.BusABC, period: float, seconds: float,
            host: Callable[[float], None] | None = None) -> None:
    task = bus.send_periodic(can.Message(arbitration_id=SYNC, data=b"", is_extended_id=False),
                             period)
    try:
        if host is None:
            time.sleep(seconds)
        else:
            host(seconds)
    finally:
        task.stop()


def tick_host(channel: str, period: float) -> Callable[[float], None]:
    """Waits for each SYNC (kernel-timed by the BCM) and sends the next cycle's RPDOs,
    tagged with the timestamp of the SYNC that triggered them."""

    def host(seconds: float) -> None:
        with can.Bus(interface="socketcan", channel=channel,
                     can_filters=[{"can_id": SYNC, "can_mask": 0x7FF}]) as bus:
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                msg = bus.recv(0.1)
                if msg is None or msg.arbitration_id != SYNC:
                    continue
                for out in rpdo_frames(round(msg.timestamp * 1e6)):
                    bus.send(out)

    return host


def tick_late(frames: list[tuple[float, int, bytes]], period: float) -> dict[str, float]:
    """``bcm_tick``: a batch triggered by SYNC k is meant for SYNC k+1; late if it
    landed after it. Reaction: trigger SYNC -> last RPDO of the batch."""
    sync_times = [ts for ts, cob, _ in frames if cob == SYNC]
    index = {round(ts * 1e6): i for i, ts in enumerate(sync_times)}
    late = cycles = unmatched = 0
    reaction = []
    for ts, cob, data in frames:
        if cob != RPDOS[-1]:
            continue
        i = index.get(struct.unpack("<Q", data)[0])
        if i is None:
            unmatched += 1
            continue
        cycles += 1
        reaction.append((ts - sync_times[i]) * 1e3)
        if i + 1 < len(sync_times) and ts > sync_times[i + 1]:
            late += 1
    return {"cycles": cycles, "late": late, "late_fraction": round(late / max(cycles, 1), 5),
            "unmatched": unmatched,
            "reaction_p50_ms": round(percentile(reaction, 50), 4),
            "reaction_p99_ms": round(percentile(reaction, 99), 4),
            "reaction_max_ms": round(max(reaction) if reaction else math.nan, 4),
            "reaction_over_period_pct": round(
                100 * sum(r > period * 1e3 for r in reaction) / max(len(reaction), 1), 3)}


def free_host(channel: str, period: float) -> Callable[[float], None]:
    """The loop keeps its own timer and sends one batch per period, SYNC or not."""

    def host(seconds: float) -> None:
        with can.Bus(interface="socketcan", channel=channel) as bus:

            def cycle(k: int) -> None:
                for msg in rpdo_frames(k):
                    bus.send(msg)

            paced(period, seconds, cycle)

    return host


def free_late(frames: list[tuple[float, int, bytes]]) -> dict[str, float]:
    """``bcm_free``: SYNC periods that carried no new batch (the drives keep the old
    target) or more than one (a target never applied)."""
    counts: list[int] = []
    current = None
    for _, cob, _data in frames:
        if cob == SYNC:
            if current is not None:
                counts.append(current)
            current = 0
        elif cob == RPDOS[-1] and current is not None:
            current += 1
    counts = counts[1:-1]  # the edges straddle start and stop
    wrong = sum(c != 1 for c in counts)
    return {"periods": len(counts), "late": wrong,
            "late_fraction": round(wrong / max(len(counts), 1), 5),
            "periods_without_targets": sum(c == 0 for c in counts),
            "periods_with_two_or_more": sum(c >= 2 for c in counts)}


def omnican_run(kernel: bool, channel: str, period: float, seconds: float,
                rt: int) -> dict[str, object]:
    """omnican's CanBus on SocketCAN, its loop as the chassis's runner runs it (on a
    thread of its own, SCHED_FIFO ``rt`` where allowed): each cycle three RPDOs, then
    ``bus.sync()``. Kernel: the cycle is woken by each SYNC and tags its RPDOs with that
    SYNC's kernel timestamp (``tick_late`` matches them); loop: with the cycle number."""
    from omnican.chassis.realtime import make_realtime
    from omnican.chassis.runner import LATE_FRACTION_OF_PERIOD, NO_SYNC_PERIODS
    from omnican.io.bus import CanBus, prepared_message

    info: dict[str, object] = {}
    stamp = [0.0]

    def on_sync(can_id: int, data: bytearray, timestamp: float) -> None:
        stamp[0] = timestamp

    def run() -> None:
        info["realtime"] = make_realtime(rt) if rt else False
        msgs = [prepared_message(cob, bytes(8)) for cob in RPDOS]
        with CanBus({"interface": "socketcan", "channel": channel,
                     "sync": "kernel" if kernel else "loop"}) as bus:
            bus.start_polling()
            bus.network.subscribe(SYNC, on_sync)
            late = restarts = 0
            end = time.monotonic() + seconds
            if kernel:
                assert bus.start_kernel_sync(period), "no broadcast manager"
                while time.monotonic() < end:
                    came = bus.wait_sync(period * NO_SYNC_PERIODS)
                    now = time.monotonic()
                    if not came:
                        if bus.kernel_sync_ran_out(now):
                            restarts += 1
                            bus.restart_kernel_sync()
                    elif now - bus.seen_sync_time > period * LATE_FRACTION_OF_PERIOD:
                        late += 1
                    bus.poll()
                    tag = struct.pack("<Q", round(stamp[0] * 1e6))
                    for m in msgs:
                        m.data = tag  # type: ignore[assignment]
                        bus.send_prepared(m, 135)
                    bus.sync()
                total = bus.kernel_sync.restarts if bus.kernel_sync else 0
                info["restarts_after_no_sync"] = restarts
                restarts = total  # and those of bus.sync(): the count ran out
                info["syncs_seen"] = bus.syncs_seen
                bus.stop_kernel_sync()
            else:
                next_t = time.monotonic()
                k = 0
                while next_t < end:
                    k += 1
                    bus.poll()
                    tag = struct.pack("<Q", k)
                    for m in msgs:
                        m.data = tag  # type: ignore[assignment]
                        bus.send_prepared(m, 135)
                    bus.sync()
                    next_t += period
                    delay = next_t - time.monotonic()
                    if delay < -period:
                        next_t = time.monotonic()
                        delay = 0.0
                    if delay > 0:
                        time.sleep(delay)
                    elif delay < -period * LATE_FRACTION_OF_PERIOD:
                        late += 1
            info["late_starts"] = late
            info["kernel_restarts"] = restarts

    thread = threading.Thread(target=run, name="omnican-loop")
    thread.start()
    thread.join()
    return info


@contextlib.contextmanager
def hogs(n: int) -> Iterator[None]:
    """``n`` processes that spin on the CPU for as long as the block runs."""
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]
    try:
        yield
    finally:
        for p in procs:
            p.kill()
            p.wait()


def measure(scheme: str, rate_hz: float, seconds: float, channel: str, rt: int = 50,
            n_hogs: int = 0) -> dict[str, object]:
    period = 1.0 / rate_hz
    info: dict[str, object] = {}
    cap = Capture(channel)
    try:
        with hogs(n_hogs):
            if scheme.startswith("omnican_"):
                # In a process of its own, as the chassis runs: this one's capture thread
                # must not hold the GIL the loop waits for.
                child = subprocess.run(
                    [sys.executable, __file__, "--child", scheme, "--channel", channel,
                     "--rates", str(rate_hz), "--seconds", str(seconds), "--rt", str(rt)],
                    capture_output=True, text=True, check=True)
                info = json.loads(child.stdout.strip().splitlines()[-1])
            else:
                with can.Bus(interface="socketcan", channel=channel) as bus:
                    if scheme == "loop":
                        run_loop(bus, period, seconds)
                    elif scheme == "bcm":
                        run_bcm(bus, period, seconds)
                    elif scheme == "bcm_tick":
                        run_bcm(bus, period, seconds, tick_host(channel, period))
                    else:
                        run_bcm(bus, period, seconds, free_host(channel, period))
    finally:
        frames = cap.close()
    out: dict[str, object] = {"scheme": scheme, "rate_hz": rate_hz, "seconds": seconds,
                              "hogs": n_hogs}
    out.update(period_stats(frames, period))
    if scheme in ("loop", "omnican_loop"):
        out.update(loop_late(frames))
    elif scheme in ("bcm_tick", "omnican_kernel"):
        out.update(tick_late(frames, period))
    elif scheme == "bcm_free":
        out.update(free_late(frames))
    out.update(info)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--channel", default=CHANNEL)
    parser.add_argument("--seconds", type=float, default=10.0, help="per run at 100 Hz")
    parser.add_argument("--fast-seconds", type=float, default=4.0, help="per run at 1 kHz")
    parser.add_argument("--schemes", default="loop,bcm,bcm_tick,bcm_free")
    parser.add_argument("--rates", default="100,1000", help="Hz, comma-separated")
    parser.add_argument("--cycles", type=int, default=0,
                        help="cycles per run at every rate (instead of the seconds)")
    parser.add_argument("--hogs", default="0",
                        help="busy processes beside each run, comma-separated: 0,2 runs "
                             "each twice")
    parser.add_argument("--rt", type=int, default=50,
                        help="SCHED_FIFO priority of the omnican schemes' loop (0: none)")
    parser.add_argument("--child", help=argparse.SUPPRESS)  # an omnican scheme's loop
    args = parser.parse_args()
    if args.child:
        info = omnican_run(args.child == "omnican_kernel", args.channel,
                           1.0 / float(args.rates), args.seconds, args.rt)
        print(json.dumps(info), flush=True)
        return
    for rate in (float(r) for r in args.rates.split(",")):
        seconds = (args.cycles / rate if args.cycles else
                   args.seconds if rate < 500 else args.fast_seconds)
        for n in (int(h) for h in args.hogs.split(",")):
            for scheme in args.schemes.split(","):
                print(json.dumps(measure(scheme, rate, seconds, args.channel, args.rt, n)),
                      flush=True)


if __name__ == "__main__":
    main()
