"""What the live view serves, and to whom: the ``[foxglove]`` table of the config and the
command line's flags, checked once (:func:`resolve`).

Control (driving from Foxglove) is off unless asked for. The server listens on loopback
unless a host is named; control on a server other hosts can reach needs its own flag
(``--foxglove-allow-remote``, ``[foxglove] allow_remote``), so that no one lets a whole
network drive the robot by naming ``0.0.0.0`` to watch it.

Who may connect: a browser only from the web pages of :attr:`FoxgloveSettings.origins`
(the WebSocket ``Origin`` header; by default Foxglove's app and its desktop build), any
program that sends no Origin. Who may drive: with a ``token`` set, only a client that gives
it (``ws://host:port/?token=...``, or ``Authorization: Bearer ...``); the others watch.
"""

from __future__ import annotations

import ipaddress
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from omnican.config import defaults_of
from omnican.errors import ConfigError
from omnican.live.table import KEYS

DEFAULT_HOST, DEFAULT_PORT = "127.0.0.1", 8765
_DEFAULTS = defaults_of(KEYS)
#: The first foxglove-sdk that tells the server's listener when a client leaves (it
#: unadvertises the client's channels; 0.25.2, "Fix a leak when disconnecting clients that
#: are still advertising"): without it the base could not stop when its driver leaves.
CONTROL_SDK = (0, 25, 2)
#: The web pages whose browsers may connect unless the config says otherwise: Foxglove's
#: app, on either of its addresses, and its desktop build (a page from file://).
DEFAULT_ORIGINS = ("https://app.foxglove.dev", "https://studio.foxglove.dev", "file://")
ANY_ORIGIN = "*"
_TOKEN_MAX = 256


def check_control_sdk() -> None:
    """ConfigError unless the installed foxglove-sdk can serve control safely."""
    from importlib.metadata import PackageNotFoundError, version

    from omnican.extras import install_hint

    try:
        have = version("foxglove-sdk")
    except PackageNotFoundError:
        raise ConfigError(f"--foxglove-control needs the Foxglove SDK: "
                          f"{install_hint('foxglove')}") from None
    numbers = tuple(int(p) if p.isdigit() else 0 for p in have.split(".")[:3])
    if numbers < CONTROL_SDK:
        need = ".".join(map(str, CONTROL_SDK))
        raise ConfigError(f"--foxglove-control needs foxglove-sdk {need} or later (it tells "
                          f"omnican when a client leaves, so the base can stop); this is "
                          f"{have}: pip install -U foxglove-sdk")


def is_loopback(host: str) -> bool:
    """Whether ``host`` (a name or an address) is this machine only."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def parse_address(text: str | None) -> tuple[str, int]:
    """``[HOST:]PORT`` (or empty: 127.0.0.1:8765) -> (host, port); ValueError if bad."""
    if not text:
        return DEFAULT_HOST, DEFAULT_PORT
    host, sep, port = text.rpartition(":")
    if not sep and not text.isdigit():
        host, port = text, str(DEFAULT_PORT)  # a bare host
    try:
        number = int(port)
    except ValueError:
        raise ValueError(f"want [HOST:]PORT, got {text!r}") from None
    if not 0 <= number <= 65535:
        raise ValueError(f"port must be 0-65535, got {number}")
    host = host.strip("[]") or DEFAULT_HOST
    return host, number


def normal_origin(text: str) -> str:
    """An Origin as browsers write it: lower case, no trailing slash."""
    return text.strip().lower().rstrip("/") if text.strip().lower() != "file://" else "file://"


def _origins(value: Any, where: str) -> tuple[str, ...]:
    from omnican.errors import quote

    if not isinstance(value, (list, tuple)):
        raise ConfigError(f"{where}: want a list of origins, got {quote(value)}")
    out = []
    for item in value:
        if not isinstance(item, str) or (item != ANY_ORIGIN and "://" not in item) \
                or any(c.isspace() for c in item.strip()):
            raise ConfigError(f"{where}: want an origin such as https://app.foxglove.dev or "
                              f"*, got {quote(item)}")
        out.append(item if item == ANY_ORIGIN else normal_origin(item))
    return tuple(dict.fromkeys(out))


def check_token(token: Any, where: str) -> str:
    """A token as given (printable, no spaces, so it fits a URL as it is); ConfigError
    naming what is wrong, never quoting it."""
    if not isinstance(token, str) or not token:
        raise ConfigError(f"{where}: want a non-empty text")
    if len(token) > _TOKEN_MAX:
        raise ConfigError(f"{where}: at most {_TOKEN_MAX} characters, got {len(token)}")
    if not all(c.isascii() and c.isprintable() and not c.isspace() and c not in "&#%+"
               for c in token):
        raise ConfigError(f"{where}: letters, digits and punctuation only (no spaces, &, #, "
                          "%, +: it goes in a URL as it is)")
    return token


@dataclass(frozen=True)
class FoxgloveSettings:
    """One live view's server: where it listens, whether clients may drive, TLS."""

    host: str = DEFAULT_HOST
    port: int = DEFAULT_PORT
    control: bool = _DEFAULTS["control"]
    cmd_vel_topic: str = _DEFAULTS["cmd_vel_topic"]
    allow_remote: bool = _DEFAULTS["allow_remote"]
    tls_cert: Path | None = None
    tls_key: Path | None = None
    #: Origins (``scheme://host[:port]``, lower case) a browser may connect from; "*" any.
    origins: tuple[str, ...] = DEFAULT_ORIGINS
    #: What a client must give to drive (None: every client that may connect may drive).
    token: str | None = None

    def origin_allowed(self, origin: str | None) -> bool:
        """Whether a client whose opening request carries this ``Origin`` header (None:
        none, not a browser) may connect."""
        if origin is None or ANY_ORIGIN in self.origins:
            return True
        return normal_origin(origin) in self.origins

    @property
    def remote(self) -> bool:
        """Other hosts can reach the server."""
        return not is_loopback(self.host)

    @property
    def scheme(self) -> str:
        return "wss" if self.tls_cert is not None else "ws"


