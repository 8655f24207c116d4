"""Repeated log messages, counted and summarised instead of logged one by one.

A drive in an EMCY storm (a thousand a second), a device sending broken frames, a
refused per-cycle SDO: each would otherwise write a log line per frame and fill a
robot's disk. :class:`Throttle` logs the first message of a kind at once, counts the
ones that follow within ``every_s``, and says how many there were with the next one
after that (or at :meth:`flush`, when the program ends).

No I/O of its own beyond the logger it is given; the clock is passed in.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Hashable
from dataclasses import dataclass

DEFAULT_EVERY_S = 5.0


@dataclass
class _Kind:
    logged_at: float
    suppressed: int = 0
    level: int = logging.WARNING
    text: str = ""


class Throttle:
    """At most one log line per kind (``key``) every ``every_s`` seconds of ``clock``."""

    def __init__(self, logger: logging.Logger, every_s: float = DEFAULT_EVERY_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.logger = logger
        self.every_s = every_s
        self.clock = clock
        self._kinds: dict[Hashable, _Kind] = {}
        self._lock = threading.Lock()

    def log(self, level: int, key: Hashable, msg: str, *args: object) -> bool:
        """Log ``msg % args`` now, or count it if its kind was logged less than
        ``every_s`` ago; True if it was logged."""
        now = self.clock()
        with self._lock:
            kind = self._kinds.get(key)
            if kind is not None and now - kind.logged_at < self.every_s:
                kind.suppressed += 1
                kind.level, kind.text = level, msg % args if args else msg
                return False
            suppressed = kind.suppressed if kind is not None else 0
            since = now - kind.logged_at if kind is not None else 0.0
            self._kinds[key] = _Kind(now, 0, level, "")
        text = msg % args if args else msg
        if suppressed:
            text += f" ({suppressed} more like it in the last {since:.0f} s)"
        self.logger.log(level, "%s", text)
        return True

    def warning(self, key: Hashable, msg: str, *args: object) -> bool:
        return self.log(logging.WARNING, key, msg, *args)

    def error(self, key: Hashable, msg: str, *args: object) -> bool:
        return self.log(logging.ERROR, key, msg, *args)

    def flush(self) -> None:
        """Say how many of each kind went unlogged since its last line."""
        now = self.clock()
        with self._lock:
            pending = [(k, v) for k, v in self._kinds.items() if v.suppressed]
            for key, _ in pending:
                self._kinds[key] = _Kind(now)
        for _key, kind in pending:
            self.logger.log(kind.level, "%s (%d more like it in the last %.0f s)", kind.text,
                            kind.suppressed, now - kind.logged_at)
