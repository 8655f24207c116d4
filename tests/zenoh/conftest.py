"""A Zenoh router on loopback for each test, and the ROS 2 message definitions that
zenoh-ros2-sdk (the independent rmw_zenoh peer) reads instead of cloning repositories.

Everything binds to 127.0.0.1 with multicast scouting off: nothing leaves the machine.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.support.helpers import locked

#: The message packages the tests' types need (with what they use): their wheels on PyPI
#: ship the .msg and .srv files under <name>.data/data/share/<package>/{msg,srv}/.
MESSAGE_WHEELS = ("ros-builtin-interfaces==2.0.3", "ros-std-msgs==5.3.6",
                  "ros-geometry-msgs==5.3.6", "ros-nav-msgs==5.3.6",
                  "ros-sensor-msgs==5.3.6", "ros-diagnostic-msgs==5.3.6",
                  "ros-std-srvs==5.3.6")


def _cache() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "omnican" / "zenoh-messages"


def message_dir() -> tuple[Path | None, str]:
    """A directory of <package>/{msg,srv}/<Name>.{msg,srv} from :data:`MESSAGE_WHEELS`, made once
    (pip download, unzip the share directories) and cached; (None, why) if it cannot."""
    root = _cache()
    out = root / "messages"
    with locked(root / "lock"):
        ok = out / "omnican-ok"
        if ok.is_file() and ok.read_text() == "\n".join(MESSAGE_WHEELS):
            return out, "cached"
        wheels = root / "wheels"
        done = subprocess.run([sys.executable, "-m", "pip", "download", "--no-deps",
                               "--disable-pip-version-check", "-q", "-d", str(wheels),
                               *MESSAGE_WHEELS], capture_output=True, text=True,
                              timeout=600, check=False)
        if done.returncode != 0:
            tail = " | ".join((done.stderr or done.stdout).strip().splitlines()[-3:])
            return None, f"cannot download the ROS 2 message wheels: {tail}"
        for wheel in wheels.glob("*.whl"):
            with zipfile.ZipFile(wheel) as z:
                for name in z.namelist():
                    parts = name.split("/")
                    if len(parts) == 6 and parts[2] == "share" and parts[4] in ("msg", "srv") \
                            and parts[5].endswith((".msg", ".srv")):
                        target = out / parts[3] / parts[4] / parts[5]
                        target.parent.mkdir(parents=True, exist_ok=True)
                        target.write_bytes(z.read(name))
        ok.write_text("\n".join(MESSAGE_WHEELS))
    return out, "downloaded"


def wait_real(done: Callable[[], bool], timeout_s: float = 60.0) -> bool:
    """``done()`` became true within ``timeout_s`` real seconds (generous: what the Zenoh
    side does in its own threads; nothing is timed)."""
    deadline = time.monotonic() + timeout_s
    while not done():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


@pytest.fixture
def router() -> Iterator[str]:
    """An in-process Zenoh router on tcp/127.0.0.1:<free port>; yields its endpoint."""
    zenoh = pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed "
                                "(pip install 'omnican[zenoh]')")
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


def client(endpoint: str) -> Any:
    """A client session of the router at ``endpoint``."""
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", f'["{endpoint}"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(conf)


@pytest.fixture
def sdk(router: str, monkeypatch: pytest.MonkeyPatch) -> Iterator[Any]:
    """zenoh-ros2-sdk, its message registry on the downloaded definitions, its session
    a peer of ``router`` listening on loopback only; closed after the test."""
    sdk = pytest.importorskip("zenoh_ros2_sdk", reason="zenoh-ros2-sdk is not installed "
                              "(pip install zenoh-ros2-sdk)")
    from zenoh_ros2_sdk import message_registry
    from zenoh_ros2_sdk.session import ZenohSession

    where, why = message_dir()
    if where is None:
        pytest.skip(why)
    monkeypatch.setattr(message_registry, "_registry",
                        message_registry.MessageRegistry(str(where)))
    monkeypatch.setenv("ZENOH_CONFIG_OVERRIDE", 'listen/endpoints=["tcp/127.0.0.1:0"]')
    port = int(router.rsplit(":", 1)[1])
    session = ZenohSession.get_instance("127.0.0.1", port)
    try:
        yield sdk
    finally:
        session.close()
