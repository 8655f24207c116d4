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
from pathlib import Path
from typing import Any

from omnican.cli.common import EXIT_OK, UsageError, positive_float, positive_int
from omnican.cli.console import serve_lines
from omnican.cli.session import add_bus_arguments, load, session
from omnican.zenoh.arguments import (
    add_graph_arguments,
    add_network_arguments,
    preflight,
    settings_from,
)
from omnican.zenoh.front_end import node_line, zenoh_front_end


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
    more = p.add_subparsers(title="subcommand (instead of running the base)",
                            metavar="credentials", parser_class=type(p))
    add_credentials_subparser(more)


CONSOLE_SOURCE = "omnican zenoh's console"  # what the other sources are told of it


def run(args: argparse.Namespace) -> int:
    from omnican.extras import needs

    why = needs("zenoh", "'zenoh'")
    if why is not None:
        raise UsageError(why)
    settings = settings_from(args, load(args))
    preflight(settings)
    with session(args) as sess, sess.open_base() as base, \
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


# ------------------------------------------------------------ credentials

CREDENTIALS_HELP = """\
omnican zenoh credentials: a fleet's certificates and Zenoh configs, in one folder.

Makes a certificate authority (CA) and, for each member named, a certificate and key
(its common name the name) and its Zenoh config, in three roles and the routers:

  base      publishes its telemetry and serves its services under /NAME; takes cmd_vel,
            ~/recover and its other services from operators only, ~/stop from viewers too
  operator  may drive, stop and recover every base
  viewer    reads everything, and may call ~/stop (a stop is not a command)
  router    passes on what each may send (a fleet without one gets 'router')

Every link is mutual TLS with the CA's certificates; the bases and routers enforce the
roles (Zenoh's access control, default deny). Run it again on the same folder to add
members (--remove takes one out): the CA and the certificates already made are kept, and
every base's and router's zenoh.json5 is written anew (copy them over and restart).
Use them with --zenoh-credentials DIR --zenoh-identity ROLE/NAME. Needs cryptography
(the zenoh-security extra) on this machine only.
"""

#: (flag, role) in the order they are told.
_ROLE_FLAGS = (("router", "router"), ("base", "base"), ("operator", "operator"),
               ("viewer", "viewer"))
DEFAULT_ROUTER = "router"


