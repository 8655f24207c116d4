"""Fixtures of the SocketCAN tests (marker ``socketcan``).

They need real kernel CAN interfaces ``vcan0`` and ``vcan1``; where there are none
(our machines' kernel has no CAN) they skip, saying how to run them:
``tools/socketcan-tests`` boots a Linux guest that has SocketCAN and runs them there.

``omnican sim`` on vcan0 and the host program on the Chassis API are shared by the
tests of a session (each takes 10-30 s to start under emulation): each test leaves the
drives as it found them (heartbeats on, not frozen) and the base recovered and still,
and compares poses relative to where the base stood when it began. A test that needs a
fresh host (killed, terminated) starts its own. Tests that take an interface down or
fill its transmit queue use vcan1 and a simulator and host of their own.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.interop.socketcan.support import (
    HostProcess,
    SimProcess,
    admin_problem,
    no_traceback,
    sh,
    vcan_problem,
    write_config,
)

CHANNEL = "vcan0"
DISRUPTED = "vcan1"


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    problems: dict[str, str | None] = {}
    for item in items:
        if item.get_closest_marker("socketcan") is None:
            continue
        for channel in (CHANNEL, DISRUPTED):
            if channel not in problems:
                problems[channel] = vcan_problem(channel)
            problem = problems[channel]
            if problem is not None:
                item.add_marker(pytest.mark.skip(reason=problem))
                break


@pytest.fixture(scope="session")
def toml(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_config(tmp_path_factory.mktemp("vcan0") / "robot.toml", CHANNEL)


@pytest.fixture(scope="session")
def _shared_sim(toml: Path) -> Iterator[list[SimProcess]]:
    box: list[SimProcess] = []
    yield box
    for sim in box:
        sim.close()


@pytest.fixture
def sim(_shared_sim: list[SimProcess], toml: Path) -> Iterator[SimProcess]:
    """``omnican sim -i socketcan -c vcan0``, started once a session (again if it died)."""
    if not _shared_sim or not _shared_sim[0].healthy():
        if _shared_sim:
            _shared_sim.pop().kill()
        _shared_sim.append(SimProcess(toml, CHANNEL, toml.with_name("sim.stderr")))
    s = _shared_sim[0]
    yield s
    if s.healthy():
        for node in (1, 2, 3):  # what a test may have changed
            s.command(f"heartbeat {node} on", f"node {node}: heartbeat on")
            s.command(f"thaw {node}", f"node {node}: thawed")
    assert "Traceback" not in s.stderr(), s.stderr()[-4000:]


@pytest.fixture(scope="session")
def _shared_host(_shared_sim: list[SimProcess]) -> Iterator[list[HostProcess]]:
    box: list[HostProcess] = []
    yield box
    _close_host(box)


def _usable(h: HostProcess) -> bool:
    """Alive, and enabled (after recover() if a test left the base stopped)."""
    if h.proc.poll() is not None:
        return False
    if h.status()["status"]["enabled"]:
        return True
    return bool(h.request("recover")["ok"])


@pytest.fixture
def host(sim: SimProcess, _shared_host: list[HostProcess], toml: Path) -> Iterator[HostProcess]:
    """tests/interop/socketcan/host.py on vcan0 (a new one if the last one is unusable)."""
    if _shared_host and not _usable(_shared_host[0]):
        _shared_host.pop().kill()
    if not _shared_host:
        n = len(list(toml.parent.glob("host*.stderr")))
        _shared_host.append(HostProcess(toml, toml.with_name(f"host{n}.stderr")))
    h = _shared_host[0]
    yield h
    if h.proc.poll() is None:
        h.request("hold")
    no_traceback(h.stderr(), "the host")


def _close_host(box: list[HostProcess]) -> None:
    while box:
        h = box.pop()
        try:
            assert h.close() == 0, h.stderr()[-3000:]
            no_traceback(h.stderr(), "the host")
        finally:
            h.kill()


@pytest.fixture
def no_host(_shared_host: list[HostProcess]) -> None:
    """The shared host closed: the test runs its own master on vcan0."""
    _close_host(_shared_host)


@pytest.fixture
def quiet_vcan0(_shared_host: list[HostProcess], _shared_sim: list[SimProcess]) -> None:
    """Nothing left running on vcan0 (the guest's two CPUs go to the test's processes)."""
    _close_host(_shared_host)
    while _shared_sim:
        sim = _shared_sim.pop()
        assert sim.close() == 0, sim.stderr()[-3000:]


@pytest.fixture
def disrupted_toml(tmp_path: Path, quiet_vcan0: None) -> Iterator[Path]:
    """A config on vcan1, for tests that take the interface down or fill its queue; the
    interface is put back (up, no qdisc) whatever the test did."""
    problem = admin_problem()
    if problem is not None:
        pytest.skip(problem)
    yield write_config(tmp_path / "robot.toml", DISRUPTED)
    sh("ip", "link", "set", DISRUPTED, "up")
    sh("tc", "qdisc", "replace", "dev", DISRUPTED, "root", "pfifo_fast")
    sh("tc", "qdisc", "del", "dev", DISRUPTED, "root")
