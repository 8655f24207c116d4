"""omnican sim: serve simulated drives for another program.

By default the drives sit behind a loopback-only hub, and a second terminal drives
them with:

    omnican teleop -i remote -c ws://127.0.0.1:54701/

On Linux they can also sit on a SocketCAN interface (-i socketcan -c vcan0),
where any CAN tool sees them. Commands typed on stdin inject faults while it runs
(listed below). A port already in use is a run-time failure (exit 1).
"""

from __future__ import annotations

import argparse
import ipaddress
import uuid
from collections.abc import Mapping
from typing import Any

from omnican.cli.common import (
    UsageError,
    add_config_argument,
    bus_overrides,
    check_bus,
    finite_float,
    load,
    pose_line,
    positive_float,
    serve_lines,
)
from omnican.hub import DEFAULT_PORT, LoopbackHub
from omnican.live import foxglove_address, prepare, watch
from omnican.sim import SimulatedBase, SimulatedDrive


def add_subparser(sub: Any) -> None:
    import can.cli

    p = sub.add_parser("sim", help="serve simulated drives to another process",
                       description=f"{__doc__}\ncommands:\n{commands_help()}\n",
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    add_config_argument(p)
    p.add_argument("--serve", metavar="[HOST:]PORT", default=None,
                   help=f"loopback hub address (default 127.0.0.1:{DEFAULT_PORT}; loopback only)")
    p.add_argument("--duration", type=positive_float, metavar="S",
                   help="stop after S seconds (default: until Ctrl-C or 'quit')")
    p.add_argument("--encoder-noise", type=finite_float, default=0.0, metavar="COUNTS",
                   help="standard deviation added to reported positions (default 0)")
    p.add_argument("--frame-loss", type=finite_float, default=0.0, metavar="P",
                   help="probability 0-1 of losing each PDO/heartbeat frame (default 0)")
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
    host = host.strip("[]") or "127.0.0.1"
    try:
        address = ipaddress.ip_address(host)
    except ValueError:
        return host, number  # a name: the hub resolves it and checks every address
    if address.is_unspecified:
        raise UsageError(f"--serve {text}: the hub serves loopback only, and {host} is every "
                         "interface (use 127.0.0.1)")
    if not address.is_loopback:
        raise UsageError(f"--serve {text}: the hub serves loopback only, and {host} is not a "
                         "loopback address (use 127.0.0.1)")
    return host, number


# The console's commands: (syntax, what it does), for the banner and 'help'.
COMMANDS = (
    ("fault NODE [CODE]", "EMCY + FAULT (default 0x2310 continuous over-current)"),
    ("reboot NODE", "boot-up, defaults restored, position counter reset"),
    ("heartbeat NODE off|on", "stop or restart the node's heartbeat"),
    ("freeze NODE", "answer nothing, send nothing (a hung node)"),
    ("thaw NODE", "back to normal after freeze"),
    ("pose", "print the ground-truth pose"),
    ("help", "list the commands"),
    ("quit", "stop the simulator"),
)
_NODE_VERBS = ("fault", "reboot", "heartbeat", "freeze", "thaw")


def commands_help() -> str:
    width = max(len(syntax) for syntax, _ in COMMANDS)
    return "\n".join(f"{syntax:<{width}}  {what}" for syntax, what in COMMANDS)


def _nodes(sim: SimulatedBase) -> str:
    return ", ".join(str(d.node_id) for d in sim.drives)


def drive_for(sim: SimulatedBase, word: str) -> SimulatedDrive:
    try:
        node = int(word, 0)
    except ValueError:
        raise ValueError(f"not a node id: {word!r} (nodes: {_nodes(sim)})") from None
    for d in sim.drives:
        if d.node_id == node:
            return d
    raise ValueError(f"no simulated node {node} (nodes: {_nodes(sim)})")


def parse_emcy_code(word: str) -> int:
    try:
        code = int(word, 0)
    except ValueError:
        raise ValueError(f"not an emergency code: {word!r} (e.g. 0x2310)") from None
    if not 0 < code <= 0xFFFF:
        raise ValueError(f"an emergency code is 0x0001-0xFFFF, got {word!r}")
    return code


def command(sim: SimulatedBase, line: str) -> str | None:
    """Apply one console command; returns the reply ('error: ...' for a command it does
    not understand, which then does nothing), or None to quit."""
    words = line.split()
    if not words:
        return ""
    verb, rest = words[0].lower(), words[1:]
    try:
        if verb in ("quit", "exit"):
            return None
        if verb == "help":
            return commands_help()
        if verb == "pose":
            return "true " + pose_line(sim.true_pose)
        if verb not in _NODE_VERBS:
            raise ValueError(f"unknown command {words[0]!r} (try 'help')")
        if verb == "heartbeat" and len(rest) != 2:
            raise ValueError("heartbeat takes a node id and on or off")
        if not rest:
            raise ValueError(f"{verb} needs a node id (nodes: {_nodes(sim)})")
        drive = drive_for(sim, rest[0])
        if verb == "fault":
            if len(rest) > 2:
                raise ValueError("fault takes a node id and an optional code")
            code = parse_emcy_code(rest[1]) if len(rest) > 1 else 0x2310
            drive.inject_fault(code)
            return f"node {drive.node_id}: fault 0x{code:04X}"
        if verb == "heartbeat":
            state = rest[1].lower()
            if state not in ("on", "off"):
                raise ValueError(f"heartbeat takes on or off, not {rest[1]!r}")
            (drive.start_heartbeat if state == "on" else drive.stop_heartbeat)()
            return f"node {drive.node_id}: heartbeat {state}"
        if len(rest) > 1:
            raise ValueError(f"{verb} takes only a node id")
        if verb == "reboot":
            drive.reboot()
            return f"node {drive.node_id}: rebooted"
        if verb == "freeze":
            drive.freeze()
            return f"node {drive.node_id}: frozen"
        drive.thaw()
        return f"node {drive.node_id}: thawed"
    except ValueError as exc:
        return f"error: {exc}"


def run(args: argparse.Namespace) -> int:
    cfg = load(args)
    on_bus = bool(bus_overrides(args))
    if on_bus and args.serve:
        raise UsageError("give either --serve (a loopback hub) or bus arguments, not both")
    if args.encoder_noise < 0:
        raise UsageError(f"--encoder-noise must be 0 or more, got {args.encoder_noise:g}")
    if not 0 <= args.frame_loss <= 1:
        raise UsageError(f"--frame-loss must be 0-1, got {args.frame_loss:g}")
    options = {"encoder_noise": args.encoder_noise, "frame_loss": args.frame_loss}
    hub = None
    if on_bus:
        check_bus(cfg.bus)
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
        if args.foxglove is not None:
            prepare(cfg)  # its slow set-up before the simulated drives run
        with SimulatedBase.from_config(cfg, **options) as sim:
            nodes = ", ".join(f"{d.node_id} ({d.eds.name})" for d in sim.drives)
            print(f"serving simulated nodes {nodes} on {where}", flush=True)
            print(f"connect with: {connect}", flush=True)
            if args.config:
                print(f"  (add --config {args.config} to use the same config)", flush=True)
            print("type a command here: " + ", ".join(syntax for syntax, _ in COMMANDS),
                  flush=True)
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
    serve_lines(lambda line: command(sim, line), duration)

