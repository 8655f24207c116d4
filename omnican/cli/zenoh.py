"""omnican zenoh: the base on Zenoh, in rmw_zenoh's format, with nothing else on.

A ROS 2 node on rmw_zenoh_cpp (or any peer speaking its format) sees the base as a node:
it publishes odom, tf, joint_states, diagnostics and battery_state, takes cmd_vel
(geometry_msgs/Twist, or TwistStamped with --cmd-vel-stamped; one publisher at a time;
the base stops when cmd_vel stops) and answers ~/stop, ~/recover and ~/reset_odometry
(std_srvs/Trigger).
Multicast scouting is off unless --zenoh-multicast: point it at a router
(--zenoh-connect tcp/HOST:7447, rmw_zenoh's default port). It listens on loopback
unless told (--zenoh-listen); beyond loopback it needs credentials (--zenoh-credentials
DIR --zenoh-identity base/NAME, made by 'omnican zenoh credentials': mutual TLS, and only
operators drive) or --zenoh-allow-insecure. The [zenoh] table of --config says all of
this too; the flags win over it. Needs eclipse-zenoh (the zenoh extra). teleop, drive,
ros2 and sim take --zenoh to run the same beside what they do.
"""

from __future__ import annotations

import argparse
import contextlib
from collections.abc import Callable, Iterator, Mapping
from dataclasses import replace
from typing import TYPE_CHECKING, Any

from omnican.cli.common import (
    EXIT_OK,
    UsageError,
    add_bus_arguments,
    load,
    positive_float,
    serve_lines,
    session,
)
from omnican.config import ZENOH_MODES, ZENOH_SECURITY
from omnican.errors import ConfigError

if TYPE_CHECKING:
    from omnican.chassis import Chassis
    from omnican.config import ChassisConfig
    from omnican.zenoh.settings import ZenohSettings


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
    from omnican.cli import zenoh_credentials

    more = p.add_subparsers(title="subcommand (instead of running the base)",
                            metavar="credentials", parser_class=type(p))
    zenoh_credentials.add_subparser(more)


CONSOLE_SOURCE = "omnican zenoh's console"  # what the other sources are told of it
ZENOH_HELP = ("also put the base on Zenoh, in rmw_zenoh's format (as omnican zenoh does: "
              "odom, tf, joint_states, diagnostics, battery_state out, cmd_vel in through "
              "the one arbiter, ~/stop, ~/recover, ~/reset_odometry); the [zenoh] table of "
              "the config configures it, the flags win over it; --no-zenoh keeps the "
              "table's enabled = true off; needs the zenoh extra")


def add_zenoh_arguments(parser: argparse.ArgumentParser, graph: bool = True,
                        commands: bool = True, what: str = ZENOH_HELP) -> None:
    """``--zenoh`` (and ``--no-zenoh``) for a command that runs something else too, with
    the network flags and, unless the command has its own (``omnican ros2``: one ROS
    graph serves both), the graph flags."""
    parser.add_argument("--zenoh", action=argparse.BooleanOptionalAction, default=None,
                        help=what)
    if graph:
        add_graph_arguments(parser, commands, title="Zenoh: the ROS 2 graph "
                            "(override [zenoh] of the config)")
    add_network_arguments(parser)


def add_graph_arguments(parser: argparse.ArgumentParser, commands: bool = True,
                        title: str = "ROS 2 graph (override [zenoh] of the config)") -> None:
    """Where the base sits in the ROS 2 graph: --namespace, --node-name, --domain-id,
    --cmd-vel-stamped (``commands``). Not given: the [zenoh] table's, else its defaults."""
    node = parser.add_argument_group(title)
    node.add_argument("--namespace", metavar="NS",
                      help="the robot's namespace, e.g. /robot1 (default none)")
    node.add_argument("--node-name", metavar="NAME",
                      help="node name (default omnican" + ("" if commands else
                                                           "; the simulator's: NAME_sim")
                      + ")")
    node.add_argument("--domain-id", type=int, metavar="N",
                      help="ROS domain 0-232: the first chunk of every key (default 0)")
    if commands:
        node.add_argument("--cmd-vel-stamped", action="store_true", default=None,
                          help="cmd_vel carries geometry_msgs/TwistStamped")


