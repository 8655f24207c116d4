"""Can a hostile Foxglove client stall the wheels? The control loop at 100 Hz against the
simulated base, its live view serving control (with a token), while one abusive client
in another process does its worst for the whole run: nothing (quiet), 16 MB Twists (a
16,000,000-character string for linear.x; each ends its connection, and it connects
again), deeply nested JSON (100k ``[`` as a
protocol message, 4,000 ``[`` as a Twist), long bad values (60 KB parameter values and
service requests), or invalid protocol messages (5,000 a round). The abuser has the
token, so what it sends reaches every check. Runs interleave, so the machine's load is
alike for all.

Prints one JSON object per run and a last one per kind of abuse: the longest gap between
two cycles (the worst run's, and the median over the rounds: a loaded machine's hiccups
land in any run), the 99th percentile gap, late cycles, the process's memory growth
(RSS), the ratio of the longest gap to a quiet run's (the goal: within 2x), and a
witness's longest gap: a process of its own that only sleeps 10 ms at a time, so a stall
it sees too is the machine's, not the live view's.

Run: ``python bench/bench_foxglove_abuse.py`` (``--seconds 8 --rounds 2 --rate 100``).
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from bench_chassis import config, cycle_starts, emit

from omnican import Chassis
from omnican.live import FoxgloveSettings, watch
from omnican.sim import SimulatedBase
from omnican.telemetry.attach import add_truth

TOKEN = "bench-token"

# The abuser: a raw WebSocket client (websockets), looping until its time is up.
ABUSER = r'''
import json, sys, time
from websockets.sync.client import connect

url, kind, seconds = sys.argv[1], sys.argv[2], float(sys.argv[3])
end = time.monotonic() + seconds
ADVERTISE = json.dumps({"op": "advertise", "channels": [{"id": 1, "topic": "/cmd_vel",
                        "encoding": "json", "schemaName": "geometry_msgs/Twist"}]})

def opened():
    ws = connect(url, subprotocols=["foxglove.sdk.v1"], open_timeout=10,
                 max_size=None).__enter__()
    ws.recv(timeout=10)
    ws.send(ADVERTISE)
    return ws

def drain(ws, tag):
    ws.send(json.dumps({"op": "getParameters", "parameterNames": [], "id": tag}))
    while True:
        m = ws.recv(timeout=30)
        if isinstance(m, str) and tag in m and "parameterValues" in m:
            return

PAYLOAD = (b"\x01" + (1).to_bytes(4, "little") + b'{"linear": {"x": "' + b"9" * 16_000_000
           + b'"}}')  # a Twist whose number is a 16 MB string: parsed, it is a bad value
BIG = bytes([0x82, 0x80 | 127]) + len(PAYLOAD).to_bytes(8, "big") + bytes(4) + PAYLOAD
sent = 0
while time.monotonic() < end:
    try:
        ws = opened()
        if kind == "big":  # one masked binary frame, its mask all zeros: no work to build
            ws.socket.sendall(BIG)
            drain(ws, "after")  # the relay ends the connection first
        elif kind == "deep":
            ws.send("[" * 100_000)
            ws.send(b"\x01" + (1).to_bytes(4, "little") + b"[" * 4000)
            ws.send(b"\x01" + (1).to_bytes(4, "little") + b'{"":' * 1020)
            drain(ws, "deep")
        elif kind == "values":
            ws.send(json.dumps({"op": "setParameters", "id": "v", "parameters": [
                {"name": "chassis.max_speed", "value": "9" * 60_000}]}))
            ws.send(json.dumps({"op": "setParameters", "id": "n", "parameters": [
                {"name": "chassis." + "x" * 60_000, "value": 1.0}]}))
            drain(ws, "values")
        elif kind == "invalid":
            for batch in range(25):
                for i in range(100):
                    ws.send("{not json")
                    ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                        {"id": batch * 100 + i + 1, "channelId": 99999}]}))
                drain(ws, f"b{batch}")
        sent += 1
        ws.close()
    except Exception:
        sent += 1
        time.sleep(0.05)
print(sent)
'''

# A witness in a process of its own: its longest gap between 10 ms sleeps is the
# machine's (a loaded machine stalls every process), not the live view's.
WITNESS = r'''
import sys, time
end = time.monotonic() + float(sys.argv[1])
last, worst = time.monotonic(), 0.0
while (now := time.monotonic()) < end:
    worst = max(worst, now - last)
    last = now
    time.sleep(0.01)
print(round(1e3 * (worst - 0.01), 2))
'''

KINDS = ("quiet", "big", "deep", "values", "invalid")


def rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def one_run(rate_hz: float, seconds: float, kind: str) -> dict[str, Any]:
    cfg = config(rate_hz)
    settings = FoxgloveSettings(port=0, control=True, token=TOKEN)
    with SimulatedBase.from_config(cfg) as sim, Chassis.open(cfg) as base, \
            contextlib.ExitStack() as stack:
        runner = base._runner
        starts = cycle_starts(base)
        add_truth(base, sim)  # as a command's session does
        view = stack.enter_context(watch(base, sim, settings))
        assert view is not None
        time.sleep(1.0)  # set-up done
        rss0 = rss_mb()
        abuser = None
        if kind != "quiet":
            abuser = subprocess.Popen(
                [sys.executable, "-c", ABUSER, f"{view.url}/?token={TOKEN}", kind,
                 str(seconds)], stdout=subprocess.PIPE, text=True)
        witness = subprocess.Popen([sys.executable, "-c", WITNESS, str(seconds)],
                                   stdout=subprocess.PIPE, text=True)
        starts.clear()
        late0, cycles0 = runner.late, base.status.cycles
        t0 = time.monotonic()
        while time.monotonic() - t0 < seconds:
            base.set_velocity(0.3, 0.1, 0.2)
            time.sleep(0.02)
        elapsed = time.monotonic() - t0
        rounds = None
        if abuser is not None:
            out, _ = abuser.communicate(timeout=120)
            rounds = int(out.strip() or 0)
        witness_gap = float(witness.communicate(timeout=60)[0].strip() or "nan")
        cycles = base.status.cycles - cycles0
        late = runner.late - late0
        gaps = sorted(b - a for a, b in itertools.pairwise(starts))
        return dict(bench="foxglove_abuse", kind=kind, rate_hz=rate_hz,
                    seconds=round(elapsed, 2), cycles=cycles, abuse_rounds=rounds,
                    late_fraction=round(late / max(cycles, 1), 4),
                    longest_gap_ms=round(1e3 * gaps[-1], 2) if gaps else None,
                    p99_gap_ms=round(1e3 * gaps[int(0.99 * (len(gaps) - 1))], 2)
                    if gaps else None,
                    rss_growth_mb=round(rss_mb() - rss0, 1),
                    witness_longest_gap_ms=witness_gap)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rate", type=float, default=100.0)
    parser.add_argument("--seconds", type=float, default=8.0)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--kinds", default=",".join(KINDS),
                        help=f"which abuse, comma-separated (of {', '.join(KINDS)})")
    args = parser.parse_args()
    kinds = [k for k in args.kinds.split(",") if k]
    if "quiet" not in kinds:
        kinds.insert(0, "quiet")
    runs: dict[str, list[dict[str, Any]]] = {k: [] for k in kinds}
    for _ in range(args.rounds):
        for kind in kinds:
            run = one_run(args.rate, args.seconds, kind)
            runs[kind].append(run)
            emit(**run)
    def gaps(kind: str) -> list[float]:
        return [float(r["longest_gap_ms"] or 0.0) for r in runs[kind]]

    quiet, quiet_median = max(gaps("quiet")), statistics.median(gaps("quiet"))
    for kind in kinds:
        worst, median = max(gaps(kind)), statistics.median(gaps(kind))
        emit(bench="foxglove_abuse.summary", kind=kind, longest_gap_ms=worst,
             longest_gap_ratio=round(worst / quiet, 2) if quiet else None,
             median_longest_gap_ms=round(median, 2),
             median_ratio=round(median / quiet_median, 2) if quiet_median else None,
             p99_gap_ms=max(float(r["p99_gap_ms"] or 0.0) for r in runs[kind]),
             rss_growth_mb=max(float(r["rss_growth_mb"]) for r in runs[kind]),
             witness_longest_gap_ms=max(float(r["witness_longest_gap_ms"])
                                        for r in runs[kind]))


if __name__ == "__main__":
    main()
