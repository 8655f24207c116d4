"""The line console of the commands that serve until told to stop (sim, ros2, zenoh):
each line on stdin to a handler, its reply printed."""

from __future__ import annotations

import codecs
import os
import select
import sys
import time
from collections.abc import Callable


def serve_lines(handle: Callable[[str], str | None], duration: float | None) -> None:
    """Feed stdin lines to ``handle`` (its reply is printed; None quits) until the duration
    ends or Ctrl-C; stdin closing (e.g. < /dev/null) keeps it running. Lines that arrive
    together (a script piping several commands) are each handled at once: stdin is read
    as bytes into a buffer of our own, never through Python's, which ``select`` cannot
    see into."""
    end = time.monotonic() + duration if duration else None
    stdin_open = not sys.stdin.closed
    fd = sys.stdin.fileno() if stdin_open else -1
    decoder = codecs.getincrementaldecoder(sys.stdin.encoding or "utf-8")("replace")
    pending = ""
    # A prompt for a person at a terminal (a script piping commands reads replies only).
    prompt = "> " if stdin_open and sys.stdin.isatty() else ""
    if prompt:
        print(prompt, end="", flush=True)
    try:
        while end is None or time.monotonic() < end:
            timeout = 0.2 if end is None else max(0.0, min(0.2, end - time.monotonic()))
            if not stdin_open:
                time.sleep(timeout)
                continue
            ready, _, _ = select.select([fd], [], [], timeout)
            if not ready:
                continue
            chunk = os.read(fd, 4096)
            if not chunk:  # closed: the last line may have had no end
                stdin_open = False
                pending += decoder.decode(b"", final=True)
                lines, pending = ([pending], "") if pending else ([], "")
            else:
                *lines, pending = (pending + decoder.decode(chunk)).split("\n")
            for line in lines:
                reply = handle(line + "\n")
                if reply is None:
                    return
                if reply:
                    print(reply, flush=True)
                if prompt:
                    print(prompt, end="", flush=True)
    except KeyboardInterrupt:
        pass