def add_network_arguments(parser: argparse.ArgumentParser) -> None:
    """How a Zenoh session connects: --zenoh-connect, --zenoh-listen, --zenoh-mode,
    --zenoh-multicast, --zenoh-config (the base's front end and ``omnican fleet`` alike).
    Not given: the [zenoh] table's, else its defaults."""
    net = parser.add_argument_group("Zenoh network (override [zenoh] of the config)")
    net.add_argument("--zenoh-connect", action="append", default=[], metavar="ENDPOINT",
                     help="connect to a router or peer, e.g. tcp/127.0.0.1:7447 (repeatable)")
    net.add_argument("--zenoh-listen", action="append", default=[], metavar="ENDPOINT",
                     help="listen on ENDPOINT, e.g. tcp/127.0.0.1:0 (repeatable)")
    net.add_argument("--zenoh-mode", choices=ZENOH_MODES, default=None,
                     help="a peer (default) or a client of the router")
    net.add_argument("--zenoh-multicast", action=argparse.BooleanOptionalAction,
                     default=None, help="find peers by multicast scouting (default off)")
    net.add_argument("--zenoh-config", metavar="FILE",
                     help="a Zenoh JSON5 config (TLS, authentication, access control), "
                          "applied before the flags")
    net.add_argument("--zenoh-credentials", metavar="DIR",
                     help="the fleet's credentials ('omnican zenoh credentials' made them): "
                          "mutual TLS, and a base's or router's access control")
    net.add_argument("--zenoh-identity", metavar="ROLE/NAME",
                     help="whose credentials: base/NAME (runs under /NAME), operator/NAME, "
                          "viewer/NAME, router/NAME")
    net.add_argument("--zenoh-security", choices=ZENOH_SECURITY, default=None,
                     help="mtls (the default with --zenoh-credentials) or none")
    net.add_argument("--zenoh-allow-insecure", action="store_true", default=None,
                     help="listen beyond loopback without credentials: anyone who reaches "
                          "it could drive the robot")


#: flag (argparse's name) -> the ZenohSettings field it sets.
_FLAGS = {"domain_id": "domain_id", "namespace": "namespace", "node_name": "node_name",
          "cmd_vel_stamped": "cmd_vel_stamped", "zenoh_mode": "mode",
          "zenoh_multicast": "multicast", "zenoh_config": "config_file",
          "zenoh_credentials": "credentials", "zenoh_identity": "identity",
          "zenoh_security": "security", "zenoh_allow_insecure": "allow_insecure"}
_NETWORK = ("zenoh_connect", "zenoh_listen", "zenoh_mode", "zenoh_multicast", "zenoh_config",
            "zenoh_credentials", "zenoh_identity", "zenoh_security", "zenoh_allow_insecure")


def settings_from(args: argparse.Namespace, cfg: ChassisConfig | None = None,
                  graph: Mapping[str, Any] | None = None) -> ZenohSettings:
    """The Zenoh settings: the flags given, then the config's [zenoh] table, then
    ``graph`` (``omnican ros2``'s node: namespace, node name, domain, cmd_vel type),
    then the defaults; validated (ConfigError naming the file or the command line)."""
    from omnican.zenoh.settings import checked, from_table

    origin = str(cfg.source) if cfg is not None and cfg.source else "config"
    s = from_table(cfg.zenoh if cfg is not None else None, origin, graph)
    changes: dict[str, Any] = {}
    for flag, key in _FLAGS.items():
        value = getattr(args, flag, None)
        if value is not None:
            changes[key] = value
    for flag, key in (("zenoh_connect", "connect"), ("zenoh_listen", "listen")):
        if getattr(args, flag, None):
            changes[key] = tuple(getattr(args, flag))
    return checked(s, "command line", **changes)


def front_end_settings(args: argparse.Namespace, cfg: ChassisConfig,
                       graph: Mapping[str, Any] | None = None) -> ZenohSettings | None:
    """The Zenoh front end's settings when the command is to run one (``--zenoh``, a
    ``--zenoh-*`` flag, or ``[zenoh] enabled = true`` without ``--no-zenoh``), else None.
    Checked before any drive comes up: a missing extra, a bad value or a Zenoh config
    file that is not there is one line (UsageError, ConfigError)."""
    network = [f"--{flag.replace('_', '-')}" for flag in _NETWORK if getattr(args, flag, None)]
    asked = getattr(args, "zenoh", None)
    if asked is False and network:
        raise UsageError(f"{network[0]} is for the Zenoh front end: drop --no-zenoh")
    table = cfg.zenoh.enabled if cfg.zenoh is not None else False
    if not (asked or network or (asked is None and table)):
        return None
    from omnican.extras import needs

    why = needs("zenoh", "--zenoh")
    if why is not None:
        raise UsageError(why)
    settings = settings_from(args, cfg, graph)
    preflight(settings)
    return settings


