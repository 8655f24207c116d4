"""The ``[foxglove]`` table of a config: its keys (their types, defaults and meaning:
README's reference), the frozen :class:`FoxgloveTable` it becomes, the TLS files' paths
made whole against the config file's folder (:func:`omnican.live.settings.resolve`
checks the rest, with the command line's flags).

Pure: no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from omnican.config.front_ends import FrontEndTable, TableSpec
from omnican.config.reader import Reader, whole_path
from omnican.config.schema import Key, defaults_of

#: Read by the live view (--foxglove).
KEYS: dict[str, Key] = {
    "control": Key((bool,), False, "drive from Foxglove (Teleop panel, services, "
                   "parameters); --foxglove-control, off: the view only watches"),
    "cmd_vel_topic": Key((str,), "/cmd_vel", "topic Foxglove's Teleop panel publishes "
                         "geometry_msgs/Twist on"),
    "allow_remote": Key((bool,), False, "control on a server that other hosts can reach "
                        "(a host other than loopback); --foxglove-allow-remote"),
    "tls_cert": Key((str,), None, "PEM certificate (relative to the config file): serve "
                    "wss:// (a phone's browser needs it); with tls_key"),
    "tls_key": Key((str,), None, "PEM private key of tls_cert"),
    "origins": Key((list,), None, "web pages (Origin) whose browsers may connect, e.g. "
                   "[\"https://app.foxglove.dev\"], \"*\" any; default Foxglove's app "
                   "(app. and studio.foxglove.dev) and desktop (file://); "
                   "--foxglove-origin adds one"),
    "token": Key((str,), None, "a secret a client must give to drive (ws://host:port/"
                 "?token=...): without it, it may only watch; --foxglove-token"),
}

_D = defaults_of(KEYS)


@dataclass(frozen=True)
class FoxgloveTable(FrontEndTable):
    """The ``[foxglove]`` table, its types checked, the TLS files' paths whole (None:
    not given)."""

    control: bool = _D["control"]
    cmd_vel_topic: str = _D["cmd_vel_topic"]
    allow_remote: bool = _D["allow_remote"]
    tls_cert: str | None = _D["tls_cert"]
    tls_key: str | None = _D["tls_key"]
    origins: tuple[Any, ...] | None = _D["origins"]
    token: str | None = _D["token"]


def read(r: Reader, t: dict[str, Any], given: frozenset[str],
         base_dir: Path | None) -> FoxgloveTable:
    """The ``[foxglove]`` table, its types checked; the TLS files' paths relative to the
    config file made whole (omnican.live.settings checks the rest)."""
    for key in ("tls_cert", "tls_key"):
        t[key] = whole_path(t[key], base_dir)
    if t["origins"] is not None:
        t["origins"] = tuple(t["origins"])
    return FoxgloveTable(**t)


TABLE = TableSpec(KEYS, read)
