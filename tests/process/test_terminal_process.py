"""The terminal commands across processes, as a user runs them: ``omnican sim`` serving
the drives in one process, ``omnican teleop`` (in a pseudo-terminal) or ``omnican drive``
driving them from another; the simulator killed, or one of its drives frozen, under them."""

from __future__ import annotations

import contextlib
import os
import re
import select
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.support import terminal

ROOT = Path(__file__).resolve().parents[2]
TIMEOUT_S = 60.0


class Served:
    """``omnican sim --serve 127.0.0.1:0`` in a process of its own: its URL, its console."""

    def __init__(self) -> None:
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "omnican", "sim", "--serve", "127.0.0.1:0"],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=env)
        self._buffer = b""
        first = self.line()
        found = re.search(r"on (ws://127\.0\.0\.1:\d+/)", first)
        assert found is not None, first
        self.url = found[1]

    def line(self, timeout: float = TIMEOUT_S) -> str:
        assert self.proc.stdout is not None
        fd = self.proc.stdout.fileno()
        end = time.monotonic() + timeout
        while b"\n" not in self._buffer:
            ready, _, _ = select.select([fd], [], [], max(0.0, end - time.monotonic()))
            assert ready, f"no line from omnican sim within {timeout} s: {self._buffer!r}"
            chunk = os.read(fd, 4096)
            assert chunk, f"omnican sim closed its output: {self._buffer!r}"
            self._buffer += chunk
        line, self._buffer = self._buffer.split(b"\n", 1)
        return line.decode()

    def say(self, command: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(f"{command}\n".encode())
        self.proc.stdin.flush()

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.communicate(timeout=10)


@pytest.fixture
def served() -> Iterator[Served]:
    sim = Served()
    try:
        yield sim
    finally:
        sim.close()


def test_teleop_whose_simulator_died_exits_1_and_calls_its_drives_offline(
        served: Served) -> None:
    """Issue 36 item 5: after ``omnican sim`` went away under teleop, the closing error
    called the drives OPERATION ENABLED (the dashboard: OFFLINE) and teleop exited 0."""
    term = terminal.Pty("teleop", "-i", "remote", "-c", served.url)
    try:
        term.wait_for_frame("RUNNING", timeout=TIMEOUT_S)
        served.proc.kill()  # the simulator (and with it every drive) is gone
        term.wait_for_frame("OFFLINE", timeout=TIMEOUT_S)
        term.keys("\x1b")  # Esc quits
        assert term.exit_code(timeout=TIMEOUT_S) == 1, term.read()[-3000:]
        text = re.sub(r"\s*\n\s*", " ", term.read(0.3))  # the error wraps at 120 columns
        closing = re.search(r"omnican: ERROR: base closed; not confirmed disabled: (.*?) pose",
                            text)
        assert closing is not None, text[-3000:]
        for node in (1, 2, 3):
            assert re.search(rf"node {node} \(OFFLINE: [^;)]+; last seen OPERATION ENABLED\)",
                             closing[1]), closing[1]
        assert "(OPERATION ENABLED)" not in closing[1], closing[1]
        assert re.search(r"pose x=\S+ y=\S+ theta=\S+", text)
    finally:
        term.close()


def test_drive_whose_drive_froze_names_it_offline_on_closing(served: Served) -> None:
    """The same line after a drive that stopped answering under ``omnican drive``."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-m", "omnican", "drive", "-i", "remote", "-c",
                             served.url, "--vx", "0.1", "--duration", "600"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        assert served.line().startswith("connect with:")
        assert served.line().startswith("type a command here:")
        # The drives are up once the simulator's truth moves: then freeze node 1.
        deadline = time.monotonic() + TIMEOUT_S
        while True:
            served.say("pose")
            true = re.fullmatch(r"true pose x=(\S+) y=\S+ theta=\S+", served.line())
            assert true is not None
            if float(true[1]) > 0.01:
                break
            assert time.monotonic() < deadline and proc.poll() is None, "the base never moved"
            time.sleep(0.2)
        served.say("freeze 1")
        _, err = proc.communicate(timeout=TIMEOUT_S)
        assert proc.returncode == 1, err
        assert "omnican: error: base stopped: node 1 heartbeat lost" in err, err
        closing = next((line for line in err.splitlines()
                        if "not confirmed disabled" in line), None)
        assert closing is not None, err
        assert "node 1 (OFFLINE: heartbeat lost; last seen OPERATION ENABLED)" in closing, err
        assert "node 1 (OPERATION ENABLED)" not in closing, err
        assert "Traceback" not in err
    finally:
        if proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                proc.send_signal(signal.SIGKILL)
            proc.communicate()


def _child_of(pid: int, timeout: float = TIMEOUT_S) -> int:
    """The one child process of ``pid`` (a shell's job)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        children = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
        if len(children) == 1:
            return int(children[0])
        time.sleep(0.05)
    raise AssertionError(f"process {pid} has no single child")


def _moving(frame: list[str], vx: str) -> bool:
    """The twist panel's vx row: the keys' and the applied command are ``vx``."""
    return any(re.search(rf"vx m/s +{re.escape(vx)} +{re.escape(vx)} ", line) for line in frame)


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="needs /proc")
def test_teleop_stopped_and_continued_takes_a_single_space_as_stop() -> None:
    """Issue 36 item 8 (safety): ``kill -STOP``, ``kill -CONT``, then ``fg`` left teleop's
    terminal in line mode (the shell resets it when a job stops, and ``fg`` of a job a
    SIGCONT already resumed sends no signal): keys echoed and acted only after Enter, the
    stop key included. In an interactive shell with job control, as a user has it."""
    term = terminal.Pty(argv=["bash", "--norc", "--noprofile", "-i"])
    try:
        term.keys(f"PS1='$ '; {sys.executable} -m omnican teleop --sim --key-timeout 0\n")
        term.wait_for_frame("RUNNING", timeout=TIMEOUT_S)
        teleop = _child_of(term.proc.pid)
        os.kill(teleop, signal.SIGSTOP)  # from elsewhere, as kill -STOP
        term.wait_for("Stopped", timeout=TIMEOUT_S)
        time.sleep(1.0)  # stopped for longer than the heartbeats' 0.35 s: a held stop
        os.kill(teleop, signal.SIGCONT)  # resumed in the background
        term.keys("fg\n")  # the shell's: the job back in the foreground, no SIGCONT
        # The drives missed the host while it was stopped: the base is held stopped.
        term.wait_for_frame("press r to recover", timeout=TIMEOUT_S)
        term.screen = ""
        term.keys("r")  # one key, no Enter
        term.wait_for_frame("RUNNING", timeout=TIMEOUT_S)
        term.keys("i")  # forward, held (no key timeout)
        end = time.monotonic() + TIMEOUT_S
        while not _moving(term.frame(), "+0.300"):
            assert time.monotonic() < end, "\n".join(term.frame())
            term.read(0.1)
        term.screen = ""
        term.keys(" ")  # a single space, no Enter: stop
        frame = term.wait_for_frame("last key ' '", timeout=TIMEOUT_S)
        while not _moving(frame, "+0.000"):
            assert time.monotonic() < end, "\n".join(frame)
            term.read(0.1)
            frame = term.frame()
        term.keys("\x1b")  # Esc quits, the pose printed
        term.wait_for("pose x=", timeout=TIMEOUT_S)
    finally:
        with contextlib.suppress(OSError):
            term.keys("exit\n")
        term.close()


@pytest.fixture
def router() -> Iterator[str]:
    """A Zenoh router on tcp/127.0.0.1:<free port> in this process, multicast off."""
    zenoh = pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed")
    from tests.zenoh.conftest import free_port

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    conf = zenoh.Config()
    conf.insert_json5("mode", '"router"')
    conf.insert_json5("listen/endpoints", f'["{endpoint}"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(conf)
    try:
        yield endpoint
    finally:
        session.close()


def test_teleop_tells_a_network_stop_from_a_driver(router: str) -> None:
    """Issue 36 item 12: a fleet stop (the base's Zenoh ``~/stop``, called here from this
    process) while the keys drove: teleop said ``Zenoh service client ... is driving``.
    It shows who stopped the base (the stop line) apart from who drives (no one)."""
    from omnican.zenoh import rmw
    from omnican.zenoh.services import SOURCE, service_key
    from tests.zenoh.conftest import client

    term = terminal.Pty("teleop", "--sim", "--key-timeout", "0", "--zenoh", "--zenoh-mode",
                        "client", "--zenoh-connect", router)
    session = client(router)
    try:
        term.wait_for_frame("Zenoh /omnican", timeout=TIMEOUT_S)
        term.wait_for_frame("RUNNING", timeout=TIMEOUT_S)
        term.keys("i")  # forward, held (no key timeout)
        end = time.monotonic() + TIMEOUT_S
        while not _moving(term.frame(), "+0.300"):
            assert time.monotonic() < end, "\n".join(term.frame())
            term.read(0.1)
        gid = bytes(range(16))
        replies = session.get(service_key(rmw.RosNode(0, "0", 0, "omnican", namespace="/"),
                                          "stop"),
                              payload=b"\x00\x01\x00\x00\x00",
                              attachment=rmw.Attachment(1, 0, gid).encode(), timeout=TIMEOUT_S)
        assert len([r for r in replies if r.ok is not None]) == 1
        stopper = f"{SOURCE} {gid.hex()}"
        frame = term.wait_for_frame(f"{stopper} stopped the terminal's keys", timeout=TIMEOUT_S)
        text = "\n".join(frame)
        assert f"STOPPED: stopped by {stopper}" in text, text
        assert "is driving" not in text, text
        term.keys("\x1b")
        assert term.exit_code(timeout=TIMEOUT_S) == 0, term.read()[-3000:]
    finally:
        session.close()
        term.close()