def preflight(settings: ZenohSettings, base: bool = True) -> None:
    """What opening the session would refuse, refused now, before any drive comes up: a
    Zenoh config or credentials that are not there (named), credentials not a base's
    (``base``: the session is a base's) or not its namespace's, a session that would
    listen beyond loopback without credentials. ConfigError, one line."""
    from omnican.zenoh.bridge import session_config
    from omnican.zenoh.settings import base_problem

    problem = base_problem(settings) if base else None
    if problem is not None:
        raise ConfigError(problem)
    session_config(settings)


@contextlib.contextmanager
def zenoh_front_end(settings: ZenohSettings | None, base: Chassis, sim: Any = None,
                    announce: Callable[[str], None] | None = None) -> Iterator[Any]:
    """The base on Zenoh while the block runs (yields the
    :class:`~omnican.zenoh.bridge.ZenohBridge`; None and nothing done without
    ``settings``): a session opened as the settings say, the bridge on it (``sim``: the
    simulator's true pose goes along), its one startup line to ``announce``; the bridge,
    then the session closed at the end."""
    if settings is None:
        yield None
        return
    from omnican.zenoh.bridge import ZenohBridge, open_session

    with contextlib.closing(open_session(settings)) as session, \
            ZenohBridge(base, settings, session, sim=sim) as bridge:
        if announce is not None:
            out = ", ".join(pub.name for pub in bridge.publishers.values())
            announce(f"{node_line(bridge)}: in {bridge.cmd_topic}; out {out}")
        yield bridge


@contextlib.contextmanager
def zenoh_truth(settings: ZenohSettings | None, sim: Any,
                announce: Callable[[str], None] | None = None) -> Iterator[Any]:
    """``omnican sim --zenoh``: the simulator's true pose on Zenoh, from the node
    ``<node name>_sim``, while the block runs (None and nothing done without
    ``settings``); its one startup line to ``announce``."""
    if settings is None:
        yield None
        return
    from omnican.zenoh.bridge import open_session
    from omnican.zenoh.simulator import publish_truth

    settings = replace(settings, node_name=f"{settings.node_name}_sim")
    with contextlib.closing(open_session(settings)) as session, \
            publish_truth(sim, settings, session) as truth:
        if announce is not None:
            announce(f"{node_line(truth)}: out {truth.publisher.name} "
                     f"{truth.rate_hz:g} Hz")
        yield truth


def node_line(front: Any) -> str:
    """``Zenoh node /robot1/omnican on domain 0 (session ..., peer; connect: ...;
    multicast off)``: the first line a Zenoh front end says."""
    s = front.settings
    node = s.node_fq_name
    where = ", ".join(s.connect) or "no router given"
    who = s.who
    secured = f"mTLS as {who}" if who is not None else "no credentials"
    return (f"Zenoh node {node} on domain {s.domain_id} (session {front.node.session_id}, "
            f"{s.mode}; connect: {where}; multicast {'on' if s.multicast else 'off'}; "
            f"{secured})")


def run(args: argparse.Namespace) -> int:
    from omnican.extras import needs

    why = needs("zenoh", "'zenoh'")
    if why is not None:
        raise UsageError(why)
    from omnican.chassis import Chassis

    settings = settings_from(args, load(args))
    preflight(settings)
    with session(args) as sess, Chassis.open(sess.cfg) as base, \
            zenoh_front_end(settings, base, sess.sim) as bridge:
        _print_startup(bridge, base.cfg.chassis.cmd_timeout_s)
        try:
            serve_lines(lambda line: _command(bridge, sess.sim, line), args.duration)
        finally:
            bridge.close()
            _print_summary(bridge)
    print("drives disabled", flush=True)
    return EXIT_OK


def _print_startup(bridge: Any, timeout_s: float) -> None:
    from omnican.zenoh.services import SERVICES

    node = bridge.settings.node_fq_name
    print(node_line(bridge), flush=True)
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
    def recover() -> str:  # as any other source: refused while another drives
        answer = bridge.base.command_source(CONSOLE_SOURCE).recover()
        if answer.refused_by is not None:
            return f"recover refused: {answer.refused_by} is driving the base"
        return "recovered" if answer.failed is None else f"recover failed: {answer.failed}"

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
