"""The terminal as the interactive commands (teleop, fleet) use it: keys without Enter,
arrow keys read as letters, Ctrl-Z refused, and log records shown in an events panel
instead of over the screen."""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import fcntl
import logging
import os
import re
import select
import signal
import struct
import termios
import textwrap
import time
import tty
from collections.abc import Callable, Iterator, Sequence
from typing import TYPE_CHECKING, Any

from rich.panel import Panel
from rich.text import Text

from omnican.command.teleop import ESC

if TYPE_CHECKING:
    from rich.console import RenderableType
    from rich.live import Live

#: The last byte of an arrow key's escape sequence -> teleop's key for it (up, down,
#: right, left: teleop_twist_keyboard's i , l j).
TELEOP_ARROWS = {"A": "i", "B": ",", "C": "l", "D": "j"}


def in_foreground(fd: int) -> bool:
    """The terminal ``fd`` is this process's to read (its process group is the
    terminal's foreground one); False for a job the shell has put in the background.
    True for a terminal that is not this process's controlling one (no job control:
    nothing puts this process in its background)."""
    try:
        return os.tcgetpgrp(fd) == os.getpgrp()
    except OSError:
        return True


@dataclasses.dataclass
class _Held:
    """A terminal :func:`cbreak` holds: the attributes it set (as the terminal reads
    them back) and who to tell when it had to set them again."""

    mode: list[Any]
    on_resume: Callable[[], None] | None


#: fd -> what cbreak set on it, while the block runs
_held: dict[int, _Held] = {}
#: the local-mode bits whose loss makes keys wait for Enter and echo over the screen
_KEY_BITS = termios.ICANON | termios.ECHO


def regain(fd: int) -> bool:
    """Set cbreak's attributes on ``fd`` again where the terminal lost them, and tell
    its ``on_resume``: True if it did. A job stopped by SIGSTOP is given a terminal the
    shell has reset (line mode, echo); after a ``kill -CONT`` it runs in the background,
    and a later ``fg`` sends no SIGCONT, so the mode is checked here, not only there.
    Only in the foreground (setting a terminal from the background stops the job)."""
    held = _held.get(fd)
    if held is None or not in_foreground(fd):
        return False
    try:
        now = termios.tcgetattr(fd)
        if not ((now[3] ^ held.mode[3]) & _KEY_BITS
                or now[6][termios.VMIN] != held.mode[6][termios.VMIN]
                or now[6][termios.VTIME] != held.mode[6][termios.VTIME]):
            return False
        termios.tcsetattr(fd, termios.TCSANOW, held.mode)
    except (termios.error, OSError):
        return False
    if held.on_resume is not None:
        held.on_resume()
    return True


def _read_ready(fd: int) -> bytes:
    """What can be read from ``fd`` now without waiting (at most 64 bytes). A select
    begun in the foreground may end in the background (a SIGSTOP, then SIGCONT, in
    between) with the shell's keys ready: reading them would stop this job (SIGTTIN),
    and, once the shell had taken them, wait for the next key with the screen frozen."""
    if fd in _held and not in_foreground(fd):
        return b""
    try:
        waiting = struct.unpack("i", fcntl.ioctl(fd, termios.FIONREAD, b"\0\0\0\0"))[0]
    except OSError:
        waiting = 1  # not a terminal nor a pipe: select said so, read one
    return os.read(fd, min(waiting, 64)) if waiting > 0 else b""


def read_keys(fd: int, timeout: float, arrows: dict[str, str] = TELEOP_ARROWS) -> list[str]:
    """Keys typed within ``timeout`` s; an arrow key becomes what ``arrows`` says (by
    default teleop's i , l j; not in it: dropped); a lone Esc is Esc. Under
    :func:`cbreak`, its mode is set again first if the terminal lost it (:func:`regain`);
    in the background nothing is read (the keys are the shell's; a read would stop
    this job), the wait is the same."""
    if fd in _held and not in_foreground(fd):
        time.sleep(timeout)
        return []
    regain(fd)
    ready, _, _ = select.select([fd], [], [], timeout)
    if not ready:
        return []
    data = _read_ready(fd).decode("utf-8", "replace")
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
                data += _read_ready(fd).decode("utf-8", "replace")
                continue
        keys.append(ch)
        i += 1
    return [k for k in keys if k]


