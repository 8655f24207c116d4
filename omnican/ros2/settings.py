"""What ``omnican ros2`` runs with: the ``[ros2]`` table, command-line overrides, ROS 2
names, and the Cyclone DDS configuration. Pure: no DDS, no I/O (the user's Cyclone files
are read through a function the caller passes).

ROS 2 naming (as rcl does it): a relative name ``cmd_vel`` lives in the node's
namespace (``/robot1/cmd_vel``), ``~/recover`` under the node (``/robot1/omnican/recover``),
an absolute ``/tf`` stays as it is. On the wire a topic is ``rt`` + its full name.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, replace
from typing import Any
from xml.etree import ElementTree
from xml.sax.saxutils import quoteattr

from omnican.config import defaults_of
from omnican.errors import ConfigError
from omnican.ros2.table import KEYS

#: eProsima's RTPS vendor id (Fast DDS, the default ROS 2 middleware). Fast DDS 3 (ROS 2
#: Kilted and later) announces XTypes type information that Cyclone does not find
#: assignable for types with arrays (nav_msgs/Odometry's covariances): readers and
#: writers then never match. Ignoring that vendor's type information falls back to
#: matching by type name, which is how ROS 2 itself matches types.
EPROSIMA_VENDOR_ID = "1.15"

#: Cyclone drops a sample larger than this as it arrives (with a warning), before any of
#: it reaches Python: omnican takes commands of well under 1 KB and sends nothing near it.
MAX_SAMPLE_BYTES = 65536

#: The highest DDS domain id whose ports fit the RTPS port formula (ROS 2's limit too).
MAX_DOMAIN_ID = 232

#: The topics omnican uses, by the short names ``--remap`` takes.
TOPIC_KEYS = ("cmd_vel", "odom", "tf", "joint_states", "diagnostics", "battery_state",
              "recover")

_NAME_TOKEN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
# Interface names, addresses, host names: printable ASCII; no spaces, no commas (Cyclone's
# configuration list separator).
_NET_WORD = re.compile(r"^[!-+\--~]+$")


# The [ros2] defaults are written once, in omnican.ros2.table (None there: not given).
_D = defaults_of(KEYS)


@dataclass(frozen=True)
class Ros2Settings:
    """Everything ``[ros2]`` configures; see the README's configuration reference."""

    namespace: str = _D["namespace"]
    node_name: str = _D["node_name"]
    domain_id: int = 0
    cmd_vel_topic: str = _D["cmd_vel_topic"]
    cmd_vel_stamped: bool = _D["cmd_vel_stamped"]
    cmd_vel_timeout_s: float | None = None  # None: the chassis' cmd_timeout_s
    odom_topic: str = _D["odom_topic"]
    odom_frame: str = _D["odom_frame"]
    base_frame: str = _D["base_frame"]
    odom_rate_hz: float = _D["odom_rate_hz"]
    publish_tf: bool = _D["publish_tf"]
    tf_topic: str = _D["tf_topic"]
    joint_states_topic: str = _D["joint_states_topic"]
    joint_states_rate_hz: float = _D["joint_states_rate_hz"]
    joint_names: tuple[str, ...] = ()  # empty: wheel_0_joint, wheel_1_joint, ...
    wheel_radius: float | None = None
    diagnostics_topic: str = _D["diagnostics_topic"]
    diagnostics_rate_hz: float = _D["diagnostics_rate_hz"]
    battery_state_topic: str = _D["battery_state_topic"]
    battery_state_rate_hz: float = _D["battery_state_rate_hz"]
    recover_topic: str = _D["recover_topic"]
    odom_slip: float = _D["odom_slip"]
    interface: str | None = None
    peers: tuple[str, ...] = ()
    multicast: bool = _D["multicast"]

    # ------------------------------------------------------------ names

    @property
    def node_namespace(self) -> str:
        """The namespace in ROS 2's form: "/" or "/robot1"."""
        return normalize_namespace(self.namespace)

    def topic(self, key: str) -> str:
        """The fully qualified ROS 2 name of one of :data:`TOPIC_KEYS`."""
        name = getattr(self, f"{key}_topic")
        return resolve_name(name, self.node_namespace, self.node_name)

    def wheel_joint_names(self, n_wheels: int) -> tuple[str, ...]:
        if self.joint_names:
            return self.joint_names
        return tuple(f"wheel_{i}_joint" for i in range(n_wheels))

    @property
    def loopback_only(self) -> bool:
        """True when DDS can reach only this machine (the loopback interface, no multicast,
        peers on 127.0.0.0/8 only)."""
        return (self.interface in ("lo", "127.0.0.1") and not self.multicast
                and all(p.startswith("127.") or p == "localhost" for p in self.peers))

    def with_loopback(self) -> Ros2Settings:
        return replace(self, interface="lo", multicast=False, peers=("127.0.0.1",))


