"""Every omnican base on a Zenoh network, seen and stopped from one place, whatever else
is on that network.

A base announces itself with rmw_zenoh's liveliness token of a ``base_summary``
publisher (``std_msgs/msg/String``: :mod:`omnican.zenoh.bridge` declares one) and
publishes its summary there, twice a second. :class:`Fleet` subscribes to the summaries
of every namespace (``<domain>/**/base_summary/...``) and to exactly those tokens.

Anyone on the network may declare a token, so a token alone is not a base:

- A base is keyed by its token, that is by its Zenoh session id and its node, never by
  its name alone: two sessions that claim one name are two entries, shown as a
  conflict, and one that comes and goes changes nothing of the other.
- A token becomes a base (listed, stopped by a fleet stop) once a summary of its own is
  heard: a summary carries its publisher's GID in its attachment, and a base's is
  :func:`~omnican.zenoh.rmw.gid_of` its token, so each summary belongs to one token,
  found in a dictionary (bounded work per sample, before anything is parsed). A token
  not heard from within :data:`UNHEARD_S` is ignored and counted (a stranger's fake, or
  a base whose telemetry this view cannot reach); a token that does not even read as a
  base (:func:`check`) is ignored and counted at once. At most :data:`MAX_TOKENS` are
  kept; the rest are counted.
- A summary that cannot be read (malformed, NaN, another node's name) makes its base
  BAD SUMMARY, with the reason.
- A service's answer is taken only from the session that owns the service (the token's
  session id; a Zenoh reply carries the id of the session that sent it): any other
  reply is an intruder's, counted and said.

Discovery goes from the summaries to the tokens, so that the bases that publish are
found first however many tokens a stranger declared: a summary whose GID no known token
has asks the network for the tokens of its one topic (a liveliness query of a few
tokens, answered in milliseconds; at most one per topic in flight, and
:data:`MAX_LOOKUPS` in all), and is read again when its token comes. The liveliness
subscriber has no history: tokens declared later come as they are declared, and the
tokens already there are asked for once, when the bases that publish have been found:
:data:`INVENTORY_AFTER_S` after the fleet starts, once no summary of a topic not seen
before came for :data:`INVENTORY_QUIET_S` and no topic's query is on its way, and at
the latest :data:`INVENTORY_LATEST_S` after the start. Zenoh answers a session's
queries one after the other, and thousands of tokens take seconds (during which the
summaries come late, and a stop would go late): the summaries' own queries, and the
stops of the bases they found, go first. Zenoh 1.x
answers a liveliness query late or never on a session with a history subscriber, and
may ignore its timeout: nothing here waits on a query. :meth:`Fleet.settled` says when
discovery is over; a caller waits in short slices, so Ctrl-C and SIGTERM are heard.

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

import logging
import re
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

from omnican.errors import printable
from omnican.log_throttle import Throttle
from omnican.zenoh import rmw
from omnican.zenoh.services import TRIGGER_REQUEST, read_trigger_response, service_key
from omnican.zenoh.summary import MAX_BYTES, SILENT_PERIODS, Summary, parse, text_of

logger = logging.getLogger(__name__)

STRING = "std_msgs/msg/String"
SUMMARY_TOPIC = "base_summary"
DEFAULT_PERIOD_S = 0.5  # a base's summary period until it says its own (2 Hz)
TIMEOUT_S = 2.0  # how long a command waits for each base's answer
#: A token whose summary is not heard within this long is ignored (three default periods).
UNHEARD_S = SILENT_PERIODS * DEFAULT_PERIOD_S
#: Discovery has settled when no token came for this long (the tokens already on the
#: network come in one burst when the subscriber is declared).
QUIET_S = 0.3
#: Tokens kept (bases, and tokens ignored for what they are); more are only counted.
MAX_TOKENS = 20_000
#: When the fleet asks for the tokens already on the network (see the module docstring):
#: not before a base at the default rate has sent a summary, once no new topic's summary
#: came for more than a default period, and at the latest after a few periods.
INVENTORY_AFTER_S = 1.2 * DEFAULT_PERIOD_S
INVENTORY_QUIET_S = 1.2 * DEFAULT_PERIOD_S
INVENTORY_LATEST_S = 6 * DEFAULT_PERIOD_S
MAX_LOOKUPS = 64  # a topic's token queries in flight at once
LOOKUP_AGAIN_S = 1.0  # a topic whose summaries are still unclaimed is asked again after
QUERY_TIMEOUT_S = 10.0  # Zenoh's bound on a liveliness query (not waited for)
MESSAGE_CHARS = 200  # characters shown of a peer's message
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")  # a ROS 2 node name or namespace chunk
_ZID = re.compile(r"^[0-9a-f]{1,32}$")  # a Zenoh id as rmw_zenoh writes it

LOST, BAD, SILENT, UNHEARD = "LOST", "BAD SUMMARY", "SILENT", "NOT HEARD"


def check(token: rmw.Token, domain_id: int) -> str | None:
    """Why ``token`` cannot be a base's in ``domain_id`` (None: it can): a base's summary
    publisher, in its node's namespace, with ROS 2 names and a Zenoh session id."""
    node = token.node
    if node.domain_id != domain_id:
        return f"domain {node.domain_id}, not {domain_id}"
    if token.kind is not rmw.Kind.PUBLISHER or token.type_name != STRING:
        return "not a String publisher"
    if not _ZID.match(node.session_id):
        return "its session id is not a Zenoh id"
    chunks = [c for c in node.namespace.split("/") if c]
    if not _NAME.match(node.name) or not all(_NAME.match(c) for c in chunks):
        return "its node's name is not a ROS 2 name"
    if token.name != rmw.fully_qualified(node.namespace, SUMMARY_TOPIC):
        return "not its node's base_summary"
    return None


