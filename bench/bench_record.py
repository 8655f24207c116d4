"""What recording costs the control loop: prints one JSON object per line.

For each rate (100 Hz, 1 kHz) and each recording (none, ``.log`` candump text, ``.mcap``
frames plus state), the simulated base drives for a while and this reports the control
loop's own CPU per cycle (its thread's CPU clock), its achieved rate and late cycles,
and, for the recorders, their writer thread's CPU per second, frames written and dropped;
last, the same with a Foxglove live view whose client subscribed to every topic.
The .log writer runs on a thread of its own, an MCAP recording on the telemetry's
thread (it is a front end of the telemetry, as the live view is); the loop's share is
one queue append per frame it sends or receives.

Run: ``python bench/bench_record.py`` (about a minute; ``--quick`` for a shorter run).
"""

from __future__ import annotations

import argparse
import contextlib
import math
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from bench_chassis import config, emit, loop_thread, notifier_threads, thread_cpu

from omnican import Chassis
from omnican.record.recording import FileRecording
from omnican.sim import SimulatedBase
from omnican.telemetry.attach import feed_of


def writer_thread(suffix: str | None) -> threading.Thread | None:
    """The recorder's writer thread: MCAP's, or the python-can log formats'."""
    name = {".mcap": "omnican-telemetry", None: None}.get(suffix, "omnican-recorder")
    return next((t for t in threading.enumerate() if t.name == name), None)


def bench(rate_hz: float, seconds: float, suffix: str | None, tmp: Path) -> None:
    cfg = config(rate_hz)
    record = tmp / f"bench-{int(rate_hz)}{suffix}" if suffix else None
    recording = FileRecording(record) if record is not None else None
    with SimulatedBase.from_config(cfg), Chassis.open(cfg, record=recording) as base:
        writer = writer_thread(suffix)
        notif = notifier_threads(base.bus.network)
        time.sleep(0.3)
        cycles0, late0 = base.status.cycles, base._runner.late
        loop0 = thread_cpu(loop_thread(base))
        notif0 = sum(thread_cpu(t) for t in notif)
        writer0 = thread_cpu(writer) if writer else 0.0
        t0 = time.monotonic()
        while time.monotonic() - t0 < seconds:
            base.set_velocity(0.3 * math.sin(time.monotonic()), 0.1, 0.2)
            time.sleep(0.01)
        elapsed = time.monotonic() - t0
        cycles = base.status.cycles - cycles0
        loop_cpu = thread_cpu(loop_thread(base)) - loop0
        notif_cpu = sum(thread_cpu(t) for t in notif) - notif0
        writer_cpu = (thread_cpu(writer) - writer0) if writer else None
        late = base._runner.late - late0
        mcap = suffix == ".mcap"
        recorder = recording.recorder if recording is not None else None
        dropped = feed_of(base).frames.dropped if mcap else getattr(recorder, "dropped", None)
    fields = dict(bench="record.loop", rate_hz=rate_hz, recording=suffix or "none",
                  seconds=round(elapsed, 2), achieved_hz=round(cycles / elapsed, 1),
                  late_cycle_fraction=round(late / max(cycles, 1), 4),
                  loop_cpu_us_per_cycle=round(loop_cpu / max(cycles, 1) * 1e6, 1),
                  notifier_cpu_us_per_cycle=round(notif_cpu / max(cycles, 1) * 1e6, 1))
    if writer_cpu is not None:
        fields["writer_cpu_ms_per_s"] = round(writer_cpu / elapsed * 1e3, 1)
        fields["frames_written"] = getattr(recorder, "frames", None)  # MCAP counts them
        fields["frames_dropped"] = dropped
    if record is not None and record.exists():
        fields["file_kib"] = round(record.stat().st_size / 1024, 1)
    emit(**fields)


def bench_sent_frame(tmp: Path) -> None:
    """What one sent frame costs the sending (control loop) thread, per recording: the
    bus's bookkeeping for a frame, timed on its own (no bus traffic, no other threads'
    noise in it)."""
    import uuid

    from omnican import default_config
    from omnican.clock import REAL_TIME
    from omnican.io.bus import CanBus
    from omnican.record.can_log import LogRecorder
    from omnican.record.mcap import McapRecorder
    from omnican.telemetry import Feed, TelemetrySettings

    n = 20_000
    for suffix in (None, ".log", ".mcap"):
        record = tmp / f"sent{suffix}" if suffix else None
        cfg = default_config(bus={"interface": "virtual", "channel": f"bench-{uuid.uuid4().hex[:8]}"})
        log = LogRecorder(record) if suffix == ".log" and record else None
        with CanBus(cfg.bus, recorder=log) as bus:
            feed = None
            if suffix == ".mcap" and record:
                feed = Feed(TelemetrySettings.from_config(cfg), cfg.kinematics(), REAL_TIME,
                            has_base=False)
                mcap = McapRecorder(record, cfg)
                feed.add(mcap)
                bus.add_listener(feed.frames, sent=True)
            t0 = time.thread_time()
            for i in range(n):
                bus._sent(0x301, i.to_bytes(4, "little"))
            cost = (time.thread_time() - t0) / n * 1e6
            dropped = log.dropped if log is not None else feed.frames.dropped if feed else None
            if feed is not None:
                feed.close()
                mcap.close()
        emit(bench="record.sent_frame", recording=suffix or "none",
             loop_thread_cpu_us_per_frame=round(cost, 2), dropped=dropped)