def normalize_namespace(ns: str) -> str:
    """"" or "robot1/" -> "/" or "/robot1"; raises ValueError for an invalid namespace."""
    text = ns.strip()
    if text in ("", "/"):
        return "/"
    if not text.startswith("/"):
        text = "/" + text
    text = text.rstrip("/")
    for token in text[1:].split("/"):
        if not _NAME_TOKEN.match(token):
            raise ValueError(f"invalid namespace {ns!r}: {token!r} is not a ROS name "
                             "(letters, digits and _, not starting with a digit)")
    return text


def resolve_name(name: str, namespace: str = "/", node: str = "omnican") -> str:
    """A topic name as rcl expands it: relative names go into the namespace, ``~`` is the
    node's own name; raises ValueError for names ROS 2 would refuse."""
    ns = normalize_namespace(namespace)
    if not _NAME_TOKEN.match(node):
        raise ValueError(f"invalid node name {node!r}")
    if name.startswith("~"):
        rest = name[1:]
        if rest and not rest.startswith("/"):
            raise ValueError(f"invalid topic name {name!r}: '~' must be followed by '/'")
        base = ns.rstrip("/") + "/" + node
        full = base + rest
    elif name.startswith("/"):
        full = name
    else:
        full = ns.rstrip("/") + "/" + name
    if full != "/" and full.endswith("/"):
        raise ValueError(f"invalid topic name {name!r}: ends with '/'")
    tokens = full[1:].split("/")
    for token in tokens:
        if not _NAME_TOKEN.match(token):
            raise ValueError(f"invalid topic name {name!r}: {token!r} is not a ROS name "
                             "(letters, digits and _, not starting with a digit)")
    return full


def dds_topic(full_name: str) -> str:
    """The DDS topic of a ROS 2 topic: ``/odom`` -> ``rt/odom``."""
    return "rt" + full_name


# ------------------------------------------------------------ from config and flags

_FIELDS = set(Ros2Settings.__dataclass_fields__)


def from_table(table: Mapping[str, Any], origin: str = "config",
               default_domain_id: int = 0) -> Ros2Settings:
    """Validate a ``[ros2]`` table (types already checked by the config schema) into
    settings. Missing keys keep their defaults; None means "not given"."""
    values: dict[str, Any] = {}
    for key, value in table.items():
        if value is None:
            continue
        if key not in _FIELDS:
            raise ConfigError(f"{origin}: ros2.{key}: unknown key")
        values[key] = tuple(value) if isinstance(value, list) else value
    values.setdefault("domain_id", default_domain_id)
    return validate(Ros2Settings(**values), origin)


def validate(s: Ros2Settings, origin: str = "config") -> Ros2Settings:
    """Check every value; raises ConfigError naming the key."""
    def bad(key: str, message: str) -> ConfigError:
        return ConfigError(f"{origin}: ros2.{key}: {message}")

    if not 0 <= s.domain_id <= MAX_DOMAIN_ID:
        raise bad("domain_id", f"must be 0-{MAX_DOMAIN_ID}, got {s.domain_id}")
    try:
        normalize_namespace(s.namespace)
    except ValueError as exc:
        raise bad("namespace", str(exc)) from None
    if not _NAME_TOKEN.match(s.node_name):
        raise bad("node_name", f"{s.node_name!r} is not a ROS node name (letters, digits "
                  "and _, not starting with a digit)")
    for key in TOPIC_KEYS:
        try:
            s.topic(key)
        except ValueError as exc:
            raise bad(f"{key}_topic", str(exc)) from None
    for key in ("odom_frame", "base_frame"):
        frame = getattr(s, key)
        if not frame or frame.startswith("/") or any(c.isspace() for c in frame):
            raise bad(key, f"must be a tf2 frame id (no leading '/', no spaces), got {frame!r}")
    if s.odom_frame == s.base_frame:
        raise bad("base_frame", f"must differ from odom_frame ({s.odom_frame!r})")
    for key in ("odom_rate_hz", "joint_states_rate_hz", "diagnostics_rate_hz",
                "battery_state_rate_hz"):
        rate = getattr(s, key)
        if not (isinstance(rate, (int, float)) and math.isfinite(rate) and 0 < rate <= 1000):
            raise bad(key, f"must be a rate in (0, 1000] Hz, got {rate!r}")
    if s.cmd_vel_timeout_s is not None and not (
            math.isfinite(s.cmd_vel_timeout_s) and s.cmd_vel_timeout_s > 0):
        raise bad("cmd_vel_timeout_s", f"must be a positive number, got {s.cmd_vel_timeout_s!r}")
    if s.wheel_radius is not None and not (
            math.isfinite(s.wheel_radius) and s.wheel_radius > 0):
        raise bad("wheel_radius", f"must be a positive number, got {s.wheel_radius!r}")
    if not (math.isfinite(s.odom_slip) and 0 <= s.odom_slip < 1):
        raise bad("odom_slip", f"must be in [0, 1), got {s.odom_slip!r}")
    names = s.joint_names
    if names and (len(set(names)) != len(names) or not all(isinstance(n, str) and n
                                                          for n in names)):
        raise bad("joint_names", "must be distinct non-empty strings")
    if s.interface is not None and not _NET_WORD.match(s.interface):
        raise bad("interface", f"must name a network interface or address, got {s.interface!r}")
    for p in s.peers:
        if not isinstance(p, str) or not _NET_WORD.match(p):
            raise bad("peers", f"must be host names or addresses, got {p!r}")
    return replace(s, namespace=normalize_namespace(s.namespace))