#: the error a Zenoh router replies with, in the name of the session it asked, when that
#: session's answer did not come within the query's timeout (zenoh's QueryCleanup: its
#: responder id is the asked session's): no answer from that base, not its error
ROUTER_TIMEOUT = "Timeout"


def same_session(a: str, b: str) -> bool:
    """Two Zenoh ids written as hex (a token's, a reply's) name one session."""
    return a.lower().lstrip("0") == b.lower().lstrip("0")


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


@dataclass(frozen=True)
class Answer:
    """One base's answer to a command: ``answered`` False when none came from it;
    ``intruders``: the other sessions that replied to it (their replies ignored)."""

    name: str
    answered: bool
    success: bool
    message: str
    zid: str = ""
    intruders: tuple[str, ...] = ()

    def __str__(self) -> str:
        text = (f"{self.name}: no answer ({self.message})" if not self.answered else
                f"{self.name}: {'ok' if self.success else 'refused'}: {self.message}")
        if self.intruders:
            n = len(self.intruders)
            who = "another session" if n == 1 else f"{n} other sessions"
            text += (f" [ignored: a reply from {who} ({', '.join(self.intruders[:3])}"
                     f"{', ...' if n > 3 else ''}): an intruder on its service]")
        return text


class Call:
    """Requests on their way (:meth:`Fleet.request`): :meth:`done` once every base
    answered or its query ended; :meth:`answers` in the order asked."""

    def __init__(self, service: str, timeout_s: float, unheard: bool = False) -> None:
        self.service = service
        self.timeout_s = timeout_s
        self.unheard = unheard  # to tokens not heard from (:meth:`Fleet.stop_unheard_call`)
        self._order: list[str] = []  # the targets (their tokens), in the order asked
        self._labels: dict[str, tuple[str, str]] = {}  # target -> (name, session)
        self._answers: dict[str, Answer] = {}
        self._intruders: dict[str, list[str]] = {}
        self._cond = threading.Condition()

    @property
    def names(self) -> list[str]:
        return [self._labels[t][0] for t in self._order]

    def _add(self, target: str, name: str, zid: str) -> None:
        self._order.append(target)
        self._labels[target] = (name, zid)

    def _settle(self, target: str, answered: bool, success: bool, message: str) -> None:
        name, zid = self._labels[target]
        with self._cond:
            if target not in self._answers:  # the first one counts
                self._answers[target] = Answer(name, answered, success, message, zid)
            self._cond.notify_all()

    def _intrude(self, target: str, zid: str) -> None:
        with self._cond:
            seen = self._intruders.setdefault(target, [])
            if printable(zid, 40) not in seen:
                seen.append(printable(zid, 40))

    def done(self) -> bool:
        with self._cond:
            return len(self._answers) == len(self._order)

    def wait(self, timeout_s: float | None = None) -> list[Answer]:
        """Block until :meth:`done` (or ``timeout_s``, default the call's timeout and a
        second), in slices (a signal is heard); bases still silent then have no answer."""
        limit = time.monotonic() + (self.timeout_s + 1.0 if timeout_s is None else timeout_s)
        with self._cond:
            while len(self._answers) < len(self._order):
                left = limit - time.monotonic()
                if left <= 0:
                    break
                self._cond.wait(min(left, 0.1))
        return self.answers()

    def answers(self) -> list[Answer]:
        with self._cond:
            got, intruders = dict(self._answers), {k: tuple(v) for k, v in
                                                   self._intruders.items()}
        out = []
        for target in self._order:
            name, zid = self._labels[target]
            answer = got.get(target) or Answer(name, False, False,
                                               f"none within {self.timeout_s:g} s", zid)
            if target in intruders:
                answer = Answer(answer.name, answer.answered, answer.success, answer.message,
                                answer.zid, intruders[target])
            out.append(answer)
        return out


