"""The terminal as the interactive commands (teleop, fleet) use it: keys without Enter,
arrow keys read as letters, Ctrl-Z refused, and log records shown in an events panel
instead of over the screen."""

from __future__ import annotations

import collections
import contextlib
import logging
import os
import re
import select
import signal
import termios
import time
import tty
from collections.abc import Callable, Iterator
from typing import Any

from omnican.command.teleop import ESC

#: The last byte of an arrow key's escape sequence -> teleop's key for it (up, down,
#: right, left: teleop_twist_keyboard's i , l j).
TELEOP_ARROWS = {"A": "i", "B": ",", "C": "l", "D": "j"}


def read_keys(fd: int, timeout: float, arrows: dict[str, str] = TELEOP_ARROWS) -> list[str]:
    """Keys typed within ``timeout`` s; an arrow key becomes what ``arrows`` says (by
    default teleop's i , l j; not in it: dropped); a lone Esc is Esc."""
    ready, _, _ = select.select([fd], [], [], timeout)
    if not ready:
        return []
    data = os.read(fd, 64).decode("utf-8", "replace")
    keys: list[str] = []
    i = 0
    while i < len(data):
        ch = data[i]
        if ch == ESC and i + 2 < len(data) + 1 and data[i + 1 : i + 2] == "[":
            code = data[i + 2 : i + 3]
            keys.append(arrows.get(code, ""))
            i += 3
            continue
        if ch == ESC and i + 1 == len(data):
            more, _, _ = select.select([fd], [], [], 0.03)  # an escape sequence on its way?
            if more:
                data += os.read(fd, 64).decode("utf-8", "replace")
                continue
        keys.append(ch)
        i += 1
    return [k for k in keys if k]


@contextlib.contextmanager
def cbreak(fd: int, on_suspend: Callable[[], None] | None = None) -> Iterator[None]:
    """Keys without Enter and without echo; Ctrl-C still interrupts. Ctrl-Z does not
    suspend (``on_suspend`` is told): stopped, teleop would leave the drives without the
    host's heartbeat and come back to a terminal the shell had reset, deaf to its keys.
    A SIGCONT (after a SIGSTOP from elsewhere) puts the keys back without Enter."""
    old = termios.tcgetattr(fd)

    def suspend(signum: int, frame: Any) -> None:
        if on_suspend is not None:
            on_suspend()

    def resumed(signum: int, frame: Any) -> None:
        with contextlib.suppress(termios.error, OSError):
            if os.tcgetpgrp(fd) == os.getpgrp():  # in the foreground: it owns the terminal
                tty.setcbreak(fd)

    saved = {signal.SIGTSTP: signal.signal(signal.SIGTSTP, suspend),
             signal.SIGCONT: signal.signal(signal.SIGCONT, resumed)}
    try:
        tty.setcbreak(fd)
        yield
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, old)
        for sig, handler in saved.items():
            signal.signal(sig, handler)


# The library names its call ("e-stop released: recover() starts the base again"); here
# the user's move is a key.
API_TO_KEYS = re.compile(r"recover\(\) starts( |$)")


class Events(logging.Handler):
    """Log records go to the dashboard instead of over it."""

    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.lines: collections.deque[str] = collections.deque(maxlen=5)

    def emit(self, record: logging.LogRecord) -> None:
        text = API_TO_KEYS.sub(r"press r to start\1", record.getMessage())
        self.say(text)

    def say(self, text: str) -> None:
        self.lines.append(f"{time.strftime('%H:%M:%S')} {text}")


@contextlib.contextmanager
def logs_into(handler: logging.Handler) -> Iterator[None]:
    """Log records into the dashboard, omnican's own from INFO on: what the base did
    (recovered, re-configured a rebooted drive) belongs in the events panel."""
    root = logging.getLogger()
    ours = logging.getLogger("omnican")
    saved, saved_level = root.handlers[:], ours.level
    root.handlers = [handler]
    if ours.getEffectiveLevel() > logging.INFO:
        ours.setLevel(logging.INFO)
    try:
        yield
    finally:
        root.handlers = saved
        ours.setLevel(saved_level)
