"""The consoles of omnican sim, ros2 and zenoh read their commands from stdin: what a
script pipes in is each handled, however the lines arrive."""

from __future__ import annotations

import io
import os
import threading

import pytest

from omnican.cli.console import serve_lines


def _stdin_of(data: bytes, keep_open: bool) -> tuple[io.TextIOWrapper, int | None]:
    r, w = os.pipe()
    os.write(w, data)
    if not keep_open:
        os.close(w)
    return io.TextIOWrapper(io.FileIO(r, "r"), encoding="utf-8"), (w if keep_open else None)


@pytest.mark.parametrize("keep_open", [True, False], ids=["still-open", "closed"])
def test_lines_that_arrive_together_are_each_handled(monkeypatch: pytest.MonkeyPatch,
                                                     keep_open: bool) -> None:
    """Three commands in one write (a script's printf): each handled, in order, without
    more input coming (main read one, then waited on select while the others sat in
    Python's buffer). A line with no end counts once stdin closes."""
    stdin, writer = _stdin_of("pose\nfault 2 0x2310\nheartbeat 3 off\nlast é".encode(),
                              keep_open)
    monkeypatch.setattr("sys.stdin", stdin)
    seen: list[str] = []
    all_in = threading.Event()

    def handle(line: str) -> str | None:
        seen.append(line)
        if len(seen) == (3 if keep_open else 4):
            all_in.set()
            return None  # quit: the test ends as soon as every line was handled
        return ""

    try:
        serve_lines(handle, duration=60.0)
    finally:
        stdin.close()
        if writer is not None:
            os.close(writer)
    assert all_in.is_set()
    want = ["pose\n", "fault 2 0x2310\n", "heartbeat 3 off\n"]
    assert seen == (want if keep_open else [*want, "last é\n"])


def test_a_split_character_and_a_quit_midway(monkeypatch: pytest.MonkeyPatch) -> None:
    """A UTF-8 character split across two reads is one character; quit ends at once and
    the lines after it are not handled."""
    r, w = os.pipe()
    stdin = io.TextIOWrapper(io.FileIO(r, "r"), encoding="utf-8")
    monkeypatch.setattr("sys.stdin", stdin)
    seen: list[str] = []
    data = "say é\nquit\npose\n".encode()
    cut = data.index("é".encode()) + 1  # inside the two bytes of é
    os.write(w, data[:cut])

    def handle(line: str) -> str | None:
        seen.append(line)
        return None if line.strip() == "quit" else ""

    feeder = threading.Timer(0.05, lambda: os.write(w, data[cut:]))
    feeder.start()
    try:
        serve_lines(handle, duration=60.0)
    finally:
        feeder.join()
        stdin.close()
        os.close(w)
    assert seen == ["say é\n", "quit\n"]