def resolve(table: Mapping[str, Any] | None, address: str | None, *,
            control: bool | None = None, allow_remote: bool | None = None,
            token: str | None = None, origins: Sequence[str] = (),
            origin: str = "config", check_sdk: bool = True) -> FoxgloveSettings:
    """The settings of a live view: the ``[foxglove]`` table (schema-checked by the
    config), then the flags (None: not given; ``origins`` adds to the table's).
    ``address`` is ``--foxglove``'s ``[HOST:]PORT``. Raises ConfigError for what would
    be unsafe or cannot work (with ``check_sdk``, also an SDK too old for control)."""
    t = {**_DEFAULTS, **(table or {})}
    try:
        host, port = parse_address(address)
    except ValueError as exc:
        raise ConfigError(f"--foxglove: {exc}") from None
    topic = t["cmd_vel_topic"]
    if not topic or topic != topic.strip() or any(c.isspace() for c in topic):
        raise ConfigError(f"{origin}: foxglove.cmd_vel_topic: want a topic name, got {topic!r}")
    cert, key = t["tls_cert"], t["tls_key"]
    if (cert is None) != (key is None):
        given, missing = ("tls_cert", "tls_key") if cert is not None else ("tls_key", "tls_cert")
        raise ConfigError(f"{origin}: foxglove.{given} needs foxglove.{missing} too")
    s = FoxgloveSettings(
        host=host, port=port,
        control=bool(t["control"] if control is None else control),
        cmd_vel_topic=topic,
        allow_remote=bool(t["allow_remote"] if allow_remote is None else allow_remote),
        tls_cert=Path(cert) if cert is not None else None,
        tls_key=Path(key) if key is not None else None,
        origins=tuple(dict.fromkeys(
            (DEFAULT_ORIGINS if t["origins"] is None else _origins(t["origins"],
                                                                   f"{origin}: foxglove.origins"))
            + _origins(list(origins), "--foxglove-origin"))),
        token=(check_token(token, "--foxglove-token") if token is not None else
               check_token(t["token"], f"{origin}: foxglove.token")
               if t["token"] is not None else None))
    for name, path in (("tls_cert", s.tls_cert), ("tls_key", s.tls_key)):
        if path is not None and not path.is_file():
            raise ConfigError(f"{origin}: foxglove.{name}: no such file {path}")
    if s.control and check_sdk:
        check_control_sdk()
    if s.control and s.remote and not s.allow_remote:
        raise ConfigError(
            f"--foxglove-control on {host}:{port} lets anyone who reaches this host drive the "
            "robot: add --foxglove-allow-remote (or [foxglove] allow_remote = true) to mean "
            "it, or serve on 127.0.0.1")
    return s


def foxglove_address(text: str) -> str:
    """argparse type for ``--foxglove [HOST:]PORT``: checked here, so a bad address or a
    missing SDK is a usage error before any drive is touched."""
    import argparse
    import importlib.util

    try:
        parse_address(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    if importlib.util.find_spec("foxglove") is None:
        from omnican.extras import install_hint

        raise argparse.ArgumentTypeError(f"needs the Foxglove SDK: {install_hint('foxglove')}")
    return text


FOXGLOVE_HELP = ("serve a live view to Foxglove on [HOST:]PORT (default 127.0.0.1:8765; "
                 "loopback unless a host is given, e.g. 0.0.0.0:8765 to watch from another "
                 "machine)")
