"""Who may do what on a fleet's Zenoh network: four roles, the access control each base
and router enforces, and where an identity's files lie. Pure: names, dicts and text.

Every member of a fleet holds a certificate of the fleet's own authority (CA), its
common name its name, and talks only over mutual TLS (``tls/`` links, each side
checking the other's certificate against the CA). Who may do what is Zenoh's access
control (``access_control``: default deny, rules allowed per subject, each subject a
list of certificate common names), in the key expressions rmw_zenoh uses
(:mod:`omnican.zenoh.rmw`): ``<domain>/<namespace>/<topic>/<type>/<hash>`` for data and
services, ``@ros2_lv/<domain>/...`` for the liveliness tokens of the ROS graph.

- a **base** ``NAME`` runs under the namespace ``/NAME``: it publishes its telemetry and
  serves its services there and announces its node there, nowhere else;
- an **operator** may drive (``cmd_vel``), stop, recover and call every service;
- a **viewer** reads everything and may call ``~/stop`` (a stop is not a command), but
  neither publishes ``cmd_vel`` nor calls ``~/recover`` or another service;
- a **router** passes on what the others may send.

It is enforced where the traffic comes in, never by the sender's own file (which is its
own to change): a base checks every session linked to it directly (an operator's or a
viewer's peer link, the router's), and trusts its router for what comes through it; a
router checks every session linked to it. A certificate of the CA whose name is in no
list (a member removed) may open a link, and then nothing passes. Only bases announce
liveliness tokens, each in its own namespace: no operator or viewer can pose as a base.
rmw_zenoh's ``zenoh_security_tools`` makes a policy per node in the same keys; theirs
restricts what a node itself sends (a trusted node's file), these what others may do.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

from omnican.zenoh import rmw

ROLES = ("router", "base", "operator", "viewer")
#: the roles whose sessions enforce access control (operators and viewers only connect)
ENFORCING = ("router", "base")
#: Zenoh 1.1's access-control message kinds (1.0 has no liveliness ones).
MESSAGES = ("put", "delete", "declare_subscriber", "query", "reply", "declare_queryable",
            "liveliness_token", "declare_liveliness_subscriber", "liveliness_query")
LIVELINESS_READ = ("declare_liveliness_subscriber", "liveliness_query")
#: A base's name is its namespace, one ROS 2 name chunk.
_BASE_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]{0,63}$")
#: Others: a certificate common name that is also a folder name.
_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}$")
ROSTER_FILE = "omnican-fleet.json"
CA_CERT = "ca.pem"
CA_KEY = "ca.key"
CERT = "cert.pem"
KEY = "key.pem"
CONFIG = "zenoh.json5"
#: What a router's file listens on for zenohd (rmw_zenoh's port, every interface: only
#: holders of the fleet's certificates get a link, and the access control is theirs).
ROUTER_LISTEN = "tls/[::]:7447"


def check_name(role: str, name: str) -> str:
    """``name`` if it may name a ``role``; ValueError saying what a name may be."""
    if role not in ROLES:
        raise ValueError(f"{role!r} is not a role ({', '.join(ROLES)})")
    if role == "base":
        if not _BASE_NAME.match(name):
            raise ValueError(f"base name {name!r} is not a namespace chunk (a letter or _, "
                             "then letters, digits, _; at most 64): the base runs under /NAME")
    elif not _NAME.match(name) or name in (".", ".."):
        raise ValueError(f"{role} name {name!r}: letters, digits, _ . - (at most 64, not "
                         "starting with . or -)")
    return name


@dataclass(frozen=True)
class Identity:
    """Whose certificate a session presents: ``base/robot1``, ``operator/alice``."""

    role: str
    name: str

    @staticmethod
    def parse(text: str) -> Identity:
        """``ROLE/NAME``; ValueError naming what is wrong."""
        role, slash, name = text.partition("/")
        if not slash or role not in ROLES:
            raise ValueError(f"identity {text!r} is not ROLE/NAME with a role of "
                             f"{', '.join(ROLES)} (e.g. base/robot1)")
        check_name(role, name)
        return Identity(role, name)

    def __str__(self) -> str:
        return f"{self.role}/{self.name}"

    @property
    def folder(self) -> str:
        """Its folder under the credentials' root (relative)."""
        return f"{self.role}/{self.name}"

    @property
    def namespace(self) -> str:
        """A base's namespace (``/robot1``); "" for the other roles."""
        return f"/{self.name}" if self.role == "base" else ""


