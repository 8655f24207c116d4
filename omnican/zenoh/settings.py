"""What the Zenoh front end is told: where the base sits in the ROS graph (domain,
namespace, node name), how often each stream goes out, and how its Zenoh session
connects. Pure: :func:`config_entries` gives the session's configuration as Zenoh's
``insert_json5`` pairs; :func:`omnican.zenoh.bridge.open_session` applies them.

Multicast scouting is off unless asked for (rmw_zenoh's default too): a base finds its
peers through the router it connects to (``tcp/HOST:7447``, rmw_zenoh's default port),
and sends nothing to a network it was not pointed at. A Zenoh JSON5 file, if given, is
read first (TLS, user/password, access control pass through it); what is set here wins.

A session listens on loopback unless told where (:func:`default_listen`; Zenoh's own
default is every interface), and one that would listen beyond loopback with nothing to
tell who may connect is refused (:func:`exposed`) unless ``allow_insecure``: anyone who
reached it could drive the robot. ``security = "mtls"`` gives the session the fleet's
certificates and, for a base or a router, its access control
(:mod:`omnican.zenoh.security`, made by ``omnican zenoh credentials``).

The defaults are the ``[zenoh]`` table's (:mod:`omnican.zenoh.table`);
:func:`from_table` makes settings of a config's table.
"""

from __future__ import annotations

import ipaddress
import json
import math
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, fields, replace
from typing import Any

from omnican.config import defaults_of
from omnican.errors import ConfigError
from omnican.zenoh.security import Identity
from omnican.zenoh.table import KEYS, ZENOH_RATES, ZENOH_SECURITY, ZenohTable

MODES = ("peer", "client", "router")
#: A ROS 2 name chunk: what rmw_zenoh's key expressions can carry unchanged.
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_ENDPOINT = re.compile(r"^(tcp|udp|quic|tls|ws|unixsock-stream)/\S+$")


_D = defaults_of(KEYS)
#: Where the base sits in the ROS graph: under ``omnican ros2 --zenoh`` the ROS 2
#: node's, unless the [zenoh] table or a flag says otherwise.
GRAPH_KEYS = ("domain_id", "namespace", "node_name", "cmd_vel_stamped")


def _default_rates() -> dict[str, float]:
    return {topic: float(_D[key]) for key, topic in ZENOH_RATES.items()}


