"""What the commands say when the world fails them (issue 36, item 11): a hub that goes
away, a kernel with no SocketCAN, and --help that fits a terminal. The words themselves
are tested in tests/io/test_bus_words.py; here, that every command says them."""

from __future__ import annotations

import argparse
import errno
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from omnican.cli import build_parser, main
from omnican.io.hub import LoopbackHub
from omnican.protocol.cia402 import State
from omnican.sim import SimulatedBase
from tests.support.helpers import ROOT, one_error_line, sim_config, wait_for

# ---------------------------------------------------------------- the hub goes away


def test_a_hub_that_goes_away_is_named_by_the_process_it_served(channel: str,
                                                                tmp_path: Path) -> None:
    """``omnican drive`` in another process, on drives behind a hub that closes (as when
    ``omnican sim`` quits): the stop names the hub, not a file descriptor of -1."""
    with SimulatedBase.from_config(sim_config(channel)) as sim:
        hub = LoopbackHub(channel, port=0)
        try:
            toml = tmp_path / "robot.toml"
            toml.write_text(
                f'[bus]\ninterface = "remote"\nchannel = "{hub.url}"\n\n'
                '[chassis]\nlayout = "b21"\nbase_radius = 0.19\n\n' +
                "".join(f"[[wheel]]\nnode_id = {n}\ngear_ratio = 16\nencoder_cpr = 4096\n"
                        "wheel_radius = 0.05\n\n" for n in (1, 2, 3)))
            env = {**os.environ, "PYTHONPATH": str(ROOT)}
            proc = subprocess.Popen(
                [sys.executable, "-m", "omnican", "drive", "--config", str(toml), "--vx", "0.05",
                 "--duration", "120"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                env=env, text=True)
            try:
                assert wait_for(lambda: all(d.state() is State.OPERATION_ENABLED
                                            for d in sim.drives), 60.0, 0.05)
                hub.close()
                _, err = proc.communicate(timeout=60)
            finally:
                if proc.poll() is None:
                    proc.kill()
                    proc.communicate()
        finally:
            hub.close()
    assert proc.returncode == 1, err
    assert (f"omnican: error: base stopped: CAN bus down (the hub at {hub.url} went away: "
            "did omnican sim stop?)") in err.splitlines(), err
    assert "file descriptor" not in err and "Traceback" not in err


# ---------------------------------------------------------------- no SocketCAN


@pytest.fixture
def no_socketcan(monkeypatch: pytest.MonkeyPatch) -> None:
    """A kernel without SocketCAN, as python-can meets it: creating the socket fails
    with EAFNOSUPPORT (whatever kernel the tests run on)."""
    from can.interfaces.socketcan import socketcan

    def refuse(*_: Any, **__: Any) -> Any:
        raise OSError(errno.EAFNOSUPPORT, os.strerror(errno.EAFNOSUPPORT))

    monkeypatch.setattr(socketcan, "create_socket", refuse)


NO_SOCKETCAN = ("omnican: error: cannot open CAN bus (channel=vcan0, interface=socketcan): "
                "this kernel has no SocketCAN (no CAN address family): load the kernel modules "
                "can and can_raw (sudo modprobe can_raw), and vcan for a virtual interface like "
                "vcan0 (sudo modprobe vcan)")


@pytest.mark.usefixtures("no_socketcan")
@pytest.mark.parametrize("argv", [
    ["sim", "-i", "socketcan", "-c", "vcan0", "--duration", "1"],
    ["drive", "-i", "socketcan", "-c", "vcan0", "--vx", "0.1"],
    ["scan", "-i", "socketcan", "-c", "vcan0"],
    ["monitor", "-i", "socketcan", "-c", "vcan0", "--duration", "1"],
])
def test_every_command_says_which_kernel_modules_are_missing(
        argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    """One line, the bus named the same way (``omnican sim`` printed a Python dict), the
    modules named, exit 1 (a failure at run time)."""
    assert main(argv) == 1
    assert one_error_line(capsys.readouterr().err) == NO_SOCKETCAN


# ---------------------------------------------------------------- --help


def _subparsers() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def test_help_fits_an_80_column_terminal(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every line argparse lays out (usage, options) fits 80 columns; python-can's -i
    listed its 24 interfaces twice on one line of 397 characters. (The descriptions
    are written by hand, laid out as they are.)"""
    monkeypatch.setenv("COLUMNS", "80")
    for name, full in _subparsers().items():
        laid_out = argparse.ArgumentParser(prog=full.prog, add_help=False, parents=[full],
                                           conflict_handler="resolve")  # no description
        text = laid_out.format_help()
        long = [line for line in text.splitlines() if len(line) > 80]
        assert not long, f"omnican {name} --help: {long}"


def test_the_interfaces_are_listed_once(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("COLUMNS", "80")
    for name in ("drive", "sim", "teleop"):
        text = " ".join(_subparsers()[name].format_help().split())
        assert text.count("udp_multicast") == 1, name
        assert "-i INTERFACE, --interface INTERFACE" in text, name