@dataclass(frozen=True)
class Roster:
    """A fleet's members by role, and its ROS domain: what ``omnican-fleet.json`` says."""

    domain_id: int = 0
    members: Mapping[str, tuple[str, ...]] = field(
        default_factory=lambda: {role: () for role in ROLES})

    def names(self, role: str) -> tuple[str, ...]:
        return tuple(self.members.get(role, ()))

    def role_of(self, name: str) -> str | None:
        return next((role for role in ROLES if name in self.names(role)), None)

    def identities(self) -> list[Identity]:
        return [Identity(role, name) for role in ROLES for name in self.names(role)]

    def adding(self, role: str, name: str) -> Roster:
        """With ``name`` as a ``role`` (as it is if it already is one); ValueError if the
        name is taken by another role (a certificate's name says one role)."""
        check_name(role, name)
        other = self.role_of(name)
        if other is not None and other != role:
            raise ValueError(f"{name!r} is already a {other}: one name, one role")
        if other == role:
            return self
        members = {r: self.names(r) for r in ROLES}
        members[role] = (*members[role], name)
        return replace(self, members=members)

    def to_json(self) -> str:
        return json.dumps({"omnican_fleet": 1, "domain_id": self.domain_id,
                           **{role: list(self.names(role)) for role in ROLES}}, indent=2) + "\n"

    @staticmethod
    def from_json(text: str) -> Roster:
        """The inverse of :meth:`to_json`; ValueError for what it did not write."""
        try:
            data = json.loads(text)
        except ValueError as exc:
            raise ValueError(f"not JSON ({exc})") from None
        if not isinstance(data, dict) or data.get("omnican_fleet") != 1:
            raise ValueError("not an omnican fleet roster")
        domain = data.get("domain_id")
        if isinstance(domain, bool) or not isinstance(domain, int) or not 0 <= domain <= 232:
            raise ValueError(f"domain_id {domain!r} is not 0..232")
        roster = Roster(domain)
        for role in ROLES:
            names = data.get(role, [])
            if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
                raise ValueError(f"{role}: not a list of names")
            for name in names:
                roster = roster.adding(role, name)
        return roster


# ------------------------------------------------------------ the key expressions


def data_keys(domain_id: int) -> list[str]:
    """Everything of the domain: its data and services, its liveliness tokens."""
    return [f"{domain_id}/**", f"{rmw.ADMIN_SPACE}/{domain_id}/**"]


def namespace_keys(domain_id: int, base: str) -> list[str]:
    """A base's data and services: under its namespace."""
    return [f"{domain_id}/{base}/**"]


def token_keys(domain_id: int, base: str) -> list[str]:
    """The liveliness tokens of nodes in a base's namespace: ``@ros2_lv/<domain>/<session>
    /<node>/<entity>/<kind>/<enclave>/%<base>/...`` (rmw's :meth:`~omnican.zenoh.rmw.RosNode.
    token` and :meth:`~omnican.zenoh.rmw.RosNode.endpoint_token`)."""
    return [f"{rmw.ADMIN_SPACE}/{domain_id}/*/*/*/*/*/{rmw.mangle('/' + base)}/**"]


def cmd_vel_keys(domain_id: int, base: str = "*") -> list[str]:
    return [f"{domain_id}/{base}/cmd_vel/**"]


def stop_keys(domain_id: int, base: str = "*") -> list[str]:
    """``~/stop`` of any node in the namespace (``/<base>/<node>/stop``)."""
    return [f"{domain_id}/{base}/*/stop/**"]


