"""Every omnican base on a Zenoh network, seen and stopped from one place, whatever else
is on that network.

A base announces itself with rmw_zenoh's liveliness token of a ``base_summary``
publisher and publishes its summary there, twice a second; :class:`Fleet` lists the
bases it hears (:class:`BaseView`) and asks them to stop or recover. Which tokens are
bases, and how they are found whatever a stranger declares, is
:mod:`omnican.zenoh.discovery`'s; the requests and their answers (each taken only from
the session that owns the service) :mod:`omnican.zenoh.calls`'.

A base whose token goes is LOST: its session closed, or the router dropped it. A killed
process's TCP link drops at once, and the router withdraws its tokens at once; a network
cut is noticed when the Zenoh lease expires (10 s by default: ``transport/link/tx/lease``
of the Zenoh config file, in ms). A base whose summary is older than
:data:`~omnican.zenoh.summary.SILENT_PERIODS` of its periods is SILENT: it is there, but
its telemetry does not come (a stalled process, a saturated link).

Commands are the bases' own ``~/stop`` and ``~/recover`` services (std_srvs/Trigger, in
rmw_zenoh's request/reply form: :mod:`omnican.zenoh.services`), the same path as a ROS 2
client's: :meth:`Fleet.request` sends every request first (one Zenoh query per base) and
the answers are collected as they come, each bounded by a timeout; a base that does not
answer in time is reported so, and one whose service nothing serves is reported at once.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

from omnican.zenoh.calls import ROUTER_TIMEOUT, TIMEOUT_S, Answer, Call, Caller, same_session
from omnican.zenoh.discovery import (
    DEFAULT_PERIOD_S,
    INVENTORY_AFTER_S,
    INVENTORY_LATEST_S,
    INVENTORY_QUIET_S,
    LOOKUP_AGAIN_S,
    MAX_LOOKUPS,
    MAX_TOKENS,
    MESSAGE_CHARS,
    QUERY_TIMEOUT_S,
    QUIET_S,
    STRING,
    SUMMARY_TOPIC,
    UNHEARD_S,
    Discovery,
    Entry,
    check,
)
from omnican.zenoh.summary import SILENT_PERIODS, Summary

__all__ = [
    "BAD", "DEFAULT_PERIOD_S", "INVENTORY_AFTER_S", "INVENTORY_LATEST_S", "INVENTORY_QUIET_S",
    "LOOKUP_AGAIN_S", "LOST", "MAX_LOOKUPS", "MAX_TOKENS", "MESSAGE_CHARS", "QUERY_TIMEOUT_S",
    "QUIET_S", "ROUTER_TIMEOUT", "SILENT", "STRING", "SUMMARY_TOPIC", "TIMEOUT_S", "UNHEARD",
    "UNHEARD_S", "Answer", "BaseView", "Call", "Fleet", "check", "same_session"]

LOST, BAD, SILENT, UNHEARD = "LOST", "BAD SUMMARY", "SILENT", "NOT HEARD"


@dataclass(frozen=True)
class BaseView:
    """One base as the fleet view shows it; ``summary`` None until one was read,
    ``age_s`` the time since (None: never). ``bad_summary``: why the newest summary was
    refused (None: it was not); ``conflict``: the other sessions that claim this name;
    ``heard``: False for a token whose summary never came (not listed as a base).
    ``key`` is its liveliness token, what a request addresses. Every text is printable
    (:func:`omnican.errors.printable`)."""

    name: str
    zid: str  # the base's Zenoh session id
    summary: Summary | None
    age_s: float | None
    lost: bool
    silent: bool
    bad_summary: str | None = None
    conflict: tuple[str, ...] = ()
    heard: bool = True
    key: str = field(default="", repr=False, compare=False)

    @property
    def state(self) -> str:
        """LOST, BAD SUMMARY, SILENT, NOT HEARD, or the base's own state (RUNNING,
        STOPPED, STARTING)."""
        if self.lost:
            return LOST
        if self.bad_summary is not None:
            return BAD
        if self.silent:
            return SILENT
        if not self.heard:
            return UNHEARD
        return self.summary.state if self.summary is not None else "?"

    def as_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"name": self.name, "zid": self.zid, "state": self.state,
                               "lost": self.lost, "silent": self.silent, "age_s": self.age_s,
                               "bad_summary": self.bad_summary,
                               "conflict": list(self.conflict)}
        if self.summary is not None:
            out["summary"] = self.summary.as_json()
        return out


class Fleet:
    """The bases reachable on ``session`` in ROS domain ``domain_id`` (see the module
    docstring). It owns the subscribers, not the session; a context manager.
    ``clock``: monotonic seconds (what ages and silence are measured in)."""

    def __init__(self, session: Any, domain_id: int = 0, *,
                 clock: Callable[[], float] = time.monotonic) -> None:
        import zenoh

        self.session = session
        self.domain_id = domain_id
        self.clock = clock
        self._closed = False
        self._cancel = zenoh.CancellationToken()  # every query of the fleet's, at close
        self._caller = Caller(session, clock, self._cancel)
        # Last: its callbacks start at once.
        self._discovery = Discovery(session, domain_id, clock, self._cancel)

    @property
    def inventory(self) -> float | None:
        """When the tokens already on the network were all in (None: not yet)."""
        return self._discovery.inventory

    @property
    def over_limit(self) -> int:
        """Tokens beyond :data:`MAX_TOKENS`: counted, not kept."""
        return self._discovery.over_limit

    @property
    def rejected(self) -> int:
        """Summaries of a base that could not be read."""
        return self._discovery.rejected

    @property
    def unclaimed(self) -> int:
        """Summaries no base's token claims (no GID of ours)."""
        return self._discovery.unclaimed

    @property
    def intruders(self) -> int:
        """Replies from a session that does not own the service."""
        return self._caller.intruders

    @property
    def gid(self) -> bytes:
        """The GID the fleet's requests carry (their answers must name it)."""
        return self._caller.gid

    @property
    def opened(self) -> float:
        """When the fleet started (its clock)."""
        return self._discovery.opened

    @property
    def summary_key(self) -> str:
        """The key expression of every base's summaries."""
        return self._discovery.summary_key

    @property
    def token_key(self) -> str:
        """The key expression of the tokens of base_summary publishers."""
        return self._discovery.token_key

    # ------------------------------------------------------------ what is shown

    def _view(self, entry: Entry, now: float) -> BaseView:
        summary, heard = entry.summary, entry.heard
        period = summary.period_s if summary is not None else DEFAULT_PERIOD_S
        last = max((t for t in (heard, entry.bad_at) if t is not None),
                   default=entry.found_at)
        bad = entry.bad if entry.bad_at is not None and (
            heard is None or entry.bad_at >= heard) else None
        entries, keys = self._discovery.entries, self._discovery.by_name[entry.name]
        conflict = tuple(sorted(entries[k].zid for k in keys
                                if k != entry.key and entries[k].lost_at is None)) \
            if entry.lost_at is None and len(keys) > 1 else ()
        return BaseView(entry.name, entry.zid, summary,
                        None if heard is None else max(0.0, now - heard),
                        entry.lost_at is not None,
                        entry.heard_from and now - last > SILENT_PERIODS * period,
                        bad, conflict, entry.heard_from, entry.key)

    def bases(self) -> list[BaseView]:
        """Every base (a token whose summary was heard), by name and session; a lost one
        stays (marked) until it comes back, or a new session of its name is heard."""
        now = self.clock()
        with self._discovery.lock:
            views = [self._view(e, now) for e in self._discovery.entries.values()
                     if e.heard_from]
        return sorted(views, key=lambda v: (v.name, v.zid))

    def unheard(self) -> list[BaseView]:
        """The tokens that announce a base but whose summary was not heard (not lost),
        but for those whose name a base heard from also has: a request to that base
        reaches every session serving that name already."""
        now = self.clock()
        with self._discovery.lock:
            entries = self._discovery.entries.values()
            heard = {e.name for e in entries if e.heard_from and e.lost_at is None}
            views = [self._view(e, now) for e in entries
                     if not e.heard_from and e.lost_at is None and e.name not in heard]
        return sorted(views, key=lambda v: (v.name, v.zid))

    def ignored(self) -> dict[str, int]:
        """How many tokens are not shown, by why: ``no summary``, ``not a base``, ``over
        the limit`` (:meth:`~omnican.zenoh.discovery.Discovery.ignored`)."""
        return self._discovery.ignored()

    def settled(self) -> bool:
        """Discovery is over (:meth:`~omnican.zenoh.discovery.Discovery.settled`): the
        tokens already there came, and each token's summary was heard or had its time."""
        return self._discovery.settled()

    def discover(self, timeout_s: float = TIMEOUT_S) -> int:
        """Wait until :meth:`settled` or ``timeout_s`` (in slices: Ctrl-C is heard);
        returns how many bases there are."""
        deadline = time.monotonic() + timeout_s
        while not self.settled() and time.monotonic() < deadline:
            time.sleep(min(0.05, max(0.0, deadline - time.monotonic())))
        return len(self.bases())

    def links(self) -> int:
        """How many Zenoh routers and peers this view's session is connected to now."""
        info = self.session.info
        return len(info.routers_zid()) + len(info.peers_zid())

    def find_all(self, name: str, heard: bool = True) -> list[BaseView]:
        """The bases called ``name``: their node name (``/robot1/omnican``) or, when the
        bases in that namespace share one node name, their namespace (``/robot1`` or
        ``robot1``). More than one: sessions claiming one name. ``heard`` False: tokens
        not heard from too."""
        views = self.bases() + (self.unheard() if not heard else [])
        exact = [v for v in views if v.name == name]
        if exact:
            return exact
        ns = "/" + name.strip("/")
        by_ns = [v for v in views if v.name.rsplit("/", 1)[0] == ns]
        return by_ns if len({v.name for v in by_ns}) == 1 else []

    def find(self, name: str) -> BaseView | None:
        """The one base called ``name`` (:meth:`find_all`); None for none, or for two
        sessions claiming it."""
        found = self.find_all(name)
        return found[0] if len(found) == 1 else None

    # ------------------------------------------------------------ commands

    def request(self, service: str, targets: Iterable[BaseView | str],
                timeout_s: float = TIMEOUT_S, *, unheard: bool = False) -> Call:
        """Call ``service`` (``stop``, ``recover``) of each target at once: every request
        goes out before any answer is awaited. A name (:meth:`find_all`, tokens not heard
        from included) asks every session that claims it; a name no token has is
        answered at once (no such base). ``unheard``: the targets are tokens not heard
        from (:meth:`stop_unheard_call`)."""
        chosen: list[BaseView] = []
        unknown: list[str] = []
        for target in targets:
            if isinstance(target, BaseView):
                chosen.append(target)
                continue
            found = self.find_all(target, heard=False)
            if not found:
                unknown.append(target)
            chosen += found
        discovery = self._discovery
        with discovery.lock:
            entries = [discovery.entries.get(view.key) for view in chosen]
        return self._caller.call(service, timeout_s, unheard, unknown,
                                   [(view.key, view.name, view.zid, entry)
                                    for view, entry in zip(chosen, entries, strict=True)])

    def stop(self, name: str, timeout_s: float = TIMEOUT_S) -> Answer:
        return self.request("stop", [name], timeout_s).wait()[0]

    def recover(self, name: str, timeout_s: float = TIMEOUT_S) -> Answer:
        return self.request("recover", [name], timeout_s).wait()[0]

    def stop_all(self, timeout_s: float = TIMEOUT_S) -> list[Answer]:
        """The fleet stop: every base not lost, all at once (then the tokens not heard
        from: :meth:`stop_unheard_call`); the bases' answers."""
        call = self.stop_all_call(timeout_s)
        self.stop_unheard_call(timeout_s)
        return call.wait()

    def stop_all_call(self, timeout_s: float = TIMEOUT_S) -> Call:
        """:meth:`stop_all` without waiting (a dashboard collects the answers): the bases
        heard from, first."""
        return self.request("stop", [v for v in self.bases() if not v.lost], timeout_s)

    def stop_unheard_call(self, timeout_s: float = TIMEOUT_S) -> Call:
        """The fleet stop's second wave: every token that announces a base but was not
        heard from (a base this view cannot hear may still serve its stop)."""
        return self.request("stop", self.unheard(), timeout_s, unheard=True)

    # ------------------------------------------------------------ lifecycle

    def close(self) -> None:
        """Undeclare the subscribers (idempotent); the session stays open."""
        if self._closed:
            return
        self._closed = True
        self._discovery.close()
        self._cancel.cancel()

    def __enter__(self) -> Fleet:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
