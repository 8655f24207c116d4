"""A fleet view's requests to the bases' ``~/stop`` and ``~/recover`` services, and their
answers, each taken only from the session that owns the service.

The services are std_srvs/Trigger in rmw_zenoh's request/reply form
(:mod:`omnican.zenoh.services`), the same path as a ROS 2 client's: :class:`Caller`
sends every request of a :class:`Call` first (one Zenoh query per service key: every
session that claims a name answers it) and the answers are collected as they come, each
bounded by a timeout; a base that does not answer in time is reported so, and one whose
service nothing serves is reported at once. A service's answer is taken only from the
session that owns the service (the token's session id; a Zenoh reply carries the id of
the session that sent it): any other reply is an intruder's, counted and said.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

from omnican.errors import printable
from omnican.log_throttle import Throttle
from omnican.zenoh import rmw
from omnican.zenoh.discovery import MESSAGE_CHARS, Entry
from omnican.zenoh.services import TRIGGER_REQUEST, read_trigger_response, service_key

logger = logging.getLogger(__name__)

TIMEOUT_S = 2.0  # how long a command waits for each base's answer

#: the error a Zenoh router replies with, in the name of the session it asked, when that
#: session's answer did not come within the query's timeout (zenoh's QueryCleanup: its
#: responder id is the asked session's): no answer from that base, not its error
ROUTER_TIMEOUT = "Timeout"


def same_session(a: str, b: str) -> bool:
    """Two Zenoh ids written as hex (a token's, a reply's) name one session."""
    return a.lower().lstrip("0") == b.lower().lstrip("0")


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
    """Requests on their way (:meth:`~omnican.zenoh.fleet.Fleet.request`): :meth:`done`
    once every base answered or its query ended; :meth:`answers` in the order asked."""

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



#: One target of a request: its token's key, the base's name and session id, and the
#: token's entry (None: the token went, and the base was forgotten).
Target = tuple[str, str, str, Entry | None]


class Caller:
    """Sends a fleet view's requests on ``session``; ``cancel`` (a
    ``zenoh.CancellationToken``) ends them. ``clock``: monotonic seconds."""

    def __init__(self, session: Any, clock: Callable[[], float], cancel: Any) -> None:
        import zenoh

        self.session = session
        self.clock = clock
        self._zenoh = zenoh
        self._cancel = cancel
        self._lock = threading.Lock()
        self._seq = 0
        self.intruders = 0  # replies from a session that does not own the service
        self._throttle = Throttle(logger)
        self.gid = rmw.gid_of(f"omnican fleet {session.info.zid()}")

    def call(self, service: str, timeout_s: float, unheard: bool, unknown: Iterable[str],
             targets: Iterable[Target]) -> Call:
        """Call ``service`` of each target at once: every request goes out before any
        answer is awaited. A name in ``unknown`` (no token has it) is answered at once (no
        such base); a target whose token went, too."""
        call = Call(service, timeout_s, unheard)
        for name in unknown:
            key = f"unknown:{name}"
            if key not in call._labels:
                call._add(key, printable(name, 80), "")
                call._settle(key, False, False, "no such base")
        groups: dict[str, list[Entry]] = {}  # one query per service key: every
        for target, name, zid, entry in targets:  # session claiming that name answers it
            if target in call._labels:
                continue
            call._add(target, name, zid)
            if entry is None:
                call._settle(target, False, False, "its token went: forgotten")
                continue
            groups.setdefault(service_key(entry.token.node, service), []).append(entry)
        for key, entries in groups.items():
            with self._lock:
                self._seq += 1
                seq = self._seq
            self._ask(call, key, entries, seq)
        return call

    def _ask(self, call: Call, key: str, entries: list[Entry], seq: int) -> None:
        """One query on ``key``; each reply is its sender's answer if that session owns
        one of ``entries`` (their tokens' session ids), else an intruder's."""
        zenoh = self._zenoh
        sent = time.monotonic()
        timed_out = threading.Event()

        def owner(replier: str) -> Entry | None:
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