def _rule(rule_id: str, messages: Iterable[str], flow: str, keys: list[str]) -> dict[str, Any]:
    return {"id": rule_id, "messages": list(messages), "flows": [flow], "permission": "allow",
            "key_exprs": keys}


def _subject(subject_id: str, names: Iterable[str]) -> dict[str, Any]:
    return {"id": subject_id, "cert_common_names": sorted(names),
            "link_protocols": ["tls"]}


def _acl(rules: list[dict[str, Any]], grants: list[tuple[str, list[str], list[str]]]
         ) -> dict[str, Any]:
    """``access_control`` of ``rules`` and ``grants`` (subject id, names, rule ids); a
    subject without names is left out (Zenoh refuses an empty list, and a subject with
    no field at all would match everyone)."""
    kept = [(sid, names, rule_ids) for sid, names, rule_ids in grants if names]
    used = {rid for _, _, rule_ids in kept for rid in rule_ids}
    return {"enabled": True, "default_permission": "deny",
            "rules": [r for r in rules if r["id"] in used],
            "subjects": [_subject(sid, names) for sid, names, _ in kept],
            "policies": [{"id": sid, "rules": rule_ids, "subjects": [sid]}
                         for sid, _, rule_ids in kept]}


def base_acl(roster: Roster, name: str) -> dict[str, Any]:
    """What base ``name`` lets each member do on a link to it."""
    d = roster.domain_id
    everything = data_keys(d)
    rules = [
        _rule("send to members", MESSAGES, "egress", everything),
        _rule("from routers", MESSAGES, "ingress", everything),
        _rule("watch", ("declare_subscriber", *LIVELINESS_READ), "ingress", everything),
        _rule("stop", ("query",), "ingress", stop_keys(d, name)),
        _rule("drive", ("put",), "ingress", cmd_vel_keys(d, name)),
        _rule("call services", ("query",), "ingress", namespace_keys(d, name)),
        # Another process on the robot under the base's own certificate (an IMU driver,
        # say) is the base: it may publish and announce in the base's namespace, as the
        # router lets it (see router_acl).
        _rule("own namespace", ("put", "liveliness_token"), "ingress",
              namespace_keys(d, name) + token_keys(d, name)),
    ]
    return _acl(rules, [
        ("routers", list(roster.names("router")), ["send to members", "from routers"]),
        ("itself", [name], ["send to members", "watch", "own namespace"]),
        ("operators", list(roster.names("operator")),
         ["send to members", "watch", "stop", "drive", "call services"]),
        ("viewers", list(roster.names("viewer")), ["send to members", "watch", "stop"]),
        ("other bases", [b for b in roster.names("base") if b != name],
         ["send to members", "watch"]),
    ])


def router_acl(roster: Roster, name: str) -> dict[str, Any]:
    """What router ``name`` lets each member send through it (and other routers all)."""
    d = roster.domain_id
    everything = data_keys(d)
    rules = [
        _rule("send to members", MESSAGES, "egress", everything),
        _rule("from routers", MESSAGES, "ingress", everything),
        _rule("watch", ("declare_subscriber", *LIVELINESS_READ), "ingress", everything),
        _rule("stop", ("query",), "ingress", stop_keys(d)),
        _rule("drive", ("put",), "ingress", cmd_vel_keys(d)),
        _rule("call services", ("query",), "ingress", everything[:1]),
    ]
    grants: list[tuple[str, list[str], list[str]]] = [
        ("routers", [r for r in roster.names("router") if r != name],
         ["send to members", "from routers"]),
        ("operators", list(roster.names("operator")),
         ["send to members", "watch", "stop", "drive", "call services"]),
        ("viewers", list(roster.names("viewer")), ["send to members", "watch", "stop"]),
    ]
    for base in roster.names("base"):
        rule_id = f"base {base}"
        rules.append(_rule(rule_id, ("put", "declare_subscriber", "declare_queryable",
                                     "reply"), "ingress", namespace_keys(d, base)))
        rules.append(_rule(f"{rule_id} tokens", ("liveliness_token", "reply"), "ingress",
                           token_keys(d, base)))
        grants.append((f"base {base}", [base],
                       ["send to members", rule_id, f"{rule_id} tokens"]))
    return _acl(rules, grants)


