"""The ``[zenoh]`` table of a config: its keys (their types, defaults, ranges and
meaning: README's reference), the frozen :class:`ZenohTable` it becomes, and its own
checks (the mode, the security, the paths of the Zenoh config file and the credentials
made whole). The names and endpoints are checked where they are used
(:mod:`omnican.zenoh.settings`). The command line's flags win over it.

Pure: no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from omnican.config.front_ends import FrontEndTable, TableSpec
from omnican.config.reader import Reader, short, whole_path
from omnican.config.schema import NUMBER, TOPIC_RATE_HZ, Key, defaults_of

#: Values of zenoh.mode (a router is a process of its own: zenohd, rmw_zenohd).
ZENOH_MODES = ("peer", "client")
#: Values of zenoh.security (omnican.zenoh.security: the fleet's certificates and roles).
ZENOH_SECURITY = ("none", "mtls")
#: The [zenoh] rate keys and the topic each sets (omnican.zenoh.settings'
#: ``ZenohSettings.rates_hz``; tf goes with odom).
ZENOH_RATES: dict[str, str] = {
    "odom_rate_hz": "/odom", "joint_states_rate_hz": "/joint_states",
    "battery_state_rate_hz": "/battery_state", "status_rate_hz": "/status",
    "wheels_rate_hz": "/wheels", "summary_rate_hz": "/base_summary",
}
_RATE_DEFAULTS = {"odom_rate_hz": 50.0, "joint_states_rate_hz": 50.0,
                  "battery_state_rate_hz": 1.0, "status_rate_hz": 10.0,
                  "wheels_rate_hz": 10.0, "summary_rate_hz": 2.0}
_RATE_NOTES = {"odom_rate_hz": " (tf with it)",
               "summary_rate_hz": " (the fleet's view; and at once on a change)"}

#: Read by the Zenoh front end (omnican zenoh, --zenoh).
KEYS: dict[str, Key] = {
    "enabled": Key((bool,), False, "turn the Zenoh front end on for teleop, drive, ros2 "
                   "and sim without --zenoh (--no-zenoh keeps it off)"),
    "domain_id": Key((int,), 0, "ROS domain: the first chunk of every key "
                     "(rmw_zenoh's ROS_DOMAIN_ID)", range=(0, 232)),
    "namespace": Key((str,), "", "the robot's namespace, e.g. \"/robot1\""),
    "node_name": Key((str,), "omnican", "node name (omnican sim's is this + \"_sim\")"),
    "mode": Key((str,), "peer", "\"peer\" or \"client\" (of the router connected to)"),
    "connect": Key((list,), None, "routers or peers to connect to, e.g. "
                   "[\"tcp/192.168.1.10:7447\"] (rmw_zenoh's router port)"),
    "listen": Key((list,), None, "endpoints to listen on, e.g. [\"tls/192.168.1.20:7448\"]; "
                  "default loopback (a peer: tcp/127.0.0.1:0; tls/ with credentials); "
                  "beyond loopback needs credentials or allow_insecure"),
    "multicast": Key((bool,), False, "find peers by multicast scouting"),
    "config_file": Key((str,), None, "a Zenoh JSON5 config (relative to the config "
                       "file): TLS, authentication, access control; applied first"),
    "cmd_vel_stamped": Key((bool,), False, "cmd_vel carries TwistStamped instead of "
                           "Twist"),
    "security": Key((str,), None, "\"mtls\": TLS links with the fleet's certificates "
                    "both ways, and a base's or router's access control (who may drive); "
                    "\"none\"; default \"mtls\" when credentials is given, else "
                    "\"none\""),
    "credentials": Key((str,), None, "the folder 'omnican zenoh credentials' made "
                       "(relative to the config file): its ca.pem and the identity's "
                       "folder"),
    "identity": Key((str,), None, "whose certificate the session presents: "
                    "\"base/NAME\" (the base runs under /NAME), \"operator/NAME\", "
                    "\"viewer/NAME\" or \"router/NAME\""),
    "allow_insecure": Key((bool,), False, "listen beyond loopback without credentials "
                          "(anyone who reaches it could drive the robot); "
                          "--zenoh-allow-insecure"),
    **{key: Key(NUMBER, _RATE_DEFAULTS[key], f"{topic[1:]} publish rate"
                + _RATE_NOTES.get(key, ""), range=TOPIC_RATE_HZ)
       for key, topic in ZENOH_RATES.items()},
}

_D = defaults_of(KEYS)


@dataclass(frozen=True)
class ZenohTable(FrontEndTable):
    """The ``[zenoh]`` table, its types and ranges checked (the names and endpoints are
    checked where they are used, by ``omnican.zenoh.settings``). ``config_file`` and
    ``credentials`` are made whole against the config file's folder; ``given``: the keys
    the table gave (under ``omnican ros2 --zenoh`` the others of the ROS graph are the
    ROS 2 node's)."""

    enabled: bool = _D["enabled"]
    domain_id: int = _D["domain_id"]
    namespace: str = _D["namespace"]
    node_name: str = _D["node_name"]
    mode: str = _D["mode"]
    connect: tuple[str, ...] = ()
    listen: tuple[str, ...] = ()
    multicast: bool = _D["multicast"]
    config_file: str | None = _D["config_file"]
    cmd_vel_stamped: bool = _D["cmd_vel_stamped"]
    odom_rate_hz: float = _D["odom_rate_hz"]
    joint_states_rate_hz: float = _D["joint_states_rate_hz"]
    battery_state_rate_hz: float = _D["battery_state_rate_hz"]
    status_rate_hz: float = _D["status_rate_hz"]
    wheels_rate_hz: float = _D["wheels_rate_hz"]
    summary_rate_hz: float = _D["summary_rate_hz"]
    security: str | None = _D["security"]
    credentials: str | None = _D["credentials"]
    identity: str | None = _D["identity"]
    allow_insecure: bool = _D["allow_insecure"]
    given: frozenset[str] = field(default=frozenset(), compare=False)


def read(r: Reader, t: dict[str, Any], given: frozenset[str],
         base_dir: Path | None) -> ZenohTable:
    """The ``[zenoh]`` table: types, ranges, the mode and security; the paths of the config
    file and the credentials made whole (omnican.zenoh.settings checks the names, the
    endpoints and the identity)."""
    if t["mode"] not in ZENOH_MODES:
        raise r.fail("zenoh.mode", f"must be one of {', '.join(ZENOH_MODES)}, got "
                     f"{short(t['mode'])}")
    for key in ("connect", "listen"):
        t[key] = t[key] or []
        if not all(isinstance(v, str) for v in t[key]):
            raise r.fail(f"zenoh.{key}", "must be an array of endpoints (strings), e.g. "
                         "[\"tcp/192.168.1.10:7447\"]")
        t[key] = tuple(t[key])
    if t["security"] is not None and t["security"] not in ZENOH_SECURITY:
        raise r.fail("zenoh.security", f"must be one of {', '.join(ZENOH_SECURITY)}, got "
                     f"{short(t['security'])}")
    for key in ("config_file", "credentials"):
        t[key] = whole_path(t[key], base_dir)
    numbers = {k: float(v) for k, v in t.items() if KEYS[k].types == NUMBER}
    return ZenohTable(**{**t, **numbers}, given=given)


TABLE = TableSpec(KEYS, read)

#: What ``omnican.config`` exported of this table before the front ends' tables were
#: their own (a DeprecationWarning there, for one release).
MOVED_FROM_CONFIG = ("ZenohTable", "ZENOH_MODES", "ZENOH_RATES", "ZENOH_SECURITY")
