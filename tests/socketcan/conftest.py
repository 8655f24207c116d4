"""Fixtures of the SocketCAN tests (marker ``socketcan``).

They need real kernel CAN interfaces ``vcan0`` and ``vcan1``; where there are none
(our machines' kernel has no CAN) they skip, saying how to run them:
``tools/socketcan-tests`` boots a Linux guest that has SocketCAN and runs them there.

``omnican sim`` on vcan0 is shared by the tests of a session (it takes ~10 s to start
under emulation); each test leaves its drives as it found them (heartbeats on, not
frozen) and compares poses relative to where the base stood when it began. Tests that
take an interface down or fill its transmit queue use vcan1 and a simulator of their own.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from .support import SimProcess, admin_problem, sh, vcan_problem, write_config

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


@pytest.fixture
def disrupted_toml(tmp_path: Path) -> Iterator[Path]:
    """A config on vcan1, for tests that take the interface down or fill its queue; the
    interface is put back (up, no qdisc) whatever the test did."""
    problem = admin_problem()
    if problem is not None:
        pytest.skip(problem)
    yield write_config(tmp_path / "robot.toml", DISRUPTED)
    sh("ip", "link", "set", DISRUPTED, "up")
    sh("tc", "qdisc", "replace", "dev", DISRUPTED, "root", "pfifo_fast")
    sh("tc", "qdisc", "del", "dev", DISRUPTED, "root")
