"""omnican zenoh --sim as a user runs it: a router on loopback, the base a client of it;
its odometry reaches another session and 'quit' ends it with the drives disabled."""

from __future__ import annotations

import os
import sys
import threading

import pytest

from tests.interop.ros2_interop.harness import Proc
from tests.support.helpers import one_error_line
from tests.zenoh.conftest import client

TIMEOUT_S = 120.0  # real seconds, generous: a process starting on a loaded machine


def test_omnican_zenoh_sim_publishes_and_quits(router: str) -> None:
    from omnican.zenoh import rmw

    proc = Proc([sys.executable, "-m", "omnican", "zenoh", "--sim", "--zenoh-mode", "client",
                 "--zenoh-connect", router, "--namespace", "/robot1"], env=dict(os.environ))
    session = client(router)
    try:
        assert proc.read_until(lambda line: "Ctrl-C to stop" in line, TIMEOUT_S), proc.lines
        assert any(line.startswith("Zenoh node /robot1/omnican on domain 0")
                   for line in proc.lines), proc.lines
        got = threading.Event()
        key = rmw.data_key(0, "/robot1/odom", "nav_msgs/msg/Odometry",
                           rmw.type_hash("nav_msgs/msg/Odometry"))
        sub = session.declare_subscriber(key, lambda sample: got.set())
        assert got.wait(TIMEOUT_S)
        sub.undeclare()
        proc.send("quit")
        code, out = proc.finish(timeout=TIMEOUT_S)
        assert code == 0, out
        assert "drives disabled" in out and "published /robot1/odom " in out
    finally:
        session.close()
        proc.kill()


@pytest.mark.parametrize(("argv", "message"), [
    (["--domain-id", "999"], "zenoh: domain id 999 is not 0..232"),
    (["--namespace", "a b"], "zenoh: namespace 'a b' is not a ROS 2 namespace"),
    (["--zenoh-connect", "127.0.0.1:7447"], "is not a Zenoh endpoint"),
    (["--zenoh-mode", "router"], "invalid choice: 'router'"),
])
def test_bad_invocations_are_one_line_exit_2(argv: list[str], message: str,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("zenoh")
    from omnican.cli import main

    try:
        code = main(["zenoh", "--sim", *argv])
    except SystemExit as exc:  # argparse's own errors
        code = int(exc.code or 0)
    assert code == 2
    assert message in one_error_line(capsys.readouterr().err)


def test_without_the_zenoh_extra_it_says_what_to_install(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    from omnican.cli import main
    from omnican.extras import install_hint

    monkeypatch.setitem(sys.modules, "zenoh", None)
    assert main(["zenoh", "--sim"]) == 2
    assert install_hint("zenoh") in one_error_line(capsys.readouterr().err)