@contextlib.contextmanager
def cbreak(fd: int, on_suspend: Callable[[], None] | None = None,
           on_resume: Callable[[], None] | None = None) -> Iterator[None]:
    """Keys without Enter and without echo; Ctrl-C still interrupts. Ctrl-Z does not
    suspend (``on_suspend`` is told): stopped, teleop would leave the drives without the
    host's heartbeat and come back to a terminal the shell had reset, deaf to its keys.
    After a SIGSTOP from elsewhere the shell resets the terminal all the same: a SIGCONT,
    and every :func:`read_keys` (a ``fg`` after ``kill -CONT`` sends no signal), puts
    the keys back without Enter and tells ``on_resume`` (to redraw the screen)."""
    old = termios.tcgetattr(fd)

    def suspend(signum: int, frame: Any) -> None:
        if on_suspend is not None:
            on_suspend()

    def resumed(signum: int, frame: Any) -> None:
        regain(fd)

    saved = {signal.SIGTSTP: signal.signal(signal.SIGTSTP, suspend),
             signal.SIGCONT: signal.signal(signal.SIGCONT, resumed)}
    try:
        tty.setcbreak(fd)
        _held[fd] = _Held(termios.tcgetattr(fd), on_resume)
        yield
    finally:
        _held.pop(fd, None)
        termios.tcsetattr(fd, termios.TCSADRAIN, old)
        for sig, handler in saved.items():
            signal.signal(sig, handler)


class Screen:
    """A full-screen dashboard's terminal (teleop's, the fleet view's): drawn while the
    command is in the terminal's foreground (a job the shell put in the background draws
    nothing over the shell), and drawn whole again once the terminal comes back
    (:meth:`resumed`, cbreak's ``on_resume``): what the shell wrote meanwhile is cleared."""

    def __init__(self, fd: int, live: Live | None = None) -> None:
        self.live = live  # set once the screen is taken
        self.fd = fd
        self._resumed = False

    def resumed(self) -> None:
        self._resumed = True  # from a signal handler too: the clearing is draw()'s

    def draw(self, frame: RenderableType) -> None:
        if self.live is None or not in_foreground(self.fd):
            return
        if self._resumed:
            self._resumed = False
            self.live.console.clear()
            self.live.console.show_cursor(False)
        self.live.update(frame, refresh=True)


# The library names its call ("e-stop released: recover() starts the base again"); here
# the user's move is a key.
API_TO_KEYS = re.compile(r"recover\(\) starts( |$)")


class RecentEvents(logging.Handler):
    """A logging handler that keeps the newest five log lines (time-stamped) for the
    dashboard to show, instead of printing them over it."""

    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.lines: collections.deque[str] = collections.deque(maxlen=5)

    def emit(self, record: logging.LogRecord) -> None:
        text = API_TO_KEYS.sub(r"press r to start\1", record.getMessage())
        self.say(text)

    def say(self, text: str) -> None:
        self.lines.append(f"{time.strftime('%H:%M:%S')} {text}")


#: Columns an event's continuation lines are indented by: under its text, past the time.
EVENT_INDENT = len("00:00:00 ")


def event_lines(lines: Sequence[str], width: int, room: int) -> list[str]:
    """The newest of ``lines`` (oldest first) that fit ``room`` lines of ``width``
    columns, each wrapped whole (continuations indented past the time) rather than cut:
    an e-stop's object or a refused recover's reason is read to its end. The newest
    comes first in what is kept; when even it does not fit, its start, ending in …."""
    width = max(width, EVENT_INDENT + 10)
    kept: list[list[str]] = []
    used = 0
    for line in reversed(lines):
        wrapped = textwrap.wrap(line, width, subsequent_indent=" " * EVENT_INDENT,
                                break_on_hyphens=False) or [""]
        if used + len(wrapped) > room:
            if not kept and room > 0:  # the newest alone is too long: its start
                head = wrapped[:room]
                head[-1] = head[-1][: width - 1] + "…"
                kept.append(head)
            break
        kept.append(wrapped)
        used += len(wrapped)
    return [text for event in reversed(kept) for text in event]


def events_panel(lines: Sequence[str], width: int, room: int) -> Panel:
    """The events panel of ``width`` columns (its frame included) and at most ``room``
    lines of events (at least one), newest last (:func:`event_lines`)."""
    text = "\n".join(event_lines(lines, width - 4, max(1, room)))
    return Panel(Text(text, no_wrap=True, overflow="ellipsis"), title="events",
                 title_align="left")


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
