"""The Zenoh front end on the command line: its flags (``--zenoh``, the ROS 2 graph's,
the network's: ``omnican zenoh``, ``omnican fleet`` and every command that runs the front
end beside what it does) and its settings from them and the config's ``[zenoh]`` table
(the flags win), checked before any drive comes up.

No I/O beyond reading a Zenoh config file's name (its presence is checked).
"""

from __future__ import annotations

import argparse
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from omnican.errors import ConfigError
from omnican.zenoh.table import ZENOH_MODES, ZENOH_SECURITY

if TYPE_CHECKING:
    from omnican.config import ChassisConfig
    from omnican.zenoh.settings import ZenohSettings

ZENOH_HELP = ("also put the base on Zenoh, in rmw_zenoh's format (as omnican zenoh does: "
              "odom, tf, joint_states, diagnostics, battery_state out, cmd_vel in through "
              "the one arbiter, ~/stop, ~/recover, ~/reset_odometry); the [zenoh] table of "
              "the config configures it, the flags win over it; --no-zenoh keeps the "
              "table's enabled = true off; needs the zenoh extra")
#: ``--zenoh`` beside a simulator alone (omnican sim).
TRUTH_HELP = ("publish the ground truth on Zenoh in rmw_zenoh's format: NS/sim/true_pose "
              "(geometry_msgs/PoseStamped) at the [zenoh] odom rate, from the node "
              "NAME_sim (omnican_sim); the [zenoh] table of the config configures it, the "
              "flags win over it; --no-zenoh keeps the table's enabled = true off; needs "
              "the zenoh extra")


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
    table = cfg.front_ends.get("zenoh") if cfg is not None else None
    s = from_table(table, origin, graph)  # type: ignore[arg-type]
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
    file that is not there is one line (ConfigError)."""
    network = [f"--{flag.replace('_', '-')}" for flag in _NETWORK if getattr(args, flag, None)]
    asked = getattr(args, "zenoh", None)
    if asked is False and network:
        raise ConfigError(f"{network[0]} is for the Zenoh front end: drop --no-zenoh")
    table = cfg.front_ends.get("zenoh")
    enabled = bool(table.enabled) if table is not None else False  # type: ignore[attr-defined]
    if not (asked or network or (asked is None and enabled)):
        return None
    from omnican.extras import needs

    why = needs("zenoh", "--zenoh")
    if why is not None:
        raise ConfigError(why)
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
