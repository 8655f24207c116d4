"""The fleet view's link to the bases: its Zenoh session and
:class:`~omnican.zenoh.fleet.Fleet`, and what the view may ask of the bases.

The session opens in a thread of its own, and again while the router cannot be reached
(:class:`Link`), so that the view says what keeps it from the bases, and hears Ctrl-C,
meanwhile. A viewer's identity may not recover (:func:`may_recover`), and no one
recovers a name two sessions claim (:data:`CONFLICT`: the recover would reach each)."""

from __future__ import annotations

import logging
import threading
import time
from typing import TYPE_CHECKING, Any

from omnican.errors import ConfigError

if TYPE_CHECKING:
    from omnican.zenoh.fleet import Fleet
    from omnican.zenoh.settings import ZenohSettings

RETRY_S = 1.0  # how often a view tries again to reach its router
#: how long a view waits for its first link before it says it cannot reach its router,
#: however short --wait (a peer's links, a client's session, come later on a busy machine)
REACH_S = 3.0
CLOSE_WAIT_S = 5.0  # the longest a view waits, when it quits, for a session being opened
ROUTER_LISTEN = "tcp/127.0.0.1:7447"  # rmw_zenoh's port, loopback unless told
RECOVER_TIMEOUT_S = 15.0  # a recover waits for the drives to enable
#: Why a recover of a name two sessions claim is not asked: it would reach both (a
#: service's key is the name's, whoever serves it), and a recover moves a base.
CONFLICT = "more than one session claims the name, and a recover would reach each"

#: Why a viewer's recover is not sent: the fleet's access control lets none through, and
#: unanswered it would read as a base that is gone.
VIEWER_RECOVERS = ("a viewer may only stop: its certificate lets no recover through "
                   "(an operator's identity may recover)")


def may_recover(settings: ZenohSettings) -> bool:
    """The session's certificate lets a recover through (a viewer's does not)."""
    who = settings.who
    return who is None or who.role != "viewer"


def reach_problem(settings: ZenohSettings, links: int) -> str | None:
    """What keeps a view with ``links`` routers and peers from every base (None: nothing):
    a mistyped router must not look like a fleet with nothing to stop."""
    if links or settings.mode == "router":
        return None
    if settings.connect:
        return f"cannot reach {', '.join(settings.connect)}"
    return "reaches no Zenoh router or peer" + (
        "" if settings.multicast else " (no --zenoh-connect, and multicast is off)")


def _unreachable(exc: ConfigError) -> bool:
    """Zenoh refused to open a client's session because no router answered."""
    return "Unable to connect" in str(exc)


class Link:
    """The view's session and its :class:`~omnican.zenoh.fleet.Fleet`, opened in a thread
    of its own and again every :data:`RETRY_S` while its router cannot be reached (a
    client's session opens only once it reaches one), so that the view says so, and
    hears Ctrl-C, meanwhile. A context manager."""

    def __init__(self, settings: ZenohSettings) -> None:
        self.settings = settings
        self._lock = threading.Lock()
        self._fleet: Fleet | None = None
        self._session: Any = None
        self._fatal: BaseException | None = None
        self._closed = threading.Event()
        self._thread = threading.Thread(target=self._open, name="omnican-fleet-open",
                                        daemon=True)  # zenoh.open cannot be interrupted
        self._thread.start()

    def _open(self) -> None:
        from omnican.zenoh.bridge import open_session
        from omnican.zenoh.fleet import Fleet

        while not self._closed.is_set():
            try:
                session = open_session(self.settings)
            except ConfigError as exc:
                if not _unreachable(exc):
                    self._fatal = exc
                    return
                logging.getLogger(__name__).debug("%s; trying again in %g s", exc, RETRY_S)
                self._closed.wait(RETRY_S)
                continue
            except Exception as exc:  # said in the main thread
                self._fatal = exc
                return
            with self._lock:
                if self._closed.is_set():
                    session.close()
                    return
                try:
                    self._fleet = Fleet(session, self.settings.domain_id)
                    self._session = session
                except Exception as exc:
                    session.close()
                    self._fatal = exc
                return

    def fleet(self) -> Fleet | None:
        """The fleet once the session is open (None before); what kept it from opening,
        raised, if that was not the router being out of reach."""
        if self._fatal is not None:
            raise self._fatal
        return self._fleet

    def wait_open(self, deadline: float) -> Fleet | None:
        """The fleet, waiting for the session until ``deadline`` (monotonic s)."""
        while (fleet := self.fleet()) is None and time.monotonic() < deadline:
            time.sleep(0.02)
        return fleet

    def wait_linked(self, deadline: float) -> Fleet | None:
        """The fleet, waiting until it is open and linked to a router or peer or until
        ``deadline`` (monotonic s)."""
        while time.monotonic() < deadline:
            fleet = self.fleet()
            if fleet is not None and reach_problem(self.settings, fleet.links()) is None:
                return fleet
            time.sleep(0.02)
        return self.fleet()

    def problem(self) -> str | None:
        """What keeps this view from the bases now (None: nothing)."""
        fleet = self.fleet()
        if fleet is None:
            return reach_problem(self.settings, 0) or "the Zenoh session is not open yet"
        return reach_problem(self.settings, fleet.links())

    def close(self) -> None:
        """Close the fleet and the session, and wait (a bounded time) for a session
        being opened: Python must not exit under a thread inside Zenoh."""
        self._closed.set()
        self._thread.join(CLOSE_WAIT_S)
        with self._lock:
            fleet, session = self._fleet, self._session
            self._fleet = self._session = None
        if fleet is not None:
            fleet.close()
        if session is not None:
            session.close()

    def __enter__(self) -> Link:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

