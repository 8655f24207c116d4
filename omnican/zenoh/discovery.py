"""Which liveliness tokens on a Zenoh network are omnican bases: the fleet view's
bookkeeping of the tokens and the summaries it hears.

A base announces itself with rmw_zenoh's liveliness token of a ``base_summary``
publisher (``std_msgs/msg/String``: :mod:`omnican.zenoh.bridge` declares one) and
publishes its summary there, twice a second. :class:`Discovery` subscribes to the
summaries of every namespace (``<domain>/**/base_summary/...``) and to exactly those
tokens.

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
may ignore its timeout: nothing here waits on a query. :meth:`Discovery.settled` says
when discovery is over; a caller waits in short slices, so Ctrl-C and SIGTERM are heard.
"""

from __future__ import annotations

import logging
import re
import threading
import time
from collections.abc import Callable
from typing import Any

from omnican.errors import printable
from omnican.zenoh import rmw
from omnican.zenoh.summary import MAX_BYTES, SILENT_PERIODS, Summary, parse, text_of

logger = logging.getLogger(__name__)

STRING = "std_msgs/msg/String"
SUMMARY_TOPIC = "base_summary"
DEFAULT_PERIOD_S = 0.5  # a base's summary period until it says its own (2 Hz)
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


class Entry:
    """What the fleet knows of one token that announces a base (under the discovery's
    lock)."""

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