class _Entry:
    """What the fleet knows of one token that announces a base (under the fleet's lock)."""

    __slots__ = ("bad", "bad_at", "found_at", "gid", "heard", "heard_from", "key", "lost_at",
                 "name", "summary", "token", "zid")

    def __init__(self, token: rmw.Token, key: str, now: float) -> None:
        self.token, self.key, self.found_at = token, key, now
        self.name = printable(token.node_name)
        self.zid = printable(token.node.session_id)
        self.gid = rmw.gid_of(key)  # its summaries' GID (what the bridge gives them)
        self.heard_from = False  # a summary of its own came (good or bad): a base
        self.summary: Summary | None = None  # the newest good one, heard at ``heard``
        self.heard: float | None = None
        self.bad: str | None = None  # why the newest refused one was, at ``bad_at``
        self.bad_at: float | None = None
        self.lost_at: float | None = None


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
        self._lock = threading.Lock()
        self._entries: dict[str, _Entry] = {}  # token key -> entry
        self._by_gid: dict[bytes, _Entry] = {}
        self._by_name: dict[str, set[str]] = {}  # name -> token keys
        self._ignored: dict[str, str] = {}  # token key -> why it is not a base
        self._gone: dict[str, float] = {}  # token key -> when it went (a late answer's)
        self._unclaimed: dict[str, tuple[bytes, bytes]] = {}  # topic -> newest (GID, CDR)
        self._lookups: dict[str, float] = {}  # topic -> when its tokens were asked for
        self._new_topic_at: float | None = None  # a topic's first unclaimed summary (real s)
        self.inventory: float | None = None  # when the tokens already there were all in
        self.over_limit = 0  # tokens beyond MAX_TOKENS: counted, not kept
        self.rejected = 0  # summaries of a base that could not be read
        self.unclaimed = 0  # summaries no base's token claims (no GID of ours)
        self.intruders = 0  # replies from a session that does not own the service
        self._throttle = Throttle(logger)
        self.opened = clock()
        self._last_token = self.opened
        self._seq = 0
        self.gid = rmw.gid_of(f"omnican fleet {session.info.zid()}")
        hash_ = rmw.type_hash(STRING)
        dds = rmw.dds_type_name(STRING)
        self.summary_key = f"{domain_id}/**/{SUMMARY_TOPIC}/{dds}/{hash_}"
        #: the tokens of base_summary publishers only (<enclave>/<namespace>/<node>, then
        #: the topic's chunk, which ends in %base_summary)
        self.token_key = (f"{rmw.ADMIN_SPACE}/{domain_id}/*/*/*/{rmw.Kind.PUBLISHER.value}"
                          f"/*/*/*/$*%{SUMMARY_TOPIC}/{dds}/{hash_}/*")
        self._closed = False
        self._zenoh = zenoh
        self._cancel = zenoh.CancellationToken()  # every query of the fleet's, at close
        # Last: their callbacks start at once.
        self._tokens = session.liveliness().declare_subscriber(self.token_key, self._on_token)
        self._summary_sub = session.declare_subscriber(self.summary_key, self._on_summary)
        self._stopping = threading.Event()
        self._inventory_thread = threading.Thread(target=self._inventory_when_ready,
                                                  name="omnican-fleet-inventory", daemon=True)
        self._inventory_thread.start()

    # ------------------------------------------------------------ what is heard

    def _on_token(self, sample: Any) -> None:
        try:
            self._token_changed(str(sample.key_expr),
                                sample.kind == self._zenoh.SampleKind.DELETE)
        except Exception:  # in Zenoh's thread: say it, never stop hearing
            logger.exception("a liveliness token not handled")

    def _ask_tokens(self, key_expr: str, done: Callable[[], None]) -> None:
        """A liveliness query for the tokens ``key_expr`` matches, answered into
        :meth:`_token_changed` (a token that went since it was sent is not taken);
        ``done`` when it ends. Nothing waits for it."""
        sent = self.clock()

        def on_reply(reply: Any) -> None:
            try:
                if reply.ok is not None:
                    self._token_changed(str(reply.ok.key_expr), False, since=sent)
            except Exception:  # in Zenoh's thread: say it, never stop hearing
                logger.exception("a liveliness token not handled")

        self.session.liveliness().get(key_expr, self._zenoh.handlers.Callback(on_reply, done),
                                      timeout=QUERY_TIMEOUT_S,
                                      cancellation_token=self._cancel)

    def _inventory_when_ready(self) -> None:
        """:meth:`_take_inventory`, when the bases that publish were found (see the
        module docstring); in real time, whatever the fleet's clock."""
        start = time.monotonic()
        while not self._stopping.wait(0.05):
            now = time.monotonic()
            with self._lock:
                new = self._new_topic_at
                quiet = (now - start >= INVENTORY_AFTER_S and not self._lookups
                         and (new is None or now - new >= INVENTORY_QUIET_S))
            if quiet or now - start >= INVENTORY_LATEST_S:
                self._take_inventory()
                return

    def _take_inventory(self) -> None:
        """The tokens already on the network, asked for once."""
        def done() -> None:
            with self._lock:
                self.inventory = self.clock()
                self._last_token = self.inventory
        if self._closed:
            return
        try:
            self._ask_tokens(self.token_key, done)
        except Exception:  # a session closing under it
            logger.debug("the tokens already there not asked for", exc_info=True)

    def _token_changed(self, key: str, gone: bool, since: float | None = None) -> None:
        now = self.clock()
        if gone:
            with self._lock:
                self._last_token = now
                if len(self._gone) < MAX_TOKENS:
                    self._gone[key] = now
                self._ignored.pop(key, None)
                entry = self._entries.get(key)
                if entry is None or entry.lost_at is not None:
                    return
                if not entry.heard_from:  # never a base: forgotten
                    self._forget(entry)
                    return
                entry.lost_at = now
            logger.info("%s lost (session %s: its token went)", entry.name, entry.zid)
            return
        try:
            token: rmw.Token | None = rmw.parse_token(key)
            why = check(token, self.domain_id) if token is not None else None
        except ValueError:
            token, why = None, "not an rmw_zenoh token"
        with self._lock:
            self._last_token = now
            if since is not None and self._gone.get(key, -1.0) >= since:
                return  # an answer older than the token's going
            self._gone.pop(key, None)
            entry = self._entries.get(key)
            if entry is not None:
                if entry.lost_at is not None and since is None:  # declared again
                    entry.lost_at = None
                    logger.info("%s back (session %s)", entry.name, entry.zid)
                return
            if key in self._ignored:
                return
            if len(self._entries) + len(self._ignored) >= MAX_TOKENS:
                self.over_limit += 1
                return
            if token is None or why is not None:
                self._ignored[key] = why or "not a token"
                return
            entry = _Entry(token, key, now)
            self._entries[key] = entry
            self._by_gid[entry.gid] = entry
            self._by_name.setdefault(entry.name, set()).add(key)
            kept = self._unclaimed.get(token.name)
            if kept is not None and kept[0] == entry.gid:
                del self._unclaimed[token.name]
        if kept is not None and kept[0] == entry.gid:
            self._read_summary(entry, kept[1])  # its summary came before its token

    def _forget(self, entry: _Entry) -> None:
        del self._entries[entry.key]
        self._by_gid.pop(entry.gid, None)
        keys = self._by_name.get(entry.name)
        if keys is not None:
            keys.discard(entry.key)
            if not keys:
                del self._by_name[entry.name]

    def _on_summary(self, sample: Any) -> None:
        try:
            self._summary_came(sample)
        except Exception:  # in Zenoh's thread: say it, never stop hearing
            logger.exception("a summary not handled")

    def _summary_came(self, sample: Any) -> None:
        raw = sample.attachment
        try:
            gid = rmw.Attachment.decode(raw.to_bytes() if raw is not None else b"").gid
        except ValueError:
            gid = b""
        size = len(sample.payload)
        with self._lock:
            entry = self._by_gid.get(gid)
            if entry is None:
                self.unclaimed += 1  # no token known claims it: not read (yet)
        if entry is None:
            if gid and size <= MAX_BYTES:
                self._claim(rmw.topic_of(str(sample.key_expr)), gid,
                            sample.payload.to_bytes())
            return
        if entry.lost_at is not None:
            return
        self._read_summary(entry, sample.payload.to_bytes() if size <= MAX_BYTES else b"",
                           size)

    def _claim(self, topic: str, gid: bytes, cdr: bytes) -> None:
        """A summary no known token claims: kept (the newest of its topic), and the
        tokens of its topic asked for, once at a time (see the module docstring)."""
        chunks = topic.split("/")[1:-1]
        if not all(_NAME.match(c) for c in chunks):
            return  # no base's namespace
        now = self.clock()
        with self._lock:
            if topic not in self._unclaimed:
                self._new_topic_at = time.monotonic()
            if topic in self._unclaimed or len(self._unclaimed) < MAX_TOKENS:
                self._unclaimed[topic] = (gid, cdr)
            for old in [t for t, at in self._lookups.items() if now - at > QUERY_TIMEOUT_S]:
                del self._lookups[old]  # a query Zenoh never ended
            asked = self._lookups.get(topic)
            if (asked is not None and now - asked < LOOKUP_AGAIN_S) or \
                    len(self._lookups) >= MAX_LOOKUPS:
                return
            self._lookups[topic] = now
        # the tokens of this topic's publishers in its namespace, whatever their node
        ns = rmw.mangle("/" + "/".join(chunks))
        key = (f"{rmw.ADMIN_SPACE}/{self.domain_id}/*/*/*/{rmw.Kind.PUBLISHER.value}/*/{ns}/*/"
               f"{rmw.mangle(topic)}/{rmw.dds_type_name(STRING)}/{rmw.type_hash(STRING)}/*")

        def done() -> None:
            with self._lock:
                if self._lookups.get(topic) == now:
                    del self._lookups[topic]
        try:
            self._ask_tokens(key, done)
        except Exception:  # a session closing under it
            done()

    def _read_summary(self, entry: _Entry, cdr: bytes, size: int | None = None) -> None:
        """``entry``'s summary (its CDR) read: its base heard, or BAD SUMMARY and why."""
        summary: Summary | None = None
        why: str | None = None
        try:
            if size is not None and size > MAX_BYTES:
                raise ValueError(f"{size} bytes, more than a summary's {MAX_BYTES}")
            read = parse(text_of(cdr))
            if read.node != entry.name:
                raise ValueError(f"it names node {read.node!r}, its token {entry.name!r}")
            summary = read
        except ValueError as exc:
            why = printable(str(exc), MESSAGE_CHARS)
        now = self.clock()
        with self._lock:
            first = not entry.heard_from
            entry.heard_from = True
            if summary is not None:
                entry.summary, entry.heard = summary, now
            else:
                entry.bad, entry.bad_at = why, now
                self.rejected += 1
            replaced = [self._entries[k] for k in self._by_name.get(entry.name, ())
                        if k != entry.key and self._entries[k].lost_at is not None] \
                if first else []
            for old in replaced:  # the base came back in a new session
                self._forget(old)
        if why is not None:
            logger.debug("a summary of %s refused: %s", entry.name, why)
        if first:
            logger.info("%s found (session %s)", entry.name, entry.zid)

    # ------------------------------------------------------------ what is shown

    def _view(self, entry: _Entry, now: float) -> BaseView:
        summary, heard = entry.summary, entry.heard
        period = summary.period_s if summary is not None else DEFAULT_PERIOD_S
        last = max((t for t in (heard, entry.bad_at) if t is not None),
                   default=entry.found_at)
        bad = entry.bad if entry.bad_at is not None and (
            heard is None or entry.bad_at >= heard) else None
        conflict = tuple(sorted(self._entries[k].zid for k in self._by_name[entry.name]
                                if k != entry.key and self._entries[k].lost_at is None)) \
            if entry.lost_at is None and len(self._by_name[entry.name]) > 1 else ()
        return BaseView(entry.name, entry.zid, summary,
                        None if heard is None else max(0.0, now - heard),
                        entry.lost_at is not None,
                        entry.heard_from and now - last > SILENT_PERIODS * period,
                        bad, conflict, entry.heard_from, entry.key)

    def bases(self) -> list[BaseView]:
        """Every base (a token whose summary was heard), by name and session; a lost one
        stays (marked) until it comes back, or a new session of its name is heard."""
        now = self.clock()
        with self._lock:
            views = [self._view(e, now) for e in self._entries.values() if e.heard_from]
        return sorted(views, key=lambda v: (v.name, v.zid))

    def unheard(self) -> list[BaseView]:
        """The tokens that announce a base but whose summary was not heard (not lost),
        but for those whose name a base heard from also has: a request to that base
        reaches every session serving that name already."""
        now = self.clock()
        with self._lock:
            heard = {e.name for e in self._entries.values()
                     if e.heard_from and e.lost_at is None}
            views = [self._view(e, now) for e in self._entries.values()
                     if not e.heard_from and e.lost_at is None and e.name not in heard]
        return sorted(views, key=lambda v: (v.name, v.zid))

    def ignored(self) -> dict[str, int]:
        """How many tokens are not shown, by why: ``no summary`` (heard nothing of their
        own for :data:`UNHEARD_S`: a fake, or a base this view cannot reach), ``not a
        base`` (:func:`check`), ``over the limit`` (:data:`MAX_TOKENS`)."""
        now = self.clock()
        with self._lock:
            unheard = sum(not e.heard_from and e.lost_at is None
                          and now - e.found_at >= UNHEARD_S for e in self._entries.values())
            return {"no summary": unheard, "not a base": len(self._ignored),
                    "over the limit": self.over_limit}

    def settled(self) -> bool:
        """Discovery is over: the tokens already there came (:data:`INVENTORY_AFTER_S`),
        some token came and none for :data:`QUIET_S`, no topic's tokens are being asked
        for, and each token's summary was heard or it had :data:`UNHEARD_S` to come."""
        now = self.clock()
        with self._lock:
            if self.inventory is None or not (self._entries or self._ignored) \
                    or now - self._last_token < QUIET_S \
                    or any(now - t < LOOKUP_AGAIN_S for t in self._lookups.values()):
                return False
            return all(e.heard_from or e.lost_at is not None or now - e.found_at >= UNHEARD_S
                       for e in self._entries.values())

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
        call = Call(service, timeout_s, unheard)
        chosen: list[BaseView] = []
        for target in targets:
            if isinstance(target, BaseView):
                chosen.append(target)
                continue
            found = self.find_all(target, heard=False)
            if not found:
                key = f"unknown:{target}"
                if key not in call._labels:
                    call._add(key, printable(target, 80), "")
                    call._settle(key, False, False, "no such base")
            chosen += found
        groups: dict[str, list[_Entry]] = {}  # one query per service key: every
        for view in chosen:  # session claiming that name's queryable answers it
            with self._lock:
                entry = self._entries.get(view.key)
            if view.key in call._labels:
                continue
            call._add(view.key, view.name, view.zid)
            if entry is None:
                call._settle(view.key, False, False, "its token went: forgotten")
                continue
            groups.setdefault(service_key(entry.token.node, service), []).append(entry)
        for key, entries in groups.items():
            with self._lock:
                self._seq += 1
                seq = self._seq
            self._ask(call, key, entries, seq)
        return call

    def _ask(self, call: Call, key: str, entries: list[_Entry], seq: int) -> None:
        """One query on ``key``; each reply is its sender's answer if that session owns
        one of ``entries`` (their tokens' session ids), else an intruder's."""
        zenoh = self._zenoh
        sent = time.monotonic()
        timed_out = threading.Event()

        def owner(replier: str) -> _Entry | None:
            return next((e for e in entries if same_session(e.token.node.session_id,
                                                            replier)), None)

        def on_reply(reply: Any) -> None:
            rid = reply.replier_id
            replier = str(rid.zid) if rid is not None else None
            if replier is None:  # Zenoh's own (a timeout): no session answered this
                timed_out.set()
                return
            entry = owner(replier)
            if entry is None:
                with self._lock:
                    self.intruders += 1
                for e in entries:
                    call._intrude(e.key, replier)
                self._throttle.log(logging.WARNING, "intruder",
                                   "%s %s: a reply from session %s ignored (the service is "
                                   "session %s's): an intruder", call.service,
                                   entries[0].name, printable(replier, 40),
                                   ", ".join(e.zid for e in entries))
                return
            if reply.ok is None:
                text = reply.err.payload.to_bytes().decode("utf-8", "replace")
                if text == ROUTER_TIMEOUT:  # a router gave up on the base for it
                    timed_out.set()
                    call._settle(entry.key, False, False,
                                 f"none within {call.timeout_s:g} s")
                    return
                call._settle(entry.key, True, False,
                             f"error: {printable(text, MESSAGE_CHARS)}")
                return
            try:
                raw = reply.ok.attachment
                att = rmw.Attachment.decode(raw.to_bytes() if raw is not None else b"")
                if (att.sequence, att.gid) != (seq, self.gid):
                    raise ValueError("it answers another request")
                ok, message = read_trigger_response(reply.ok.payload.to_bytes())
            except ValueError as exc:
                call._settle(entry.key, True, False,
                             f"unreadable answer: {printable(str(exc), MESSAGE_CHARS)}")
                return
            call._settle(entry.key, True, ok, printable(message, MESSAGE_CHARS))

        def finished() -> None:  # every reply in, or the query's timeout
            took = time.monotonic() - sent
            if timed_out.is_set() or took >= call.timeout_s:
                why = f"none within {call.timeout_s:g} s"
            else:
                why = (f"nothing serves its {call.service} service: the query ended after "
                       f"{took:.2f} s")
            for e in entries:
                lost = (f"lost {self.clock() - e.lost_at:.0f} s ago; "
                        if e.lost_at is not None else "")
                call._settle(e.key, False, False, lost + why)

        attachment = rmw.Attachment(seq, time.time_ns(), self.gid).encode()
        # cancelled at close: no callback of ours may run once Python is shutting down
        self.session.get(key, zenoh.handlers.Callback(on_reply, finished),
                         payload=TRIGGER_REQUEST, attachment=attachment,
                         target=zenoh.QueryTarget.ALL_COMPLETE,
                         consolidation=zenoh.ConsolidationMode.NONE, timeout=call.timeout_s,
                         cancellation_token=self._cancel)

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
        self._stopping.set()
        self._inventory_thread.join()
        self._summary_sub.undeclare()
        self._tokens.undeclare()
        self._cancel.cancel()

    def __enter__(self) -> Fleet:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
