"""Shared fixtures. Every test gets its own virtual CAN channel, and no test may
leave a thread or a bus behind (the check runs after each test)."""

from __future__ import annotations

import signal
import threading
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import settings

# Property tests check behaviour, not speed: no per-example deadline (on a loaded
# machine hypothesis's default 200 ms deadline fails examples that are correct).
settings.register_profile("omnican", deadline=None)
# Before a release, or after touching pure code: pytest --hypothesis-profile thorough
# (tests that set their own max_examples keep it; vary --hypothesis-seed for those).
settings.register_profile("thorough", deadline=None, max_examples=2000)
settings.load_profile("omnican")

# A test run started in the background (`cmd &` in a script, some CI launchers) has
# SIGINT ignored, and every program it starts would inherit that: each Ctrl-C test
# would then find a program that never saw its Ctrl-C. The tests stand for a user
# at a terminal, where Ctrl-C is live; programs started from here get the default.
if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)



@pytest.fixture
def channel(request: pytest.FixtureRequest) -> str:
    """A virtual channel name no other test uses."""
    return f"omnican-test-{request.node.name}-{uuid.uuid4().hex[:8]}"


def _live_threads() -> set[threading.Thread]:
    # A _DummyThread is a thread Python did not start (foxglove-sdk's, calling a listener)
    # that Python code once asked about; Python never forgets it, and no test can join it.
    return {t for t in threading.enumerate() if t is not threading.main_thread() and t.is_alive()
            and not isinstance(t, threading._DummyThread)}


@pytest.fixture(autouse=True)
def no_leaked_threads() -> Iterator[None]:
    before = _live_threads()
    yield
    deadline = time.monotonic() + 3.0
    while True:
        leaked = {t for t in _live_threads() - before if not t.name.startswith("asyncio")}
        if not leaked or time.monotonic() > deadline:
            break
        time.sleep(0.02)
    assert not leaked, f"test leaked threads: {sorted(t.name for t in leaked)}"


@pytest.fixture(autouse=True)
def no_leaked_virtual_channels() -> Iterator[None]:
    from can.interfaces import virtual

    before = set(virtual.channels)
    yield
    deadline = time.monotonic() + 3.0
    while True:
        leaked = {c for c in set(virtual.channels) - before if virtual.channels.get(c)}
        if not leaked or time.monotonic() > deadline:
            break
        time.sleep(0.02)
    assert not leaked, f"test left virtual buses open on: {sorted(leaked)}"


@pytest.fixture
def served(channel: str, tmp_path: Path) -> Iterator[tuple[Any, Path]]:
    """Simulated drives in this process behind a loopback hub, and a config file that
    reaches them from another process (``interface = "remote"``)."""
    from omnican.io.hub import LoopbackHub
    from omnican.sim import SimulatedBase
    from tests.support.helpers import sim_config

    cfg = sim_config(channel)
    with SimulatedBase.from_config(cfg) as sim, LoopbackHub(channel, port=0) as hub:
        toml = tmp_path / "robot.toml"
        toml.write_text(
            f'[bus]\ninterface = "remote"\nchannel = "{hub.url}"\n\n'
            "[chassis]\nlayout = \"b21\"\nbase_radius = 0.19\n\n" +
            "".join(f"[[wheel]]\nnode_id = {n}\ngear_ratio = 16\nencoder_cpr = 4096\n"
                    "wheel_radius = 0.05\n\n" for n in (1, 2, 3)))
        yield sim, toml
