"""omnican fleet as a user runs it: a router on loopback, two 'omnican zenoh --sim'
processes (clients of it, /robot1 and /robot2), and the fleet view in scripts (--once
--json, --stop all, --json lines while one base is killed) and in a terminal (the
dashboard: both rows, space stops both)."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from tests.interop.ros2_interop.harness import Proc
from tests.support import terminal
from tests.support.helpers import one_error_line

pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed "
                    "(pip install 'omnican[zenoh]')")

TIMEOUT_S = 120.0  # real seconds, generous: processes starting on a loaded machine
NAMES = ["/robot1/omnican", "/robot2/omnican"]


@contextlib.contextmanager
def bases(router: str, count: int = 2) -> Iterator[list[Proc]]:
    """``count`` simulated bases, /robot1.., each a client of ``router``, running."""
    procs = []
    try:
        for n in range(1, count + 1):
            procs.append(Proc([sys.executable, "-m", "omnican", "zenoh", "--sim",
                               "--zenoh-mode", "client", "--zenoh-connect", router,
                               "--namespace", f"/robot{n}"], env=dict(os.environ)))
        for proc in procs:
            assert proc.read_until(lambda line: "Ctrl-C to stop" in line, TIMEOUT_S), \
                proc.lines
        yield procs
    finally:
        for proc in procs:
            proc.kill()


def fleet(router: str, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "omnican", "fleet", "--zenoh-mode", "client",
                           "--zenoh-connect", router, *args], capture_output=True, text=True,
                          timeout=TIMEOUT_S, check=False)


@contextlib.contextmanager
def cmd_vel(router: str, topic: str, vx: float) -> Iterator[None]:
    """A Twist of ``vx`` on ``topic`` at 20 Hz from another process (rmw_zenoh's format)
    while the block runs."""
    code = f"""
import sys, time
from omnican.telemetry import cdr
from omnican.zenoh import rmw
from tests.zenoh.conftest import client
s = client({router!r})
key = rmw.data_key(0, {topic!r}, "geometry_msgs/msg/Twist",
                   rmw.type_hash("geometry_msgs/msg/Twist"))
pub = s.declare_publisher(key)
data = cdr.encode("geometry_msgs/msg/Twist", {{"linear": {{"x": {vx}, "y": 0.0, "z": 0.0}},
                                              "angular": {{"x": 0.0, "y": 0.0, "z": 0.0}}}})
n = 0
while True:
    n += 1
    pub.put(data, attachment=rmw.Attachment(n, time.time_ns(), bytes(range(16))).encode())
    time.sleep(0.05)
"""
    proc = subprocess.Popen([sys.executable, "-c", code], env=dict(os.environ))
    try:
        yield
    finally:
        proc.kill()
        proc.wait()


def summaries_until(router: str, ok: Callable[[dict[str, Any]], bool]) -> bool:
    """``omnican fleet --json`` (another process) until a line's summaries by base name
    satisfy ``ok``."""
    watch = Proc([sys.executable, "-m", "omnican", "fleet", "--json", "--zenoh-mode",
                  "client", "--zenoh-connect", router], env=dict(os.environ))

    def good(line: str) -> bool:
        try:
            got = {b["name"]: b["summary"] for b in json.loads(line)["bases"]}
            return sorted(got) == NAMES and ok(got)
        except (ValueError, KeyError, TypeError):
            return False

    try:
        return watch.read_until(good, TIMEOUT_S) is not None
    finally:
        watch.kill()


def test_scripts_list_stop_and_see_a_killed_base_lost(router: str) -> None:
    with bases(router) as procs:
        done = fleet(router, "--once", "--json", "--wait", "30")
        assert done.returncode == 0, done.stderr
        snapshot = json.loads(done.stdout)
        assert [b["name"] for b in snapshot["bases"]] == NAMES
        assert all(b["summary"]["state"] == "RUNNING" and b["summary"]["battery_v"] > 20
                   for b in snapshot["bases"]), snapshot

        # robot1 driven by a cmd_vel publisher of a third process that keeps sending
        # through the fleet stop, as a navigation stack would.
        with cmd_vel(router, "/robot1/cmd_vel", 0.2):
            assert summaries_until(router, lambda b: b["/robot1/omnican"]["speed"]["vx"] > 0.1)
            done = fleet(router, "--stop", "all", "--wait", "30", "--timeout", "30")
            assert done.returncode == 0, done.stdout + done.stderr
            assert done.stdout.splitlines() == [
                f"stop {name}: ok: stopped: held until recover" for name in NAMES]
            held = summaries_until(router, lambda b: all(
                s["state"] == "STOPPED" and s["stopped_reason"].startswith("stopped by Zenoh")
                and s["true_speed"]["vx"] == 0.0 for s in b.values()))
            assert held, "the bases did not come to rest, held stopped"

        done = fleet(router, "--stop", "robot2", "--recover", "/robot1/omnican", "--json",
                     "--wait", "30", "--timeout", "30")
        assert done.returncode == 0, done.stdout + done.stderr
        got = [json.loads(line) for line in done.stdout.splitlines()]
        assert [(g["service"], g["base"], g["success"]) for g in got] == [
            ("stop", "/robot2/omnican", True), ("recover", "/robot1/omnican", True)]

        watch = Proc([sys.executable, "-m", "omnican", "fleet", "--json", "--zenoh-mode",
                      "client", "--zenoh-connect", router], env=dict(os.environ))
        try:
            def states(line: str) -> dict[str, str]:
                try:
                    return {b["name"]: b["state"] for b in json.loads(line)["bases"]}
                except (ValueError, KeyError, TypeError):
                    return {}

            assert watch.read_until(lambda line: sorted(states(line)) == NAMES
                                    and "LOST" not in states(line).values(), TIMEOUT_S)
            procs[1].p.send_signal(signal.SIGKILL)
            line = watch.read_until(lambda line: states(line).get(NAMES[1]) == "LOST",
                                    TIMEOUT_S)
            assert line is not None, watch.lines[-3:]
            assert states(line)[NAMES[0]] != "LOST"
        finally:
            watch.kill()


def rows_when(term: terminal.Pty, ok: Callable[[list[str]], bool]) -> list[str]:
    """The table's rows of the first whole frame whose rows ``ok`` accepts."""
    deadline = time.monotonic() + TIMEOUT_S
    while time.monotonic() < deadline:
        term.read(0.1)
        rows = [line for line in term.frame() if "/robot" in line and "session" not in line
                and not line.startswith("│")]
        if ok(rows):
            return rows
    raise AssertionError("no such frame:\n" + "\n".join(term.frame()))


def test_the_dashboard_shows_both_and_space_stops_all(router: str) -> None:
    with bases(router):
        term = terminal.Pty("fleet", "--zenoh-mode", "client", "--zenoh-connect", router,
                            "--timeout", "30", columns=80, lines=24)
        try:
            rows = rows_when(term, lambda rows: len(rows) == 2
                             and all("RUNNING" in row for row in rows))
            assert rows[0].startswith("> /robot1") and rows[1].startswith("  /robot2"), rows
            assert all(len(line) <= 80 for line in term.frame()), term.frame()
            # each base found once, in the events, however the run went
            found = [line for line in term.frame() if " found (session " in line]
            assert sorted(line.split()[2] for line in found) == NAMES, term.frame()
            term.keys(" ")
            for name in NAMES:
                term.wait_for(f"stop {name}: ok: stopped: held until recover", TIMEOUT_S)
            rows_when(term, lambda rows: len(rows) == 2
                      and all("STOPPED" in row for row in rows))
            term.keys("\x1b[B")  # the down arrow selects the second row
            rows_when(term, lambda rows: rows[1].startswith("> /robot2"))
            term.keys("\x1b[D")  # left selects nothing else
            term.keys("r")  # recover the selected base, and only it
            term.wait_for("recover /robot2/omnican: ok: recovered", TIMEOUT_S)
            rows = rows_when(term, lambda rows: "RUNNING" in rows[1])
            assert rows[1].startswith("> /robot2") and "STOPPED" in rows[0], rows
            term.keys("q")
            assert term.exit_code(TIMEOUT_S) == 0
        finally:
            term.close()


def test_an_unknown_base_is_one_line_exit_2(router: str,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    from omnican.cli import main

    code = main(["fleet", "--stop", "robot9", "--wait", "0.5", "--zenoh-mode", "client",
                 "--zenoh-connect", router])
    assert code == 2
    assert "fleet: no base named 'robot9' (found: none)" in one_error_line(
        capsys.readouterr().err)


def test_the_dashboard_wants_a_terminal(router: str, capsys: pytest.CaptureFixture[str],
                                        monkeypatch: pytest.MonkeyPatch) -> None:
    import io

    from omnican.cli import main

    monkeypatch.setattr(sys, "stdin", io.StringIO(""))
    assert main(["fleet", "--zenoh-connect", router]) == 2
    assert "reads keys from a terminal" in one_error_line(capsys.readouterr().err)


def test_the_fleet_view_can_be_the_router(tmp_path: object) -> None:
    """One machine, no zenohd: ``omnican fleet --router`` listens and a base (a peer that
    keeps trying its --zenoh-connect, started first) joins it."""
    from tests.zenoh.conftest import free_port

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    base = Proc([sys.executable, "-m", "omnican", "zenoh", "--sim", "--zenoh-connect",
                 endpoint, "--namespace", "/robot1"], env=dict(os.environ))
    watch = Proc([sys.executable, "-m", "omnican", "fleet", "--router", "--json",
                  "--zenoh-listen", endpoint], env=dict(os.environ))
    try:
        assert base.read_until(lambda line: "Ctrl-C to stop" in line, TIMEOUT_S), base.lines

        def running(line: str) -> bool:
            try:
                return [(b["name"], b["state"]) for b in json.loads(line)["bases"]] == [
                    (NAMES[0], "RUNNING")]
            except (ValueError, KeyError, TypeError):
                return False

        assert watch.read_until(running, TIMEOUT_S), watch.lines[-3:]
    finally:
        watch.kill()
        base.kill()


def test_router_and_a_mode_together_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    from omnican.cli import main

    assert main(["fleet", "--router", "--zenoh-mode", "client", "--once"]) == 2
    assert "--router makes this view the Zenoh router: drop --zenoh-mode" in one_error_line(
        capsys.readouterr().err)
