"""``omnican sim``: serve simulated drives for another program.

By default the drives sit behind a loopback-only hub, and a second terminal drives
them with::

    omnican teleop -i remote -c ws://127.0.0.1:54701/

On Linux they can also sit on a SocketCAN interface (``-i socketcan -c vcan0``),
where any CAN tool sees them. Commands on stdin inject faults while it runs:

    fault NODE [CODE]   EMCY + FAULT (default 0x2310 over-current)
    reboot NODE         boot-up, defaults restored, position counter reset
    heartbeat NODE off|on
    freeze NODE / thaw NODE
    pose                print the ground-truth pose
    quit
"""

from __future__ import annotations

import argparse
import select
import sys
import time
import uuid
from collections.abc import Mapping
from typing import Any

from omnican.cli.common import (
    UsageError,
    add_config_argument,
    bus_overrides,
    load,
    positive_float,
)
from omnican.hub import DEFAULT_PORT, LoopbackHub
from omnican.live import foxglove_address, watch
from omnican.sim import SimulatedBase, SimulatedDrive


def add_subparser(sub: Any) -> None:
    import can.cli

    p = sub.add_parser("sim", help="serve simulated drives to another process",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_config_argument(p)
    p.add_argument("--serve", metavar="[HOST:]PORT", default=None,
                   help=f"loopback hub address (default 127.0.0.1:{DEFAULT_PORT}; loopback only)")
    p.add_argument("--duration", type=positive_float, metavar="S",
                   help="stop after S seconds (default: until Ctrl-C or 'quit')")
    p.add_argument("--encoder-noise", type=float, default=0.0, metavar="COUNTS",
                   help="standard deviation added to reported positions")
    p.add_argument("--frame-loss", type=float, default=0.0, metavar="P",
                   help="probability of losing each PDO/heartbeat frame")
    p.add_argument("--foxglove", nargs="?", const="", type=foxglove_address,
                   metavar="[HOST:]PORT", help="serve the ground truth and the bus to Foxglove on "
                   "[HOST:]PORT (default 127.0.0.1:8765; loopback unless a host is given)")
    can.cli.add_bus_arguments(p, group_title="bus arguments (serve on this bus instead of a hub)")
    p.set_defaults(func=run)


def parse_serve(text: str | None) -> tuple[str, int]:
    if not text:
        return "127.0.0.1", DEFAULT_PORT
    host, _, port = text.rpartition(":")
    try:
        number = int(port)
    except ValueError:
        raise UsageError(f"--serve wants [HOST:]PORT, got {text!r}") from None
    if not 0 <= number <= 65535:
        raise UsageError(f"--serve port must be 0-65535, got {number}")
    return host or "127.0.0.1", number


def drive_for(sim: SimulatedBase, word: str) -> SimulatedDrive:
    try:
        node = int(word, 0)
    except ValueError:
        raise ValueError(f"not a node id: {word!r}") from None
    for d in sim.drives:
        if d.node_id == node:
            return d
    raise ValueError(f"no simulated node {node} (nodes: "
                     f"{', '.join(str(d.node_id) for d in sim.drives)})")


def command(sim: SimulatedBase, line: str) -> str | None:
    """Apply one stdin command; returns a reply, or None to quit."""
    words = line.split()
    if not words:
        return ""
    verb, rest = words[0].lower(), words[1:]
    try:
        if verb in ("quit", "exit"):
            return None
        if verb == "pose":
            p = sim.true_pose
            return f"true pose x={p.x:.4f} y={p.y:.4f} theta={p.theta:.4f}"
        if verb == "help":
            return (__doc__ or "").split("stdin inject faults while it runs:")[-1].strip()
        if not rest:
            raise ValueError(f"{verb} needs a node id")
        drive = drive_for(sim, rest[0])
        if verb == "fault":
            code = int(rest[1], 0) if len(rest) > 1 else 0x2310
            drive.inject_fault(code)
            return f"node {drive.node_id}: fault 0x{code:04X}"
        if verb == "reboot":
            drive.reboot()
            return f"node {drive.node_id}: rebooted"
        if verb == "heartbeat":
            on = len(rest) > 1 and rest[1].lower() == "on"
            (drive.start_heartbeat if on else drive.stop_heartbeat)()
            return f"node {drive.node_id}: heartbeat {'on' if on else 'off'}"
        if verb == "freeze":
            drive.freeze()
            return f"node {drive.node_id}: frozen"
        if verb == "thaw":
            drive.thaw()
            return f"node {drive.node_id}: thawed"
        raise ValueError(f"unknown command {verb!r} (try 'help')")
    except (ValueError, IndexError) as exc:
        return f"error: {exc}"


def run(args: argparse.Namespace) -> int:
    cfg = load(args)
    on_bus = bool(bus_overrides(args))
    if on_bus and args.serve:
        raise UsageError("give either --serve (a loopback hub) or bus arguments, not both")
    for name, value in (("--encoder-noise", args.encoder_noise), ("--frame-loss", args.frame_loss)):
        if not value >= 0:
            raise UsageError(f"{name} must be 0 or more, got {value}")
    options = {"encoder_noise": args.encoder_noise, "frame_loss": args.frame_loss}
    hub = None
    if on_bus:
        where = ", ".join(f"{k}={v}" for k, v in (cfg.bus or {}).items())
        connect = f"omnican teleop {' '.join(_bus_flags(cfg.bus or {}))}"
    else:
        host, port = parse_serve(args.serve)
        channel = f"omnican-hub-{uuid.uuid4().hex[:8]}"
        hub = LoopbackHub(channel, host, port)
        cfg = cfg.with_bus(interface="virtual", channel=channel)
        where = hub.url
        connect = f"omnican teleop -i remote -c {hub.url}"
    try:
        with SimulatedBase.from_config(cfg, **options) as sim:
            nodes = ", ".join(f"{d.node_id} ({d.eds.name})" for d in sim.drives)
            print(f"serving simulated nodes {nodes} on {where}", flush=True)
            print(f"connect with: {connect}", flush=True)
            if args.config:
                print(f"  (add --config {args.config} to use the same config)", flush=True)
            with watch(None, sim, args.foxglove, announce=lambda t: print(t, flush=True)):
                serve(sim, args.duration)
    finally:
        if hub is not None:
            hub.close()
    print("simulator stopped", flush=True)
    return 0


def _bus_flags(bus: Mapping[str, Any]) -> list[str]:
    flags = []
    for key, flag in (("interface", "-i"), ("channel", "-c"), ("bitrate", "-b")):
        if key in bus:
            flags += [flag, str(bus[key])]
    return flags


def serve(sim: SimulatedBase, duration: float | None) -> None:
    """Run until the duration ends, stdin says quit (or closes), or Ctrl-C."""
    end = time.monotonic() + duration if duration else None
    stdin_open = True
    try:
        while end is None or time.monotonic() < end:
            timeout = 0.2 if end is None else max(0.0, min(0.2, end - time.monotonic()))
            if not stdin_open:
                time.sleep(timeout)
                continue
            ready, _, _ = select.select([sys.stdin], [], [], timeout)
            if not ready:
                continue
            line = sys.stdin.readline()
            if line == "":
                stdin_open = False  # stdin closed (e.g. < /dev/null): keep serving
                continue
            reply = command(sim, line)
            if reply is None:
                break
            if reply:
                print(reply, flush=True)
    except KeyboardInterrupt:
        pass

