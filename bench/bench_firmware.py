"""A program image downloaded to a simulated drive in SDO block mode (CiA 302-3): how
long it took, and the bus load it made.

One simulated drive on a virtual channel, omnican's download (``omnican.drive.program``:
canopen's block transfer, 127 segments a sub-block, CRC-16) of a random image of
``--kib`` KiB, ``--runs`` times. A listener on the channel counts every frame and its
worst-case bits on the wire (bit stuffing included, ``omnican.plan.pdo.frame_bits``).
Prints one JSON object per run: the time, the frames, the bits, the bus load those bits
make in that time at each nominal bitrate (a virtual bus has none: above 100 % the wire
would be the limit), and how long the bits alone take on the wire at that bitrate; then
the medians.

Run: ``python bench/bench_firmware.py`` (``--kib 256 --runs 3``).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import threading
import time
import uuid
from typing import Any

import can
import canopen

from omnican.drive.program import download
from omnican.plan.pdo import frame_bits
from omnican.sim import SimulatedDrive

NODE = 1
BITRATES = (500_000, 1_000_000)


class BitCounter(can.Listener):
    """Every frame on the channel and its worst-case bits."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.frames = 0
        self.bits = 0

    def on_message_received(self, msg: can.Message) -> None:
        with self.lock:
            self.frames += 1
            self.bits += frame_bits(len(msg.data))


def one_run(kib: int) -> dict[str, Any]:
    channel = f"bench-firmware-{uuid.uuid4().hex[:8]}"
    image = os.urandom(kib * 1024)
    sim_net, master = canopen.Network(), canopen.Network()
    sim_net.NOTIFIER_CYCLE = master.NOTIFIER_CYCLE = 0.05
    sim_net.connect(interface="virtual", channel=channel)
    master.connect(interface="virtual", channel=channel)
    counter = BitCounter()
    spy = can.Bus(interface="virtual", channel=channel)
    notifier = can.Notifier(spy, [counter], timeout=0.05)
    drive = SimulatedDrive(sim_net, NODE)
    try:
        start = time.monotonic()
        result = download(master, NODE, image)
        seconds = time.monotonic() - start
        time.sleep(0.2)  # the last answers reach the counter
    finally:
        drive.close()
        notifier.stop()
        spy.shutdown()
        master.disconnect()
        sim_net.disconnect()
    if not result.ok:
        raise SystemExit(f"download failed: {result.line()}")
    row: dict[str, Any] = {"kib": kib, "seconds": round(seconds, 3),
                           "frames": counter.frames, "bits": counter.bits,
                           "payload_bytes_per_s": round(len(image) / seconds)}
    for rate in BITRATES:
        row[f"load_at_{rate // 1000}k"] = round(counter.bits / seconds / rate, 3)
        row[f"wire_s_at_{rate // 1000}k"] = round(counter.bits / rate, 3)
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--kib", type=int, default=256, help="image size in KiB (default 256)")
    parser.add_argument("--runs", type=int, default=3, help="downloads (default 3)")
    args = parser.parse_args()
    rows = []
    for _ in range(args.runs):
        rows.append(one_run(args.kib))
        print(json.dumps(rows[-1]), flush=True)
    median = {key: statistics.median(r[key] for r in rows) for key in rows[0]
              if key != "kib"}
    print(json.dumps({"kib": args.kib, "median": median}))


if __name__ == "__main__":
    main()
