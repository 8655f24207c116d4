"""omnican sim: serve simulated drives for another program.

By default the drives sit behind a loopback-only hub, and a second terminal drives
them with:

    omnican teleop -i remote -c ws://127.0.0.1:54701/

On Linux they can also sit on a SocketCAN interface (-i socketcan -c vcan0),
where any CAN tool sees them. Commands typed on stdin inject faults while it runs
(listed below). A port already in use is a run-time failure (exit 1). --zenoh publishes
the simulated robot's true pose on Zenoh (NS/sim/true_pose), beside what a base that
drives it publishes there.
"""

from __future__ import annotations

import argparse
import ipaddress
import uuid
from collections.abc import Mapping
from typing import Any

from omnican.chassis.realtime import realtime_refusal
from omnican.cli import front_ends
from omnican.cli.common import UsageError, finite_float, positive_float
from omnican.cli.console import serve_lines
from omnican.cli.session import (
    add_config_argument,
    add_python_can_arguments,
    bus_overrides,
    check_bus,
    load,
)
from omnican.io.hub import DEFAULT_PORT, LoopbackHub
from omnican.sim import SimulatedBase
from omnican.sim.console import COMMANDS, command, commands_help


def add_subparser(sub: Any) -> None:
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
    p.add_argument("--unconfigured", action="store_true",
                   help="the drives start without node ids (FFh): silent but for LSS until "
                        "'omnican commission' gives them theirs")
    p.add_argument("--serials", type=_serials, metavar="N,N,...",
                   help="the drives' serial numbers (1018h sub 4), one per node in node "
                        "order (default: the config's [[wheel]] serial, else the node id)")
    p.add_argument("--refuse-store", type=_serials, metavar="NODE,...",
                   help="these nodes' drives refuse LSS 'store configuration' (a failed "
                        "memory)")
    front_ends.add_arguments(p, "sim")
    add_python_can_arguments(p, "bus arguments (serve on this bus instead of a hub)")
    p.set_defaults(func=run)


def _serials(text: str) -> list[int]:
    """argparse type: numbers separated by commas (0x... too)."""
    try:
        values = [int(word, 0) for word in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"want numbers separated by commas, got {text!r}"
                                         ) from None
    if any(not 0 <= v <= 0xFFFFFFFF for v in values):
        raise argparse.ArgumentTypeError(f"a serial number is 0-0xFFFFFFFF, got {text!r}")
    return values


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


def run(args: argparse.Namespace) -> int:
    cfg = load(args)
    on_bus = bool(bus_overrides(args))
    if on_bus and args.serve:
        raise UsageError("give either --serve (a loopback hub) or bus arguments, not both")
    if args.encoder_noise < 0:
        raise UsageError(f"--encoder-noise must be 0 or more, got {args.encoder_noise:g}")
    if not 0 <= args.frame_loss <= 1:
        raise UsageError(f"--frame-loss must be 0-1, got {args.frame_loss:g}")
    options: dict[str, Any] = {"encoder_noise": args.encoder_noise,
                               "frame_loss": args.frame_loss}
    node_ids = sorted(cfg.nodes())
    if args.serials is not None:
        if len(args.serials) != len(node_ids):
            raise UsageError(f"--serials gives {len(args.serials)} serial(s) for "
                             f"{len(node_ids)} node(s) ({', '.join(map(str, node_ids))})")
        # Two drives with one serial are allowed: a maker's mistake 'commission' must name.
        options["serials"] = dict(zip(node_ids, args.serials, strict=True))
    if args.refuse_store is not None:
        unknown = sorted(set(args.refuse_store) - set(node_ids))
        if unknown:
            raise UsageError(f"--refuse-store: no node {unknown[0]} in the config")
        options["refuse_store"] = frozenset(args.refuse_store)
    options["unconfigured"] = args.unconfigured
    running = front_ends.from_args(args, cfg, "sim")
    hub = None
    if on_bus:
        check_bus(cfg.bus)
        where = ", ".join(f"{k}={v}" for k, v in (cfg.bus or {}).items())
        connect = f"omnican teleop {' '.join(_bus_flags(cfg.bus or {}))}"
    else:
        host, port = parse_serve(args.serve)
        channel = f"omnican-hub-{uuid.uuid4().hex[:8]}"
        priority = cfg.chassis.rt_priority  # its relays carry the drives' frames: theirs
        hub = LoopbackHub(channel, host, port, on_thread=(
            (lambda: realtime_refusal(priority)) if priority else None))
        cfg = cfg.with_bus(interface="virtual", channel=channel)
        where = hub.url
        connect = f"omnican teleop -i remote -c {hub.url}"
    try:
        front_ends.prepare(running, cfg)  # their slow set-up before the drives run
        # Its drives keep up with a control loop in another process: at that loop's
        # real-time priority where this process may, else a note on how to get it.
        with SimulatedBase.from_config(cfg, rt_priority=cfg.chassis.rt_priority,
                                       **options) as sim:
            if args.unconfigured:
                serials = ", ".join(f"0x{serial:08X}" for serial, _ in sim.lss.node_ids()) \
                    if sim.lss is not None else ""
                print(f"serving simulated nodes (no node ids yet: serials {serials}) on "
                      f"{where}", flush=True)
            else:
                nodes = ", ".join(f"{d.node_id} ({d.eds.name})" for d in sim.drives)
                print(f"serving simulated nodes {nodes} on {where}", flush=True)
            if sim.realtime_refused is not None:
                print(steadiness_hint(sim.realtime_refused), flush=True)
            if args.unconfigured:
                print("give them their node ids with: "
                      + connect.replace("omnican teleop", "omnican commission CONFIG"),
                      flush=True)
            print(f"connect with: {connect}", flush=True)
            if args.config:
                print(f"  (add --config {args.config} to use the same config)", flush=True)
            print("type a command here: " + ", ".join(syntax for syntax, _ in COMMANDS),
                  flush=True)
            with front_ends.attached(running, None, sim, announce=_say):
                serve(sim, args.duration)
            if hub is not None:  # its clients see the bus go before the drives go quiet
                hub.close()
    finally:
        if hub is not None:
            hub.close()
    print("simulator stopped", flush=True)
    return 0


def steadiness_hint(why: str) -> str:
    """What ``omnican sim`` says when its drives cannot run at real-time priority."""
    return (f"note: simulated drives at normal priority, real-time priority {why}: "
            "beside a busy desktop their heartbeats can come late and stop the base "
            "(--sim in the driving process instead runs them on its control loop)")


def _say(text: str) -> None:
    print(text, flush=True)


def _bus_flags(bus: Mapping[str, Any]) -> list[str]:
    flags = []
    for key, flag in (("interface", "-i"), ("channel", "-c"), ("bitrate", "-b")):
        if key in bus:
            flags += [flag, str(bus[key])]
    return flags


def serve(sim: SimulatedBase, duration: float | None) -> None:
    """Run until the duration ends, stdin says quit (or closes), or Ctrl-C."""
    serve_lines(lambda line: command(sim, line), duration)

