"""Signal handling while a base is open: SIGINT and SIGTERM end the program as usual,
and the ``with`` block's exit stops and disables the drives; a second signal right
behind the first cannot cut that stop short (see :class:`SignalGuard`)."""

from __future__ import annotations

import contextlib
import logging
import math
import os
import signal
import sys
import threading
import time
from collections.abc import Iterator
from types import FrameType
from typing import Any

logger = logging.getLogger("omnican.chassis")

SIGNAL_GRACE_S = 3.0  # repeated signals this soon after the first do not cut the stop short


class SignalGuard:
    """SIGINT and SIGTERM while a base is open, in the main thread.

    The first signal ends the program as usual (KeyboardInterrupt, or SystemExit for
    SIGTERM), and the ``with`` block's exit stops and disables the drives. A second
    signal right behind it (an impatient double Ctrl-C, or ``timeout``, which signals the
    child and then its whole process group) would otherwise raise inside that stop and
    cut it short, leaving drives enabled with a target. So signals that come while a
    base is closing, or within ``SIGNAL_GRACE_S`` of the first, are logged and ignored;
    the stop-and-disable sequence is bounded, so the program still ends.

    The grace outlives the base: a stop that ends within it leaves the handlers in place
    until it is over, so the second Ctrl-C cannot cut short what the program does after
    the stop either (a front end printing the final pose, a simulator shutting down).
    The first signal after the grace restores the program's own handlers and acts as
    they would.

    A Ctrl-C also makes the terminal discard the output it has not shown yet (the
    terminal's NOFLSH flag is off by default): a second one right after the program
    printed its final pose, with the terminal behind (ssh to a loaded robot), would wipe
    the pose off the screen. So while a base is open, and until the grace is over,
    NOFLSH is set on the controlling terminal. A program that ends within the grace
    leaves it set: restoring it as it exits would open that window again. (NOFLSH only
    keeps ^C from discarding output not yet shown.)"""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self._users = 0
        self._closing = 0
        self._saved: dict[int, Any] = {}
        self._first_at = -math.inf
        self._lingering = False  # released within the grace: handlers still installed
        self._terminal: tuple[int, int] | None = None  # (fd, its NOFLSH bit before)

    def acquire(self) -> bool:
        """Install the handlers (main thread only); False where that is impossible."""
        if threading.current_thread() is not threading.main_thread():
            return False
        if self._users == 0:
            if self._lingering:
                self._lingering = False  # still installed, the program's ones saved
            else:
                self._saved = {int(sig): signal.signal(sig, self._handle)
                               for sig in self.SIGNALS}
                self._keep_output()
            self._first_at = -math.inf
        self._users += 1
        return True

    def release(self) -> None:
        if self._users == 0:
            return
        self._users -= 1
        if self._users == 0:
            if time.monotonic() - self._first_at < SIGNAL_GRACE_S:
                self._lingering = True
                return
            self._restore()

    def _restore(self) -> None:
        self._lingering = False
        for sig, old in self._saved.items():
            with contextlib.suppress(ValueError, TypeError):  # not the main thread now
                signal.signal(sig, old if old is not None else signal.SIG_DFL)
        self._saved = {}
        self._restore_output()

    def _keep_output(self) -> None:
        """NOFLSH on the controlling terminal (the first of stdin, stdout, stderr that is
        one), its old value kept; nothing where there is no terminal."""
        if self._terminal is not None:
            return
        try:
            import termios
        except ImportError:  # not POSIX
            return
        for stream in (sys.stdin, sys.stdout, sys.stderr):
            try:
                fd = stream.fileno()
                if not os.isatty(fd):
                    continue
                if os.tcgetpgrp(fd) != os.getpgrp():
                    return  # in the background: a terminal change would stop us (SIGTTOU)
                attrs = termios.tcgetattr(fd)
                was = attrs[3] & termios.NOFLSH
                attrs[3] |= termios.NOFLSH
                termios.tcsetattr(fd, termios.TCSANOW, attrs)
            except (AttributeError, ValueError, OSError, termios.error):
                continue
            self._terminal = (fd, was)
            return

    def _restore_output(self) -> None:
        terminal, self._terminal = self._terminal, None
        if terminal is None:
            return
        import termios

        fd, was = terminal
        with contextlib.suppress(OSError, termios.error):
            if os.tcgetpgrp(fd) != os.getpgrp():
                return  # put in the background since: a change would stop us (SIGTTOU)
            attrs = termios.tcgetattr(fd)
            attrs[3] = (attrs[3] & ~termios.NOFLSH) | was
            termios.tcsetattr(fd, termios.TCSANOW, attrs)

    def at_exit(self) -> None:
        """The interpreter is ending within the grace: ignore the signals from here on.
        Python puts back the default SIGINT as it finalises, and a second Ctrl-C landing
        then would end the program by the signal, after it did all it had to."""
        if self._lingering and time.monotonic() - self._first_at < SIGNAL_GRACE_S:
            for sig in self.SIGNALS:
                with contextlib.suppress(ValueError, TypeError, OSError):
                    signal.signal(sig, signal.SIG_IGN)

    @contextlib.contextmanager
    def closing(self) -> Iterator[None]:
        self._closing += 1
        try:
            yield
        finally:
            self._closing -= 1

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        name = signal.Signals(signum).name
        now = time.monotonic()
        if self._closing or now - self._first_at < SIGNAL_GRACE_S:
            logger.warning("%s ignored: %s", name, "the drives are stopped and disabled; "
                           "finishing" if self._lingering else
                           "stopping the wheels and disabling the drives")
            return
        self._first_at = now
        old = self._saved.get(signum)
        if self._lingering:  # the base is gone and the grace over: the program's own again
            self._restore()
        if old is signal.SIG_IGN:
            return
        if callable(old) and old is not signal.default_int_handler:
            old(signum, frame)  # the program's own handler decides
            return
        if signum == signal.SIGINT:
            raise KeyboardInterrupt
        raise SystemExit(128 + signum)


#: The one guard of the process (signal handlers are per process).
guard = SignalGuard()