@dataclass(frozen=True)
class ZenohSettings:
    domain_id: int = _D["domain_id"]  # ROS_DOMAIN_ID: the first chunk of every key
    namespace: str = _D["namespace"]  # the robot's: "/robot1" -> 0/robot1/odom/...
    node_name: str = _D["node_name"]
    mode: str = _D["mode"]
    connect: tuple[str, ...] = ()  # e.g. ("tcp/192.168.1.10:7447",)
    listen: tuple[str, ...] = ()  # empty: Zenoh's default for the mode
    multicast: bool = _D["multicast"]  # multicast scouting
    config_file: str | None = _D["config_file"]  # a Zenoh JSON5 file, applied first
    cmd_vel_stamped: bool = _D["cmd_vel_stamped"]  # cmd_vel: geometry_msgs/msg/TwistStamped
    #: Hz per telemetry topic (tf goes with odom; diagnostics at the telemetry's pace).
    rates_hz: dict[str, float] = field(default_factory=_default_rates)
    #: "mtls", "none"; None: "mtls" when credentials are given, else "none"
    security: str | None = _D["security"]
    credentials: str | None = _D["credentials"]  # the folder omnican zenoh credentials made
    identity: str | None = _D["identity"]  # ROLE/NAME: whose certificate (base/robot1)
    allow_insecure: bool = _D["allow_insecure"]  # listen beyond loopback without credentials

    def validate(self) -> ZenohSettings:
        """Self, or ConfigError naming what is wrong."""
        if not (isinstance(self.domain_id, int) and 0 <= self.domain_id <= 232):
            raise ConfigError(f"zenoh: domain id {self.domain_id!r} is not 0..232")
        if self.mode not in MODES:
            raise ConfigError(f"zenoh: mode {self.mode!r} is not one of {', '.join(MODES)}")
        if not _NAME.match(self.node_name):
            raise ConfigError(f"zenoh: node name {self.node_name!r} is not a ROS 2 name")
        chunks = [c for c in self.namespace.split("/") if c]
        if any(not _NAME.match(c) for c in chunks) or "//" in self.namespace:
            raise ConfigError(f"zenoh: namespace {self.namespace!r} is not a ROS 2 namespace")
        for endpoint in (*self.connect, *self.listen):
            if not _ENDPOINT.match(endpoint):
                raise ConfigError(f"zenoh: {endpoint!r} is not a Zenoh endpoint "
                                  "(like tcp/127.0.0.1:7447)")
        for topic, rate in self.rates_hz.items():
            if not (math.isfinite(rate) and 0 < rate <= 1000):
                raise ConfigError(f"zenoh: rate of {topic} {rate!r} is not in (0, 1000] Hz")
        self._validate_security()
        # a listen endpoint given beyond loopback, refused already here (check-config
        # too); with a Zenoh config file, once it is read (it may ask for passwords)
        open_to = [] if self.allow_insecure or self.config_file else \
            exposed(self.listen, mtls=self.mtls)
        if open_to:
            raise ConfigError(exposed_refusal(self, open_to))
        return self

    @property
    def mtls(self) -> bool:
        """The fleet's certificates and access control are on (``security = "mtls"``)."""
        return self.security == "mtls" or (self.security is None
                                           and self.credentials is not None)

    @property
    def who(self) -> Identity | None:
        """Whose certificate the session presents (None: no credentials)."""
        return Identity.parse(self.identity) if self.mtls and self.identity else None

    def _validate_security(self) -> None:
        if self.security is not None and self.security not in ZENOH_SECURITY:
            raise ConfigError(f"zenoh: security {self.security!r} is not one of "
                              f"{', '.join(ZENOH_SECURITY)}")
        if not self.mtls:
            given = [k for k in ("credentials", "identity") if getattr(self, k) is not None]
            if given == ["identity"] and self.security is None:
                raise ConfigError(f"zenoh: identity {self.identity} needs the credentials' "
                                  "folder (--zenoh-credentials DIR, [zenoh] credentials)")
            if given:
                raise ConfigError(f"zenoh: {given[0]} is for security \"mtls\", and security "
                                  "is \"none\"")
            return
        if self.credentials is None or self.identity is None:
            missing = "credentials" if self.credentials is None else "identity"
            raise ConfigError(f"zenoh: security \"mtls\" needs the {missing} (the folder "
                              "'omnican zenoh credentials' made, and ROLE/NAME in it)")
        try:
            Identity.parse(self.identity)
        except ValueError as exc:
            raise ConfigError(f"zenoh: {exc}") from None
        plain = [e for e in (*self.connect, *self.listen) if e.split("/", 1)[0] != "tls"]
        if plain:
            raise ConfigError(f"zenoh: with credentials a link is TLS: {plain[0]!r} is not "
                              "a tls/HOST:PORT endpoint")

    @property
    def ros_namespace(self) -> str:
        """The namespace as ROS 2 writes it: "" -> "/", "robot1/" -> "/robot1"."""
        return "/" + "/".join(c for c in self.namespace.split("/") if c)

    @property
    def node_fq_name(self) -> str:
        """The node's fully qualified name: "/robot1/omnican", "/omnican"."""
        return self.ros_namespace.rstrip("/") + "/" + self.node_name


def from_table(table: ZenohTable | None, origin: str = "config",
               graph: Mapping[str, Any] | None = None) -> ZenohSettings:
    """Settings of a config's ``[zenoh]`` table (None: none given: the defaults),
    validated; a ConfigError begins with ``origin`` (the file). ``graph``: where the ROS
    graph puts the node when the table does not say (:data:`GRAPH_KEYS`; ``omnican ros2
    --zenoh`` passes its ROS 2 node's)."""
    t = table or ZenohTable()
    names = {f.name for f in fields(ZenohSettings)} - {"rates_hz"}
    values = {name: getattr(t, name) for name in names}
    for key, value in (graph or {}).items():
        if key in GRAPH_KEYS and key not in t.given:
            values[key] = value
    rates = {topic: float(getattr(t, key)) for key, topic in ZENOH_RATES.items()}
    return checked(ZenohSettings(**values, rates_hz=rates), origin)


def checked(settings: ZenohSettings, origin: str = "command line",
            **changes: Any) -> ZenohSettings:
    """``settings`` with ``changes``, validated; a ConfigError begins with ``origin``."""
    try:
        return replace(settings, **changes).validate()
    except ConfigError as exc:
        raise ConfigError(f"{origin}: {exc}") from None