def add_credentials_subparser(sub: Any) -> None:
    p = sub.add_parser("credentials", help="make a fleet's certificates and Zenoh configs "
                       "(bases, operators, viewers)", description=CREDENTIALS_HELP,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("folder", metavar="DIR", type=Path,
                   help="the folder to make (or to add members to)")
    p.add_argument("--base", action="append", default=[], metavar="NAME",
                   help="a base; it runs under the namespace /NAME (repeatable)")
    p.add_argument("--operator", action="append", default=[], metavar="NAME",
                   help="an operator: may drive, stop and recover (repeatable)")
    p.add_argument("--viewer", action="append", default=[], metavar="NAME",
                   help="a viewer: reads, and may stop (repeatable)")
    p.add_argument("--router", action="append", default=[], metavar="NAME",
                   help=f"a router (repeatable; default one called {DEFAULT_ROUTER!r})")
    p.add_argument("--remove", action="append", default=[], metavar="NAME",
                   help="take a member out: no base or router lets its certificate do "
                        "anything any more (repeatable)")
    p.add_argument("--domain-id", type=int, metavar="N",
                   help="ROS domain 0-232 of the fleet's keys (default 0; kept from then on)")
    p.add_argument("--days", type=positive_int, default=730, metavar="N",
                   help="how long a member's certificate is valid (default 730)")
    p.add_argument("--installed-at", type=Path, metavar="PATH",
                   help="where the folder will be on the members' machines: the paths "
                        "zenohd or rmw_zenoh read in the configs (default DIR; omnican "
                        "finds the files itself)")
    p.set_defaults(func=run_credentials)


def run_credentials(args: argparse.Namespace) -> int:
    from omnican.extras import needs

    why = needs("zenoh-security", "'zenoh credentials'")
    if why is not None:
        raise UsageError(why)
    from omnican.zenoh.credentials import make, read_roster
    from omnican.zenoh.security import Identity, check_name

    if args.domain_id is not None and not 0 <= args.domain_id <= 232:
        raise UsageError(f"--domain-id {args.domain_id}: not 0..232")
    add: list[Identity] = []
    for flag, role in _ROLE_FLAGS:
        for name in getattr(args, flag):
            try:
                add.append(Identity(role, check_name(role, name)))
            except ValueError as exc:
                raise UsageError(f"--{flag} {name}: {exc}") from None
    root: Path = args.folder
    before = read_roster(root.expanduser().resolve()) if root.exists() else None
    if before is None and not add:
        raise UsageError("name the members: --base NAME, --operator NAME, --viewer NAME")
    has_router = any(w.role == "router" for w in add) or (
        before is not None and before.names("router"))
    if not has_router:
        add.insert(0, Identity("router", DEFAULT_ROUTER))
    report = make(root, add, domain_id=args.domain_id, remove=tuple(args.remove),
                  days=args.days, installed_at=args.installed_at,
                  say=lambda line: print(line, flush=True))
    roster = report.roster
    counts = ", ".join(f"{len(roster.names(role))} {role}{'s' * (len(roster.names(role)) != 1)}"
                       for role in ("router", "base", "operator", "viewer"))
    loaded = _check_loads(report)
    print(f"fleet of domain {roster.domain_id} in {report.root}: {counts} (made "
          f"{len(report.made)}, kept {len(report.kept)}); {loaded}", flush=True)
    changed = report.made or report.removed
    if before is not None and changed and (before.names("base") or before.names("router")):
        print("the access control changed: give every base and router its new zenoh.json5 "
              "and restart it", flush=True)
    _print_use(report.root, roster)
    return EXIT_OK


def _check_loads(report: Any) -> str:
    """Every member's zenoh.json5 read back by Zenoh (when it is installed here)."""
    from omnican.extras import missing
    from omnican.zenoh.credentials import Files

    if missing("zenoh") is not None:
        return "Zenoh is not installed here to read them back"
    import zenoh

    from omnican.errors import ConfigError
    from omnican.zenoh.bridge import zenoh_words

    for who in report.roster.identities():
        path = Files.of(report.root, who).config
        try:
            zenoh.Config.from_file(str(path))
        except zenoh.ZError as exc:
            raise ConfigError(f"{path}: Zenoh cannot read it: {zenoh_words(exc)}") from None
    return "every zenoh.json5 reads in Zenoh"


def _print_use(root: Path, roster: Any) -> None:
    """How each role uses its folder (one line per role the fleet has)."""
    creds = f"--zenoh-credentials {root}"
    uses = {
        "router": (f"omnican fleet --router {creds} --zenoh-identity router/NAME "
                   "--zenoh-listen tls/0.0.0.0:7447  (or zenohd -c "
                   f"{root}/router/NAME/zenoh.json5)"),
        "base": (f"omnican zenoh {creds} --zenoh-identity base/NAME --namespace /NAME "
                 "--zenoh-connect tls/ROUTER:7447"),
        "operator": (f"omnican fleet {creds} --zenoh-identity operator/NAME "
                     "--zenoh-connect tls/ROUTER:7447"),
        "viewer": (f"omnican fleet {creds} --zenoh-identity viewer/NAME "
                   "--zenoh-connect tls/ROUTER:7447"),
    }
    print(f"each machine needs {root}/ca.pem and its own ROLE/NAME folder (never ca.key); "
          "then:", flush=True)
    for role in ("router", "base", "operator", "viewer"):
        if roster.names(role):
            print(f"  {role + ':':<9} {uses[role]}", flush=True)