class _Watcher(threading.Thread):
    """A Foxglove client subscribed to every topic, reading and dropping what comes."""

    def __init__(self, url: str) -> None:
        super().__init__(name="bench-foxglove-client", daemon=True)
        self.url, self.messages = url, 0
        self.stop_event = threading.Event()

    def run(self) -> None:
        import json

        from websockets.sync.client import connect

        protocols: Any = ["foxglove.sdk.v1", "foxglove.websocket.v1"]  # websockets' Subprotocol
        with connect(self.url, subprotocols=protocols, max_size=None) as ws:
            subscribed = False
            while not self.stop_event.is_set():
                try:
                    data = ws.recv(timeout=0.2)
                except TimeoutError:
                    continue
                if isinstance(data, str):
                    msg = json.loads(data)
                    if msg.get("op") == "advertise" and not subscribed:
                        ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                            {"id": i, "channelId": ch["id"]}
                            for i, ch in enumerate(msg["channels"])]}))
                        subscribed = True
                else:
                    self.messages += 1


def bench_live(rate_hz: float, seconds: float) -> None:
    """The loop with a Foxglove live view that a client watches on every topic."""
    from omnican.live import watch
    from omnican.telemetry.attach import add_truth

    cfg = config(rate_hz)
    with SimulatedBase.from_config(cfg) as sim, Chassis.open(cfg) as base, \
            contextlib.ExitStack() as stack:
        add_truth(base, sim)  # as a command's session does
        view = stack.enter_context(watch(base, sim, "127.0.0.1:0"))
        assert view is not None
        watcher = _Watcher(view.url)
        watcher.start()
        publisher = next(t for t in threading.enumerate() if t.name == "omnican-telemetry")
        relay = next(t for t in threading.enumerate() if t.name == "omnican-foxglove-relay")
        time.sleep(1.0)
        cycles0, late0 = base.status.cycles, base._runner.late
        loop0, pub0, msgs0 = thread_cpu(loop_thread(base)), thread_cpu(publisher), watcher.messages
        relay0 = thread_cpu(relay)
        t0 = time.monotonic()
        while time.monotonic() - t0 < seconds:
            base.set_velocity(0.3 * math.sin(time.monotonic()), 0.1, 0.2)
            time.sleep(0.01)
        elapsed = time.monotonic() - t0
        cycles = base.status.cycles - cycles0
        fields = dict(bench="record.loop", rate_hz=rate_hz, recording="foxglove live view",
                      seconds=round(elapsed, 2), achieved_hz=round(cycles / elapsed, 1),
                      late_cycle_fraction=round((base._runner.late - late0) / max(cycles, 1), 4),
                      loop_cpu_us_per_cycle=round((thread_cpu(loop_thread(base)) - loop0)
                                                  / max(cycles, 1) * 1e6, 1),
                      publisher_cpu_ms_per_s=round((thread_cpu(publisher) - pub0)
                                                   / elapsed * 1e3, 1),
                      # the port the client connects to (omnican.live.relay): its copying
                      relay_cpu_ms_per_s=round((thread_cpu(relay) - relay0) / elapsed * 1e3, 1),
                      messages_per_s=round((watcher.messages - msgs0) / elapsed))
        watcher.stop_event.set()
        watcher.join()
    emit(**fields)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true", help="shorter runs")
    parser.add_argument("--repeat", type=int, default=1, help="runs of each case")
    args = parser.parse_args()
    seconds = 3.0 if args.quick else 8.0
    with tempfile.TemporaryDirectory(prefix="omnican-bench-") as tmp:
        bench_sent_frame(Path(tmp))
        for rate in (100.0, 1000.0):
            for _ in range(args.repeat):
                for suffix in (None, ".log", ".mcap"):
                    bench(rate, seconds, suffix, Path(tmp))
                bench_live(rate, seconds)


if __name__ == "__main__":
    main()