def role_problem(s: ZenohSettings) -> str | None:
    """What is wrong with the session's identity for its mode (None: nothing): a router
    takes a router's credentials (its access control is the fleet's), and only it."""
    who = s.who
    if who is not None and (s.mode == "router") != (who.role == "router"):
        return (f"zenoh: a {s.mode} session cannot be {who}: a router takes a router's "
                "credentials, and only a router does")
    return None


def base_problem(s: ZenohSettings) -> str | None:
    """What is wrong with a base's identity (None: nothing, or no credentials): it must be
    a base's, and the base must run under that base's namespace (its certificate may
    publish and announce nothing elsewhere: the router would drop the rest)."""
    who = s.who
    if who is None:
        return None
    if who.role != "base":
        return (f"zenoh: a base presents a base's credentials (base/NAME), not {who}: its "
                "access control says who may drive it")
    if s.ros_namespace != who.namespace:
        return (f"zenoh: {who} runs under the namespace {who.namespace} (its certificate "
                f"may publish there only), not {s.ros_namespace}: give --namespace "
                f"{who.namespace}")
    return None


def default_listen(s: ZenohSettings) -> tuple[str, ...]:
    """Where a session listens when nothing says: a peer or router on loopback (a free
    port; a router on rmw_zenoh's 7447), TLS with credentials; a client nowhere."""
    if s.mode == "client":
        return ()
    port = 7447 if s.mode == "router" else 0
    return (f"{'tls' if s.mtls else 'tcp'}/127.0.0.1:{port}",)


def loopback(endpoint: str) -> bool:
    """``endpoint`` accepts links from this machine only: a loopback address
    (127.0.0.0/8, ::1, localhost) or a Unix socket. Every interface (``[::]``,
    ``0.0.0.0``), an interface's address and a host name are beyond it."""
    proto, _, rest = endpoint.partition("/")
    if proto.startswith("unixsock"):
        return True
    address = re.split(r"[?#]", rest, maxsplit=1)[0]
    host = address.rsplit(":", 1)[0] if ":" in address else address
    host = host[1:-1] if host.startswith("[") and host.endswith("]") else host
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.split("%", 1)[0]).is_loopback
    except ValueError:
        return False


def exposed(endpoints: Iterable[str], *, mtls: bool = False,
            password: bool = False) -> list[str]:
    """The endpoints of ``endpoints`` beyond loopback that no credentials guard: every
    one without credentials; with mutual TLS, those not over TLS or QUIC; none when
    every session must give a user and password (``password``)."""
    if password:
        return []
    return [e for e in endpoints if not loopback(e)
            and not (mtls and e.split("/", 1)[0] in ("tls", "quic"))]


def exposed_refusal(s: ZenohSettings, endpoints: list[str]) -> str:
    """The one line that refuses a session listening on ``endpoints`` (:func:`exposed`)
    without credentials: who could then drive the robot, and the ways out."""
    where = ", ".join(endpoints)
    everyone = [e for e in endpoints if re.search(r"/(\[::\]|0\.0\.0\.0):", e)]
    scope = " (every interface)" if everyone else ""
    robots = ("every robot connected to this router" if s.mode == "router"
              else "this robot")
    return (f"zenoh: would listen on {where}{scope} without credentials: anyone who can "
            f"reach it could drive {robots} (publish cmd_vel, call ~/recover). Give "
            "credentials (--zenoh-credentials DIR --zenoh-identity ROLE/NAME, made by "
            "'omnican zenoh credentials'), listen on loopback (--zenoh-listen "
            "tcp/127.0.0.1:0), or accept it with --zenoh-allow-insecure ([zenoh] "
            "allow_insecure = true)")


def config_entries(s: ZenohSettings) -> list[tuple[str, str]]:
    """(path, JSON5 value) pairs for ``zenoh.Config.insert_json5``, in order."""
    out = [("mode", json.dumps(s.mode)),
           ("scouting/multicast/enabled", json.dumps(s.multicast))]
    if s.connect:
        out.append(("connect/endpoints", json.dumps(list(s.connect))))
    if s.listen:
        out.append(("listen/endpoints", json.dumps(list(s.listen))))
    return out