class Discovery:
    """The tokens and summaries heard on ``session`` in ROS domain ``domain_id`` (see the
    module docstring): a token's entry, found by its key (:attr:`entries`), its
    summaries' GID or its name (:attr:`by_name`), each read and written under
    :attr:`lock`. It owns the subscribers and the thread that asks for the tokens
    already there, not the session; ``cancel`` (a ``zenoh.CancellationToken``) ends its
    queries. ``clock``: monotonic seconds (what ages and silence are measured in)."""

    def __init__(self, session: Any, domain_id: int, clock: Callable[[], float],
                 cancel: Any) -> None:
        import zenoh

        self.session = session
        self.domain_id = domain_id
        self.clock = clock
        self.lock = threading.Lock()
        self.entries: dict[str, Entry] = {}  # token key -> entry
        self._by_gid: dict[bytes, Entry] = {}
        self.by_name: dict[str, set[str]] = {}  # name -> token keys
        self._ignored: dict[str, str] = {}  # token key -> why it is not a base
        self._gone: dict[str, float] = {}  # token key -> when it went (a late answer's)
        self._unclaimed: dict[str, tuple[bytes, bytes]] = {}  # topic -> newest (GID, CDR)
        self._lookups: dict[str, float] = {}  # topic -> when its tokens were asked for
        self._new_topic_at: float | None = None  # a topic's first unclaimed summary (real s)
        self.inventory: float | None = None  # when the tokens already there were all in
        self.over_limit = 0  # tokens beyond MAX_TOKENS: counted, not kept
        self.rejected = 0  # summaries of a base that could not be read
        self.unclaimed = 0  # summaries no base's token claims (no GID of ours)
        self.opened = clock()
        self._last_token = self.opened
        hash_ = rmw.type_hash(STRING)
        dds = rmw.dds_type_name(STRING)
        self.summary_key = f"{domain_id}/**/{SUMMARY_TOPIC}/{dds}/{hash_}"
        #: the tokens of base_summary publishers only (<enclave>/<namespace>/<node>, then
        #: the topic's chunk, which ends in %base_summary)
        self.token_key = (f"{rmw.ADMIN_SPACE}/{domain_id}/*/*/*/{rmw.Kind.PUBLISHER.value}"
                          f"/*/*/*/$*%{SUMMARY_TOPIC}/{dds}/{hash_}/*")
        self._closed = False
        self._zenoh = zenoh
        self._cancel = cancel  # every query of the fleet's, at close
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
            with self.lock:
                new = self._new_topic_at
                quiet = (now - start >= INVENTORY_AFTER_S and not self._lookups
                         and (new is None or now - new >= INVENTORY_QUIET_S))
            if quiet or now - start >= INVENTORY_LATEST_S:
                self._take_inventory()
                return

    def _take_inventory(self) -> None:
        """The tokens already on the network, asked for once."""
        def done() -> None:
            with self.lock:
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
            with self.lock:
                self._last_token = now
                if len(self._gone) < MAX_TOKENS:
                    self._gone[key] = now
                self._ignored.pop(key, None)
                entry = self.entries.get(key)
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
        with self.lock:
            self._last_token = now
            if since is not None and self._gone.get(key, -1.0) >= since:
                return  # an answer older than the token's going
            self._gone.pop(key, None)
            entry = self.entries.get(key)
            if entry is not None:
                if entry.lost_at is not None and since is None:  # declared again
                    entry.lost_at = None
                    logger.info("%s back (session %s)", entry.name, entry.zid)
                return
            if key in self._ignored:
                return
            if len(self.entries) + len(self._ignored) >= MAX_TOKENS:
                self.over_limit += 1
                return
            if token is None or why is not None:
                self._ignored[key] = why or "not a token"
                return
            entry = Entry(token, key, now)
            self.entries[key] = entry
            self._by_gid[entry.gid] = entry
            self.by_name.setdefault(entry.name, set()).add(key)
            kept = self._unclaimed.get(token.name)
            if kept is not None and kept[0] == entry.gid:
                del self._unclaimed[token.name]
        if kept is not None and kept[0] == entry.gid:
            self._read_summary(entry, kept[1])  # its summary came before its token

    def _forget(self, entry: Entry) -> None:
        del self.entries[entry.key]
        self._by_gid.pop(entry.gid, None)
        keys = self.by_name.get(entry.name)
        if keys is not None:
            keys.discard(entry.key)
            if not keys:
                del self.by_name[entry.name]

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
        with self.lock:
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
        with self.lock:
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
            with self.lock:
                if self._lookups.get(topic) == now:
                    del self._lookups[topic]
        try:
            self._ask_tokens(key, done)
        except Exception:  # a session closing under it
            done()

    def _read_summary(self, entry: Entry, cdr: bytes, size: int | None = None) -> None:
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
        with self.lock:
            first = not entry.heard_from
            entry.heard_from = True
            if summary is not None:
                entry.summary, entry.heard = summary, now
            else:
                entry.bad, entry.bad_at = why, now
                self.rejected += 1
            replaced = [self.entries[k] for k in self.by_name.get(entry.name, ())
                        if k != entry.key and self.entries[k].lost_at is not None] \
                if first else []
            for old in replaced:  # the base came back in a new session
                self._forget(old)
        if why is not None:
            logger.debug("a summary of %s refused: %s", entry.name, why)
        if first:
            logger.info("%s found (session %s)", entry.name, entry.zid)

    # ------------------------------------------------------------ what is known

    def ignored(self) -> dict[str, int]:
        """How many tokens are not shown, by why: ``no summary`` (heard nothing of their
        own for :data:`UNHEARD_S`: a fake, or a base this view cannot reach), ``not a
        base`` (:func:`check`), ``over the limit`` (:data:`MAX_TOKENS`)."""
        now = self.clock()
        with self.lock:
            unheard = sum(not e.heard_from and e.lost_at is None
                          and now - e.found_at >= UNHEARD_S for e in self.entries.values())
            return {"no summary": unheard, "not a base": len(self._ignored),
                    "over the limit": self.over_limit}

    def settled(self) -> bool:
        """Discovery is over: the tokens already there came (:data:`INVENTORY_AFTER_S`),
        some token came and none for :data:`QUIET_S`, no topic's tokens are being asked
        for, and each token's summary was heard or it had :data:`UNHEARD_S` to come."""
        now = self.clock()
        with self.lock:
            if self.inventory is None or not (self.entries or self._ignored) \
                    or now - self._last_token < QUIET_S \
                    or any(now - t < LOOKUP_AGAIN_S for t in self._lookups.values()):
                return False
            return all(e.heard_from or e.lost_at is not None or now - e.found_at >= UNHEARD_S
                       for e in self.entries.values())

    def close(self) -> None:
        """Stop asking for tokens and undeclare the subscribers (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self._stopping.set()
        self._inventory_thread.join()
        self._summary_sub.undeclare()
        self._tokens.undeclare()
