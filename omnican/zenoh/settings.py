"""What the Zenoh front end is told: where the base sits in the ROS graph (domain,
namespace, node name), how often each stream goes out, and how its Zenoh session
connects. Pure: :func:`config_entries` gives the session's configuration as Zenoh's
``insert_json5`` pairs; :func:`omnican.zenoh.bridge.open_session` applies them.

Multicast scouting is off unless asked for (rmw_zenoh's default too): a base finds its
peers through the router it connects to (``tcp/HOST:7447``, rmw_zenoh's default port),
and sends nothing to a network it was not pointed at. A Zenoh JSON5 file, if given, is
read first (TLS, user/password, access control pass through it); what is set here wins.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field

from omnican.errors import ConfigError

MODES = ("peer", "client", "router")
#: A ROS 2 name chunk: what rmw_zenoh's key expressions can carry unchanged.
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_ENDPOINT = re.compile(r"^(tcp|udp|quic|tls|ws|unixsock-stream)/\S+$")


def _default_rates() -> dict[str, float]:
    return {"/odom": 50.0, "/joint_states": 50.0, "/battery_state": 1.0, "/status": 10.0,
            "/wheels": 10.0, "/base_summary": 2.0}


@dataclass(frozen=True)
class ZenohSettings:
    domain_id: int = 0  # ROS_DOMAIN_ID: the first chunk of every key
    namespace: str = ""  # the robot's: "/robot1" -> 0/robot1/odom/...
    node_name: str = "omnican"
    mode: str = "peer"
    connect: tuple[str, ...] = ()  # e.g. ("tcp/192.168.1.10:7447",)
    listen: tuple[str, ...] = ()  # empty: Zenoh's default for the mode
    multicast: bool = False  # multicast scouting
    config_file: str | None = None  # a Zenoh JSON5 file, applied first
    cmd_vel_stamped: bool = False  # cmd_vel carries geometry_msgs/msg/TwistStamped
    #: Hz per telemetry topic (tf goes with odom; diagnostics at the telemetry's pace).
    rates_hz: dict[str, float] = field(default_factory=_default_rates)

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
        return self

    @property
    def ros_namespace(self) -> str:
        """The namespace as ROS 2 writes it: "" -> "/", "robot1/" -> "/robot1"."""
        return "/" + "/".join(c for c in self.namespace.split("/") if c)


def config_entries(s: ZenohSettings) -> list[tuple[str, str]]:
    """(path, JSON5 value) pairs for ``zenoh.Config.insert_json5``, in order."""
    out = [("mode", json.dumps(s.mode)),
           ("scouting/multicast/enabled", json.dumps(s.multicast))]
    if s.connect:
        out.append(("connect/endpoints", json.dumps(list(s.connect))))
    if s.listen:
        out.append(("listen/endpoints", json.dumps(list(s.listen))))
    return out