def access_control(roster: Roster, who: Identity) -> dict[str, Any] | None:
    """The ``access_control`` of ``who``'s session: a base's or a router's; None for an
    operator or a viewer (what they may do is the bases' and routers' to say)."""
    if who.role == "base":
        return base_acl(roster, who.name)
    if who.role == "router":
        return router_acl(roster, who.name)
    return None


# ------------------------------------------------------------ the session's config


def tls_entries(ca: str, cert: str, key: str) -> list[tuple[str, str]]:
    """(path, JSON5 value) pairs for ``zenoh.Config.insert_json5``: TLS links only, each
    side presenting its certificate and checking the other's against the CA. A peer's
    name is not checked against its address (robots' addresses change; what it may do
    follows from the certificate's name, which the CA vouches for), as rmw_zenoh's
    security tools do."""
    tls = {"root_ca_certificate": ca, "listen_certificate": cert, "listen_private_key": key,
           "connect_certificate": cert, "connect_private_key": key, "enable_mtls": True,
           "verify_name_on_connect": False}
    return [("transport/link/protocols", json.dumps(["tls"])),
            ("transport/link/tls", json.dumps(tls))]


def session_config(roster: Roster, who: Identity, ca: str, cert: str, key: str
                   ) -> dict[str, Any]:
    """A whole Zenoh config for ``who`` (what its ``zenoh.json5`` holds), for programs
    other than omnican (zenohd, rmw_zenoh's ``ZENOH_SESSION_CONFIG_URI``): a router
    listens on :data:`ROUTER_LISTEN`; the others are peers on loopback, their router to
    be given (``connect``)."""
    router = who.role == "router"
    config: dict[str, Any] = {
        "mode": "router" if router else "peer",
        "connect": {"endpoints": []},
        "listen": {"endpoints": [ROUTER_LISTEN if router else "tls/127.0.0.1:0"]},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"link": {"protocols": ["tls"], "tls": json.loads(
            tls_entries(ca, cert, key)[1][1])}},
    }
    acl = access_control(roster, who)
    if acl is not None:
        config["access_control"] = acl
    return config


_ROLE_TEXT = {
    "router": "passes on what each member may send (listens on every interface for "
              "zenohd; omnican fleet --router listens where told)",
    "base": "publishes its telemetry and serves its services under its namespace; takes "
            "cmd_vel, recover and its other services from operators, stop from viewers "
            "too",
    "operator": "may drive, stop and recover (enforced by the bases and routers)",
    "viewer": "reads, and may call stop (enforced by the bases and routers)",
}


def config_text(roster: Roster, who: Identity, ca: str, cert: str, key: str,
                made: str) -> str:
    """``zenoh.json5``: :func:`session_config` (JSON, which JSON5 reads) under a comment
    saying whose it is and how it is used."""
    body = json.dumps(session_config(roster, who, ca, cert, key), indent=2)
    head = [
        f"// omnican fleet on domain {roster.domain_id}: {who} ({_ROLE_TEXT[who.role]}).",
        f"// Made by 'omnican zenoh credentials' on {made}; run it again to add members "
        "(every base's and router's file changes then).",
        f"// omnican reads it with --zenoh-credentials DIR --zenoh-identity {who}: only",
        "// access_control is read from here, the certificates are found in DIR.",
        "// Other programs (zenohd -c, rmw_zenoh's ZENOH_SESSION_CONFIG_URI) read it whole:",
        "// its paths are where the files were made; mode, connect and listen are theirs.",
    ]
    return "\n".join(head) + "\n" + body + "\n"