def parse_remap(text: str) -> tuple[str, str]:
    """``--remap cmd_vel:=/robot/cmd_vel`` -> ("cmd_vel", "/robot/cmd_vel")."""
    key, sep, target = text.partition(":=")
    key = key.strip().lstrip("/")
    if not sep or not target.strip():
        raise ValueError(f"expected NAME:=TOPIC, got {text!r}")
    if key not in TOPIC_KEYS:
        raise ValueError(f"cannot remap {key!r}; known: {', '.join(TOPIC_KEYS)}")
    return key, target.strip()


# ------------------------------------------------------------ Cyclone DDS configuration

def cyclone_config(s: Ros2Settings, env_uri: str | None = None,
                   read_file: Callable[[str], str] | None = None) -> str:
    """The configuration string for ``cyclonedds.domain.Domain``: omnican's compatibility
    settings and its sample size limit (:data:`MAX_SAMPLE_BYTES`) first, then the user's
    ``CYCLONEDDS_URI`` (files or XML, which may override them), then what ``[ros2]`` or
    the command line said about the network (which wins).

    Cyclone reads a comma-separated list of XML fragments and file names (``file://``
    URIs too), later ones overriding earlier ones, which is the form ``CYCLONEDDS_URI``
    takes. Lists are not overridden but added to: an interface named by the user and by
    omnican is selected twice, which Cyclone refuses, and a user's other interface or
    peer would widen ``--sim``'s loopback-only network. So where omnican names the
    interface, the user's interface selection is left out of the user's part, and where
    it names peers, the user's peers; the rest of the user's configuration stays.
    ``read_file`` (a path -> its text) reads the user's files for that; without it, or
    for a file it cannot read or parse, the user's part goes to Cyclone as it is."""
    parts = [_domain_xml(
        "<Compatibility>"
        f"<IgnoreTypeInformation>{EPROSIMA_VENDOR_ID}</IgnoreTypeInformation>"
        "</Compatibility>"
        f"<Internal><MaxSampleSize>{MAX_SAMPLE_BYTES}B</MaxSampleSize></Internal>")]
    if env_uri and env_uri.strip():
        drop = (_INTERFACE_TAGS if s.interface is not None else frozenset()) | (
            _PEER_TAGS if s.peers else frozenset())
        if drop:
            parts += [_without(item, is_xml, drop, read_file)
                      for item, is_xml in split_cyclone_uri(env_uri)]
        else:
            parts.append(env_uri.strip())
    general = ""
    if s.interface is not None:
        general += ("<Interfaces><NetworkInterface "
                    f"{'address' if _looks_like_address(s.interface) else 'name'}="
                    f"{quoteattr(s.interface)}/></Interfaces>")
    if not s.multicast:
        general += "<AllowMulticast>false</AllowMulticast>"
    network = f"<General>{general}</General>" if general else ""
    if s.peers:
        peers = "".join(f"<Peer address={quoteattr(p)}/>" for p in s.peers)
        # Unicast discovery probes the ports of the first participant indices on each
        # peer: "auto" gives this participant such an index, so peers find it as well.
        network += (f"<Discovery><ParticipantIndex>auto</ParticipantIndex>"
                    f"<Peers>{peers}</Peers></Discovery>")
    if network:
        parts.append(_domain_xml(network))
    return ",".join(parts)


