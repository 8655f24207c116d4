"""A program in a pseudo-terminal: send keys, read the screen (teleop tests)."""

from __future__ import annotations

import codecs
import fcntl
import os
import re
import select
import struct
import subprocess
import sys
import termios
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
ANSI = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]|\x1b[()][A-Za-z0-9]|\x1b[=>]")


class Pty:
    """``python -m omnican ARGS`` (or the command ``argv``) in a pseudo-terminal of
    120 x 40 that is its controlling terminal (so Ctrl-C on it sends SIGINT)."""

    def __init__(self, *args: str, columns: int = 120, lines: int = 40,
                 argv: list[str] | None = None) -> None:
        self.master, slave = os.openpty()
        fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", lines, columns, 0, 0))
        env = {**os.environ, "PYTHONPATH": str(ROOT), "TERM": "xterm-256color",
               "COLUMNS": str(columns), "LINES": str(lines)}

        def controlling_terminal() -> None:
            os.setsid()
            fcntl.ioctl(0, termios.TIOCSCTTY, 0)

        self.proc = subprocess.Popen(argv or [sys.executable, "-m", "omnican", *args],
                                     stdin=slave, stdout=slave, stderr=slave, env=env,
                                     preexec_fn=controlling_terminal)  # noqa: PLW1509
        os.close(slave)
        self.screen = ""
        # One decoder for the whole stream: a character whose bytes two reads split
        # (a box-drawing line, 3 bytes each) must not become two replacement characters.
        self._decoder = codecs.getincrementaldecoder("utf-8")("replace")

    def read(self, timeout: float = 0.2) -> str:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            ready, _, _ = select.select([self.master], [], [], 0.05)
            if ready:
                try:
                    chunk = self._decoder.decode(os.read(self.master, 65536))
                except OSError:
                    break
                self.screen += chunk
        return ANSI.sub("", self.screen)

    def frame(self) -> list[str]:
        """The lines of the last whole screen a full-screen program drew (rich's Live
        starts each frame with the cursor home, ESC [ H); [] before the first one."""
        frames = self.screen.split("\x1b[H")
        if len(frames) < 3:  # what precedes the first frame, then one maybe cut short
            return []
        return ANSI.sub("", frames[-2]).replace("\r", "").split("\n")

    def wait_for_frame(self, text: str, timeout: float = 15.0) -> list[str]:
        """The first whole frame with ``text`` in it (the newest as it is read)."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            self.read(0.1)
            lines = self.frame()
            if any(text in line for line in lines):
                return lines
            if self.proc.poll() is not None:
                break
        raise AssertionError(f"{text!r} not in the last frame:\n" + "\n".join(self.frame()))

    def wait_for(self, text: str, timeout: float = 15.0) -> str:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            screen = self.read(0.1)
            if text in screen:
                return screen
            if self.proc.poll() is not None:
                break
        raise AssertionError(f"{text!r} not on screen:\n{self.read(0.1)[-3000:]}")

    def wait_for_any(self, texts: tuple[str, ...], timeout: float = 15.0) -> str:
        """The first of ``texts`` to show on the screen."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            screen = self.read(0.1)
            for text in texts:
                if text in screen:
                    return text
            if self.proc.poll() is not None:
                break
        raise AssertionError(f"none of {texts!r} on screen:\n{self.read(0.1)[-3000:]}")

    def exit_code(self, timeout: float = 15.0) -> int | None:
        """Wait for the program to end, reading the screen so it never blocks on output."""
        end = time.monotonic() + timeout
        while self.proc.poll() is None and time.monotonic() < end:
            self.read(0.05)
        return self.proc.poll()

    def keys(self, keys: str) -> None:
        os.write(self.master, keys.encode())

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(timeout=5)
        os.close(self.master)
