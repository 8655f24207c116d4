"""Every omnican base on a Zenoh network, seen and stopped from one place.

A base is a node whose liveliness token announces a ``base_summary`` publisher of type
``std_msgs/msg/String`` (:mod:`omnican.zenoh.bridge` declares one); its name is the
node's fully qualified name (``/robot1/omnican``). :class:`Fleet` finds bases with a
liveliness subscriber (with history: the tokens already there come at once) on
``@ros2_lv/<domain>/**``, and keeps each base's newest summary from one subscriber on
the ``base_summary`` key of every namespace (``<domain>/**/base_summary/...``).

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
answer in time is reported so.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

from omnican.zenoh import rmw
from omnican.zenoh.services import TRIGGER_REQUEST, read_trigger_response, service_key
from omnican.zenoh.summary import SILENT_PERIODS, Summary, parse

logger = logging.getLogger(__name__)

STRING = "std_msgs/msg/String"
SUMMARY_TOPIC = "base_summary"
DEFAULT_PERIOD_S = 0.5  # a base's summary period until it says its own (2 Hz)
TIMEOUT_S = 2.0  # how long a command waits for each base's answer


@dataclass(frozen=True)
class BaseView:
    """One base as the fleet view shows it; ``summary`` None until one was heard,
    ``age_s`` the time since (None: never)."""

    name: str
    zid: str  # the base's Zenoh session id
    summary: Summary | None
    age_s: float | None
    lost: bool
    silent: bool

    @property
    def state(self) -> str:
        """LOST, SILENT, or the base's own state (RUNNING, STOPPED, STARTING)."""
        if self.lost:
            return "LOST"
        if self.silent:
            return "SILENT"
        return self.summary.state if self.summary is not None else "?"

    def as_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"name": self.name, "zid": self.zid, "state": self.state,
                               "lost": self.lost, "silent": self.silent, "age_s": self.age_s}
        if self.summary is not None:
            out["summary"] = self.summary.as_json()
        return out


@dataclass(frozen=True)
class Answer:
    """One base's answer to a command: ``answered`` False when none came in time."""

    name: str
    answered: bool
    success: bool
    message: str

    def __str__(self) -> str:
        if not self.answered:
            return f"{self.name}: no answer ({self.message})"
        return f"{self.name}: {'ok' if self.success else 'refused'}: {self.message}"


class Call:
    """Requests on their way (:meth:`Fleet.request`): :meth:`done` once every base
    answered or timed out; :meth:`answers` in the order asked."""

    def __init__(self, service: str, names: list[str], timeout_s: float) -> None:
        self.service = service
        self.names = names
        self.timeout_s = timeout_s
        self._answers: dict[str, Answer] = {}
        self._cond = threading.Condition()

    def _settle(self, answer: Answer) -> None:
        with self._cond:
            self._answers.setdefault(answer.name, answer)  # the first one counts
            self._cond.notify_all()

    def done(self) -> bool:
        with self._cond:
            return len(self._answers) == len(self.names)

    def wait(self, timeout_s: float | None = None) -> list[Answer]:
        """Block until :meth:`done` (or ``timeout_s``, default the call's timeout and a
        second); bases still silent then have no answer."""
        limit = self.timeout_s + 1.0 if timeout_s is None else timeout_s
        with self._cond:
            self._cond.wait_for(lambda: len(self._answers) == len(self.names), limit)
        return self.answers()

    def answers(self) -> list[Answer]:
        with self._cond:
            got = dict(self._answers)
        return [got.get(n) or Answer(n, False, False, f"none within {self.timeout_s:g} s")
                for n in self.names]


