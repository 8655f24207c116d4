"""omnican ros2: the base as a ROS 2 node, over DDS, without a ROS installation.

Subscribes cmd_vel (geometry_msgs/Twist, or TwistStamped; one publisher drives at a
time, the newest of its samples taken up to 100 times a second); publishes odom
(nav_msgs/Odometry), tf (odom -> base_link), joint_states, diagnostics and
battery_state (sensor_msgs/BatteryState); an std_msgs/Empty on ~/recover clears a
latched stop. Needs cyclonedds (the ros2 extra). --zenoh puts the same node on Zenoh
beside it, in rmw_zenoh's format (its namespace, name, domain and cmd_vel type unless
the [zenoh] table says otherwise; the flags below set both).
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Mapping
from dataclasses import replace
from typing import Any

from omnican.cli import front_ends
from omnican.cli.common import EXIT_OK, UsageError, positive_float
from omnican.cli.console import serve_lines
from omnican.cli.session import add_bus_arguments, add_record_argument, load, session
from omnican.errors import ConfigError


def stdin_help() -> str:
    """The lines ros2 takes on stdin: its own, and under --sim every one of omnican sim's
    (made from the console's own list, so that the two never differ)."""
    from omnican.sim.console import commands_help

    sim = "\n".join(f"    {line}" for line in commands_help().splitlines()
                    if not line.startswith("quit"))
    return ("Lines on stdin while it runs:\n\n"
            "    recover  clear a latched stop (as ~/recover does)\n"
            "    quit\n"
            f"  under --sim also (as in omnican sim):\n{sim}\n")


def add_subparser(sub: Any) -> None:
    p = sub.add_parser("ros2", help="run the base as a ROS 2 node (DDS; no ROS install)",
                       description=f"{__doc__}\n{stdin_help()}",
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    node = p.add_argument_group("ROS 2 (override [ros2] of the config)")
    node.add_argument("--namespace", metavar="NS", help="node namespace, e.g. /robot1")
    node.add_argument("--node-name", metavar="NAME", help="node name (default omnican)")
    node.add_argument("--domain-id", type=int, metavar="N",
                      help="DDS domain 0-232 (default: [ros2] domain_id, ROS_DOMAIN_ID, 0)")
    node.add_argument("-r", "--remap", action="append", default=[], metavar="NAME:=TOPIC",
                      help="topic name: cmd_vel, odom, tf, joint_states, diagnostics or "
                           "recover, e.g. -r cmd_vel:=/nav/cmd_vel (repeatable)")
    node.add_argument("--cmd-vel-stamped", action="store_true", default=None,
                      help="cmd_vel carries geometry_msgs/TwistStamped")
    node.add_argument("--cmd-vel-timeout", type=positive_float, metavar="S",
                      help="stop when no cmd_vel arrives for S seconds")
    node.add_argument("--odom-frame", metavar="FRAME",
                      help="frame of the odometry pose (default odom)")
    node.add_argument("--base-frame", metavar="FRAME",
                      help="frame of the base, the odometry's child frame (default base_link)")
    node.add_argument("--odom-rate", type=positive_float, metavar="HZ",
                      help="odom and tf rate (default 50)")
    node.add_argument("--joint-states-rate", type=positive_float, metavar="HZ",
                      help="joint_states rate (default 50)")
    node.add_argument("--diagnostics-rate", type=positive_float, metavar="HZ",
                      help="diagnostics rate, and at once on a change (default 1)")
    node.add_argument("--no-tf", action="store_true", help="do not publish odom -> base_link")
    node.add_argument("--wheel-radius", type=positive_float, metavar="M",
                      help="wheel radius for joint angles (default: from the config)")
    net = p.add_argument_group("DDS network (override [ros2] of the config)")
    net.add_argument("--dds-interface", metavar="IF",
                     help="network interface name or address (default: Cyclone DDS picks; "
                          "under --sim: loopback)")
    net.add_argument("--dds-peer", action="append", default=[], metavar="ADDR",
                     help="unicast discovery peer (repeatable)")
    net.add_argument("--no-multicast", action="store_true",
                     help="no multicast (discover only the peers)")
    net.add_argument("--localhost", action="store_true",
                     help="this machine only: loopback, no multicast, peer 127.0.0.1")
    p.add_argument("--duration", type=positive_float, metavar="S",
                   help="stop after S seconds (default: until Ctrl-C or 'quit')")
    front_ends.add_arguments(p, "node")  # the ROS 2 graph's flags above serve them too
    add_record_argument(p)
    add_bus_arguments(p, sim_help="run against simulated drives in this process; DDS stays "
                      "on loopback unless --dds-interface or --dds-peer says otherwise")
    p.set_defaults(func=run)


def settings_from(args: argparse.Namespace, table: Mapping[str, Any] | None, origin: str,
                  env: dict[str, str] | None = None) -> Any:
    """[ros2] of the config, then ROS_DOMAIN_ID, then the flags; validated."""
    from omnican.ros2.settings import from_table, parse_remap, validate

    environ = os.environ if env is None else env
    default_domain = 0
    if environ.get("ROS_DOMAIN_ID", "").strip():
        try:
            default_domain = int(environ["ROS_DOMAIN_ID"])
        except ValueError:
            raise ConfigError(f"ROS_DOMAIN_ID: not a number: {environ['ROS_DOMAIN_ID']!r}") \
                from None
    s = from_table(table or {}, origin, default_domain)
    changes: dict[str, Any] = {}
    for flag, key in (("namespace", "namespace"), ("node_name", "node_name"),
                      ("domain_id", "domain_id"), ("cmd_vel_stamped", "cmd_vel_stamped"),
                      ("cmd_vel_timeout", "cmd_vel_timeout_s"), ("odom_frame", "odom_frame"),
                      ("base_frame", "base_frame"), ("odom_rate", "odom_rate_hz"),
                      ("joint_states_rate", "joint_states_rate_hz"),
                      ("diagnostics_rate", "diagnostics_rate_hz"),
                      ("wheel_radius", "wheel_radius"), ("dds_interface", "interface")):
        value = getattr(args, flag, None)
        if value is not None:
            changes[key] = value
    for text in args.remap:
        try:
            key, target = parse_remap(text)
        except ValueError as exc:
            raise UsageError(f"--remap: {exc}") from None
        changes[f"{key}_topic"] = target
    if args.no_tf:
        changes["publish_tf"] = False
    if args.dds_peer:
        changes["peers"] = tuple(args.dds_peer)
    if args.no_multicast:
        changes["multicast"] = False
    s = replace(s, **changes)
    network_given = (args.dds_interface or args.dds_peer or args.no_multicast
                     or (table or {}).get("interface") or (table or {}).get("peers"))
    if args.localhost or (getattr(args, "sim", False) and not network_given):
        s = s.with_loopback()
    return validate(s, origin)


#: Where the ROS 2 node sits in the ROS graph: a front end beside it that joins the graph
#: too (Zenoh's) sits there unless its own table says otherwise.
GRAPH_KEYS = ("domain_id", "namespace", "node_name", "cmd_vel_stamped")


def run(args: argparse.Namespace) -> int:
    try:
        import cyclonedds.domain  # noqa: F401  (the ros2 extra)

        from omnican.ros2.bridge import Bridge  # noqa: F401
        from omnican.ros2.transport import DdsTransport  # noqa: F401
    except ImportError:
        from omnican.extras import install_hint

        raise UsageError(f"'ros2' needs cyclonedds: {install_hint('ros2')}") from None
    from omnican.ros2.front_end import Ros2FrontEnd
    from omnican.ros2.settings import describe_network
    from omnican.ros2.table import TELEMETRY_KEYS, Ros2Table

    cfg = load(args)
    origin = str(cfg.source) if cfg.source else "command line"
    table = cfg.front_ends.get("ros2")
    settings = settings_from(args, table, origin)
    node = Ros2FrontEnd(settings)
    graph = {key: getattr(settings, key) for key in GRAPH_KEYS}
    others = front_ends.from_args(args, cfg, "node", graph)
    with session(args) as sess:
        # What every front end says alike (frames, joints, rates) is read from [ros2] by
        # the base's telemetry: the command line's values go there too.
        values = {**(table or {}), **{key: getattr(settings, key) for key in TELEMETRY_KEYS}}
        run_cfg = replace(sess.cfg, front_ends=sess.cfg.front_ends.replace(
            "ros2", Ros2Table(**values)))
        if settings.cmd_vel_timeout_s is not None:
            run_cfg = replace(run_cfg, chassis=replace(run_cfg.chassis,
                                                       cmd_timeout_s=settings.cmd_vel_timeout_s))
        # cmd_vel's publishers and Foxglove's clients drive one at a time: each is a
        # source of commands of the base's own (Chassis.command_source)
        running = [node, *others]
        try:
            front_ends.prepare(running, run_cfg)  # DDS, and the others' slow set-up
            with sess.open_base(run_cfg, record=args.record) as base, \
                    front_ends.attached(running, base, sess.sim,
                                        announce=lambda t: print(t, flush=True)):
                bridge = node.bridge
                _print_startup(bridge, describe_network(settings), run_cfg.chassis.cmd_timeout_s)
                try:
                    serve_lines(lambda line: command(bridge, line), args.duration)
                finally:
                    node.close()
                    _print_summary(bridge)
        finally:
            node.close()
    print("drives disabled", flush=True)
    return EXIT_OK


def _print_startup(bridge: Any, network: str, timeout_s: float) -> None:
    s = bridge.settings
    ns = s.node_namespace
    node = (ns.rstrip("/") + "/" + s.node_name)
    cmd_type = "TwistStamped" if s.cmd_vel_stamped else "Twist"
    out = [f"{s.topic('odom')} {s.odom_rate_hz:g} Hz"]
    if s.publish_tf:
        out.append(f"{s.topic('tf')} ({s.odom_frame} -> {s.base_frame})")
    if bridge.wheel_radii is not None:
        out.append(f"{s.topic('joint_states')} {s.joint_states_rate_hz:g} Hz")
    out.append(f"{s.topic('diagnostics')} {s.diagnostics_rate_hz:g} Hz")
    out.append(f"{s.topic('battery_state')} {s.battery_state_rate_hz:g} Hz")
    print(f"ROS 2 node {node} on DDS domain {s.domain_id} ({network})", flush=True)
    print(f"  in:  {s.topic('cmd_vel')} ({cmd_type}; one publisher at a time; stop after "
          f"{timeout_s:g} s without), "
          f"{s.topic('recover')} (std_msgs/Empty: recover)", flush=True)
    print(f"  out: {', '.join(out)}", flush=True)
    if bridge.wheel_radii is None:
        print("  no joint_states: the config gives no wheel radius (set [ros2] wheel_radius "
              "or --wheel-radius)", flush=True)
    if bridge.sim is not None:
        from omnican.sim.console import COMMANDS

        verbs = ", ".join(syntax for syntax, _ in COMMANDS if not syntax.startswith("quit"))
        print(f"  sim: true pose on {bridge.true_pose_topic}; stdin: {verbs}, recover, quit",
              flush=True)
    print("Ctrl-C to stop", flush=True)


def _print_summary(bridge: Any) -> None:
    rates = bridge.achieved_rates()
    parts = ", ".join(f"{name} {hz:.1f} Hz" for name, hz in rates.items() if hz > 0)
    refused = (f", {bridge.cmd_vel_refused} ignored: another publisher or client drove"
               if bridge.cmd_vel_refused else "")
    rejected = f", {bridge.cmd_vel_rejected} refused" if bridge.cmd_vel_rejected else ""
    print(f"published {parts}; received {bridge.cmd_vel_count} cmd_vel ({bridge.cmd_vel_parsed} "
          f"parsed: a publisher's newest at each poll{refused}{rejected})", flush=True)
    from omnican.ros2.cmd_vel import quote

    for guid, type_name in bridge.wrong_types.items():
        print(f"not received: cmd_vel publisher {guid} sent {quote(type_name)}", flush=True)
    if bridge.sim is not None:
        p = bridge.sim.true_pose
        print(f"true pose x={p.x:.4f} y={p.y:.4f} theta={p.theta:.4f} (simulated)", flush=True)
    p = bridge.base.pose
    print(f"pose x={p.x:.4f} y={p.y:.4f} theta={p.theta:.4f}", flush=True)


def command(bridge: Any, line: str) -> str | None:
    """One stdin line; returns the reply, or None to quit. Under --sim, the simulator's
    console (omnican sim's commands) with recover besides."""
    def recover() -> str:
        return ("recovered" if bridge.recover(answered=True) else
                f"recover {bridge.recover_note}")

    if bridge.sim is not None:
        from omnican.sim import console

        return console.command(bridge.sim, line, more={"recover": recover})
    words = line.split()
    if not words:
        return ""
    verb = words[0].lower()
    if verb in ("quit", "exit"):
        return None
    if verb == "recover":
        return recover()
    return f"error: unknown command {verb!r} (recover, quit; more under --sim)"
