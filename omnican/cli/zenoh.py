"""omnican zenoh: the base on Zenoh, in rmw_zenoh's format, with nothing else on.

A ROS 2 node on rmw_zenoh_cpp (or any peer speaking its format) sees the base as a node:
it publishes odom, tf, joint_states, diagnostics and battery_state, takes cmd_vel
(geometry_msgs/Twist, or TwistStamped with --cmd-vel-stamped; one publisher at a time;
the base stops when cmd_vel stops) and answers ~/stop, ~/recover and ~/reset_odometry
(std_srvs/Trigger).
Multicast scouting is off unless --zenoh-multicast: point it at a router
(--zenoh-connect tcp/HOST:7447, rmw_zenoh's default port). Needs eclipse-zenoh (the
zenoh extra).
"""

from __future__ import annotations

import argparse
from typing import Any

from omnican.cli.common import (
    EXIT_OK,
    UsageError,
    add_bus_arguments,
    positive_float,
    serve_lines,
    session,
)


def add_subparser(sub: Any) -> None:
    p = sub.add_parser("zenoh", help="run the base on Zenoh (rmw_zenoh's format)",
                       description=__doc__,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    add_graph_arguments(p)
    add_network_arguments(p)
    p.add_argument("--duration", type=positive_float, metavar="S",
                   help="stop after S seconds (default: until Ctrl-C or 'quit')")
    add_bus_arguments(p, sim_help="run against simulated drives in this process")
    p.set_defaults(func=run)


def add_graph_arguments(parser: argparse.ArgumentParser) -> None:
    """Where the base sits in the ROS 2 graph: --namespace, --node-name, --domain-id,
    --cmd-vel-stamped."""
    node = parser.add_argument_group("ROS 2 graph")
    node.add_argument("--namespace", metavar="NS", default="",
                      help="the robot's namespace, e.g. /robot1")
    node.add_argument("--node-name", metavar="NAME", default="omnican",
                      help="node name (default omnican)")
    node.add_argument("--domain-id", type=int, metavar="N", default=0,
                      help="ROS domain 0-232: the first chunk of every key (default 0)")
    node.add_argument("--cmd-vel-stamped", action="store_true",
                      help="cmd_vel carries geometry_msgs/TwistStamped")


def add_network_arguments(parser: argparse.ArgumentParser) -> None:
    """How a Zenoh session connects: --zenoh-connect, --zenoh-listen, --zenoh-mode,
    --zenoh-multicast, --zenoh-config (the base's front end and ``omnican fleet`` alike)."""
    net = parser.add_argument_group("Zenoh network")
    net.add_argument("--zenoh-connect", action="append", default=[], metavar="ENDPOINT",
                     help="connect to a router or peer, e.g. tcp/127.0.0.1:7447 (repeatable)")
    net.add_argument("--zenoh-listen", action="append", default=[], metavar="ENDPOINT",
                     help="listen on ENDPOINT, e.g. tcp/127.0.0.1:0 (repeatable)")
    net.add_argument("--zenoh-mode", choices=("peer", "client"), default="peer",
                     help="a peer (default) or a client of the router")
    net.add_argument("--zenoh-multicast", action="store_true",
                     help="find peers by multicast scouting (off by default)")
    net.add_argument("--zenoh-config", metavar="FILE",
                     help="a Zenoh JSON5 config (TLS, authentication, access control), "
                          "applied before the flags")


def settings_from(args: argparse.Namespace) -> Any:
    from omnican.zenoh.settings import ZenohSettings

    return ZenohSettings(domain_id=args.domain_id, namespace=args.namespace,
                         node_name=args.node_name, mode=args.zenoh_mode,
                         connect=tuple(args.zenoh_connect), listen=tuple(args.zenoh_listen),
                         multicast=args.zenoh_multicast,
                         config_file=args.zenoh_config,
                         cmd_vel_stamped=args.cmd_vel_stamped).validate()


def run(args: argparse.Namespace) -> int:
    from omnican.extras import needs

    why = needs("zenoh", "'zenoh'")
    if why is not None:
        raise UsageError(why)
    from omnican.chassis import Chassis
    from omnican.zenoh.bridge import ZenohBridge, open_session

    settings = settings_from(args)
    with session(args) as sess:
        zsession = open_session(settings)
        try:
            with Chassis.open(sess.cfg) as base, \
                    ZenohBridge(base, settings, zsession) as bridge:
                _print_startup(bridge, base.cfg.chassis.cmd_timeout_s)
                try:
                    serve_lines(lambda line: _command(bridge, sess.sim, line), args.duration)
                finally:
                    bridge.close()
                    _print_summary(bridge)
        finally:
            zsession.close()
    print("drives disabled", flush=True)
    return EXIT_OK


def _print_startup(bridge: Any, timeout_s: float) -> None:
    from omnican.zenoh.services import SERVICES

    s = bridge.settings
    node = s.ros_namespace.rstrip("/") + "/" + s.node_name
    where = ", ".join(s.connect) or "no router given"
    print(f"Zenoh node {node} on domain {s.domain_id} (session {bridge.node.session_id}, "
          f"{s.mode}; connect: {where}; multicast {'on' if s.multicast else 'off'})",
          flush=True)
    kind = bridge.cmd_type.rsplit("/", 1)[1]
    print(f"  in:  {bridge.cmd_topic} ({kind}; one publisher at a time; stop after "
          f"{timeout_s:g} s without)", flush=True)
    print(f"  out: {', '.join(pub.name for pub in bridge.publishers.values())}", flush=True)
    print(f"  services: {', '.join(f'{node}/{name}' for name in SERVICES)} "
          "(std_srvs/Trigger)", flush=True)
    print("Ctrl-C to stop", flush=True)


def _print_summary(bridge: Any) -> None:
    sent = ", ".join(f"{pub.name} {pub.count}" for pub in bridge.publishers.values())
    print(f"published {sent}; received {bridge.cmd_vel_count} cmd_vel "
          f"({bridge.cmd_vel_rejected} refused, {bridge.cmd_vel_refused} ignored: another "
          "publisher drove)", flush=True)
    p = bridge.base.pose
    print(f"pose x={p.x:.4f} y={p.y:.4f} theta={p.theta:.4f}", flush=True)


def _command(bridge: Any, sim: Any, line: str) -> str | None:
    """One stdin line: quit, recover; under --sim omnican sim's console besides."""
    def recover() -> str:
        from omnican.errors import DriveError

        try:
            bridge.base.recover()
        except DriveError as exc:
            return f"recover failed: {exc}"
        return "recovered"

    if sim is not None:
        from omnican.sim import console

        return console.command(sim, line, more={"recover": recover})
    words = line.split()
    if not words:
        return ""
    if words[0].lower() in ("quit", "exit"):
        return None
    if words[0].lower() == "recover":
        return recover()
    return f"error: unknown command {words[0]!r} (recover, quit; more under --sim)"