class _Base:
    """What the fleet knows of one base (guarded by the fleet's lock)."""

    def __init__(self, token: rmw.Token, key: str, now: float) -> None:
        self.token, self.key, self.found_at = token, key, now
        self.lost = False


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
        self._bases: dict[str, _Base] = {}
        self._summaries: dict[str, tuple[Summary, float]] = {}  # topic -> newest, heard
        self.rejected = 0  # summaries that could not be read
        self._seq = 0
        self.gid = rmw.gid_of(f"omnican fleet {session.info.zid()}")
        hash_ = rmw.type_hash(STRING)
        self.summary_key = (f"{domain_id}/**/{SUMMARY_TOPIC}/"
                            f"{rmw.dds_type_name(STRING)}/{hash_}")
        self._closed = False
        self._zenoh = zenoh
        # Last: their callbacks start at once (the tokens already there come with them).
        self._summary_sub = session.declare_subscriber(self.summary_key, self._on_summary)
        self._tokens = session.liveliness().declare_subscriber(
            f"{rmw.ADMIN_SPACE}/{domain_id}/**", self._on_token, history=True)

    # ------------------------------------------------------------ what is heard

    def _on_token(self, sample: Any) -> None:
        try:
            self._token_changed(sample)
        except Exception:  # in Zenoh's thread: say it, never stop hearing
            logger.exception("a liveliness token not handled")

    def _token_changed(self, sample: Any) -> None:
        key = str(sample.key_expr)
        if sample.kind == self._zenoh.SampleKind.DELETE:
            with self._lock:
                for base in self._bases.values():
                    if base.key == key and not base.lost:
                        base.lost = True
                        logger.info("%s lost (its token went)", base.token.node_name)
            return
        self._found(key)

    def _found(self, key: str) -> None:
        try:
            token = rmw.parse_token(key)
        except ValueError:
            return  # not an rmw_zenoh endpoint we can read: not a base
        if (token.kind is not rmw.Kind.PUBLISHER or token.type_name != STRING
                or token.name.rsplit("/", 1)[-1] != SUMMARY_TOPIC):
            return
        name = token.node_name
        with self._lock:
            old = self._bases.get(name)
            if old is not None and old.key == key and not old.lost:
                return
            self._bases[name] = _Base(token, key, self.clock())
        logger.info("%s found (session %s)", name, token.node.session_id)

    def _on_summary(self, sample: Any) -> None:
        from omnican.telemetry import cdr

        key = str(sample.key_expr)
        topic = rmw.topic_of(key)
        try:
            summary = parse(cdr.decode(STRING, sample.payload.to_bytes())["data"])
        except Exception as exc:  # whatever a broken sample raises: from the network
            self.rejected += 1
            logger.debug("a summary on %s not read: %s", key, exc)
            return
        with self._lock:
            self._summaries[topic] = (summary, self.clock())

    def discover(self, timeout_s: float = TIMEOUT_S) -> int:
        """Ask the network for the tokens there now and wait for the answer (what the
        subscriber's history also brings, but with an end: ``--once`` knows when).
        A session just opened may be answered with nothing at all: asked again then,
        until ``timeout_s``. Returns how many tokens came."""
        deadline = time.monotonic() + timeout_s
        while True:
            left = max(0.01, deadline - time.monotonic())
            tokens = [str(r.ok.key_expr) for r in self.session.liveliness().get(
                f"{rmw.ADMIN_SPACE}/{self.domain_id}/**", timeout=left) if r.ok is not None]
            for key in tokens:
                self._found(key)
            if tokens or time.monotonic() >= deadline:
                return len(tokens)
            time.sleep(0.05)

    # ------------------------------------------------------------ what is shown

    def bases(self) -> list[BaseView]:
        """Every base found, by name; a lost one stays (marked) until it comes back."""
        now = self.clock()
        with self._lock:
            out = []
            for name, base in sorted(self._bases.items()):
                summary, heard = self._summaries.get(base.token.name, (None, None))
                period = summary.period_s if summary is not None else DEFAULT_PERIOD_S
                since = now - (heard if heard is not None else base.found_at)
                out.append(BaseView(name, base.token.node.session_id, summary,
                                    None if heard is None else max(0.0, now - heard),
                                    base.lost, since > SILENT_PERIODS * period))
            return out

    def find(self, name: str) -> BaseView | None:
        """The base called ``name``: its node name (``/robot1/omnican``) or, when only
        one base has it, its namespace (``/robot1`` or ``robot1``)."""
        views = self.bases()
        exact = [v for v in views if v.name == name]
        if exact:
            return exact[0]
        ns = "/" + name.strip("/")
        by_ns = [v for v in views if v.name.rsplit("/", 1)[0] == ns]
        return by_ns[0] if len(by_ns) == 1 else None

    # ------------------------------------------------------------ commands

    def request(self, service: str, names: Iterable[str],
                timeout_s: float = TIMEOUT_S) -> Call:
        """Call ``service`` (``stop``, ``recover``) of each base in ``names`` at once:
        every request goes out before any answer is awaited. Names not found are
        answered at once (no answer: unknown)."""
        names = list(dict.fromkeys(names))
        call = Call(service, names, timeout_s)
        with self._lock:
            nodes = {n: b.token.node for n, b in self._bases.items() if n in names}
        for name in names:
            node = nodes.get(name)
            if node is None:
                call._settle(Answer(name, False, False, "no such base"))
                continue
            with self._lock:
                self._seq += 1
                seq = self._seq
            self._ask(call, name, service_key(node, service), seq)
        return call

    def _ask(self, call: Call, name: str, key: str, seq: int) -> None:
        zenoh = self._zenoh

        def on_reply(reply: Any) -> None:
            if reply.ok is None:  # Zenoh's own (a timeout), or not an rmw_zenoh server
                text = reply.err.payload.to_bytes().decode("utf-8", "replace")
                call._settle(Answer(name, False, False, f"{text[:200]} after "
                                    f"{call.timeout_s:g} s" if text == "Timeout"
                                    else f"error: {text[:200]}"))
                return
            try:
                raw = reply.ok.attachment
                att = rmw.Attachment.decode(raw.to_bytes() if raw is not None else b"")
                if (att.sequence, att.gid) != (seq, self.gid):
                    return  # not the answer to this request
                ok, message = read_trigger_response(reply.ok.payload.to_bytes())
            except ValueError as exc:
                call._settle(Answer(name, True, False, f"unreadable answer: {exc}"))
                return
            call._settle(Answer(name, True, ok, message))

        def finished() -> None:  # every reply in, or the query's timeout
            call._settle(Answer(name, False, False, f"none within {call.timeout_s:g} s"))

        attachment = rmw.Attachment(seq, time.time_ns(), self.gid).encode()
        self.session.get(key, zenoh.handlers.Callback(on_reply, finished),
                         payload=TRIGGER_REQUEST, attachment=attachment,
                         target=zenoh.QueryTarget.ALL_COMPLETE,
                         consolidation=zenoh.ConsolidationMode.NONE, timeout=call.timeout_s)

    def stop(self, name: str, timeout_s: float = TIMEOUT_S) -> Answer:
        return self.request("stop", [name], timeout_s).wait()[0]

    def recover(self, name: str, timeout_s: float = TIMEOUT_S) -> Answer:
        return self.request("recover", [name], timeout_s).wait()[0]

    def stop_all(self, timeout_s: float = TIMEOUT_S) -> list[Answer]:
        """The fleet stop: every base not lost, all at once."""
        return self.stop_all_call(timeout_s).wait()

    def stop_all_call(self, timeout_s: float = TIMEOUT_S) -> Call:
        """:meth:`stop_all` without waiting (a dashboard collects the answers)."""
        return self.request("stop", [v.name for v in self.bases() if not v.lost], timeout_s)

    # ------------------------------------------------------------ lifecycle

    def close(self) -> None:
        """Undeclare the subscribers (idempotent); the session stays open."""
        if self._closed:
            return
        self._closed = True
        self._tokens.undeclare()
        self._summary_sub.undeclare()

    def __enter__(self) -> Fleet:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