# What selects network interfaces in a Cyclone configuration: General/Interfaces and the
# deprecated General elements (which Cyclone refuses beside General/Interfaces), and the
# discovery peers. Cyclone matches element names without regard to case.
_INTERFACE_TAGS = frozenset({"networkinterface", "networkinterfaceaddress",
                             "multicastrecvnetworkinterfaceaddresses",
                             "assumemulticastcapable", "prefermulticast"})
_PEER_TAGS = frozenset({"peer"})
_XML_TOKEN = re.compile(r"<!--.*?-->|<!\[CDATA\[.*?\]\]>|<[?!].*?>|<(/?)[^>]*?(/?)>", re.S)


def split_cyclone_uri(uri: str) -> Iterator[tuple[str, bool]]:
    """The items of a ``CYCLONEDDS_URI`` as Cyclone reads them: (text, True) for an XML
    fragment (it starts with ``<`` and runs to the end of its element, commas and all),
    (name, False) for a file (up to the next comma)."""
    i, n = 0, len(uri)
    while True:
        while i < n and (uri[i].isspace() or uri[i] == ","):
            i += 1
        if i >= n:
            return
        if uri[i] != "<":
            end = uri.find(",", i)
            end = n if end < 0 else end
            yield uri[i:end].strip(), False
            i = end
            continue
        depth, end = 0, n
        for m in _XML_TOKEN.finditer(uri, i):
            closing, empty = m.group(1), m.group(2)
            if closing is None:  # a comment, CDATA, declaration or processing instruction
                continue
            depth += -1 if closing else 0 if empty else 1
            if depth <= 0:
                end = m.end()
                break
        yield uri[i:end], True
        i = end


def _without(item: str, is_xml: bool, drop: frozenset[str],
             read_file: Callable[[str], str] | None) -> str:
    """One item of the user's configuration without the elements ``drop`` names (local
    names, lower case), inline; the item as it was when nothing goes or it cannot be read."""
    if is_xml:
        text = item
    elif read_file is None:
        return item
    else:
        try:
            text = read_file(item[len("file://"):] if item.startswith("file://") else item)
        except (OSError, UnicodeDecodeError):
            return item  # Cyclone says it cannot open it
    try:
        root = ElementTree.fromstring(text)
    except ElementTree.ParseError:
        return item  # Cyclone says what is wrong with it
    removed = False
    for parent in list(root.iter()):
        for child in list(parent):
            if _local(child.tag).lower() in drop:
                parent.remove(child)
                removed = True
    if not removed:
        return item
    for parent in list(root.iter()):  # an Interfaces or Peers left empty goes too
        for child in list(parent):
            if _local(child.tag).lower() in ("interfaces", "peers") and len(child) == 0:
                parent.remove(child)
    for element in root.iter():  # Cyclone reads plain names: no namespace prefixes
        element.tag = _local(element.tag)
        for key in [k for k in element.attrib if k.startswith("{")]:
            del element.attrib[key]
    return ElementTree.tostring(root, encoding="unicode")


def _local(tag: Any) -> str:
    return str(tag).rpartition("}")[2]


def _domain_xml(inner: str) -> str:
    return f'<CycloneDDS><Domain Id="any">{inner}</Domain></CycloneDDS>'


def _looks_like_address(text: str) -> bool:
    return bool(re.fullmatch(r"[0-9.]+|[0-9A-Fa-f:]*:[0-9A-Fa-f:.]*", text))


def describe_network(s: Ros2Settings) -> str:
    """One phrase for the startup line."""
    if s.loopback_only:
        return "loopback only"
    where = f"interface {s.interface}" if s.interface else "all interfaces"
    how = "multicast discovery" if s.multicast else "no multicast"
    peers = f", peers {', '.join(s.peers)}" if s.peers else ""
    return f"{where}, {how}{peers}"


__all__ = [
    "EPROSIMA_VENDOR_ID",
    "MAX_DOMAIN_ID",
    "MAX_SAMPLE_BYTES",
    "TOPIC_KEYS",
    "Ros2Settings",
    "cyclone_config",
    "dds_topic",
    "describe_network",
    "from_table",
    "normalize_namespace",
    "parse_remap",
    "resolve_name",
    "split_cyclone_uri",
    "validate",
]
