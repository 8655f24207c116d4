"""Program download across processes: ``omnican sim`` serving its drives in one process,
``omnican firmware`` in another; and the safety path, a base driving from a third
process: the download is refused and nothing is written."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import zlib
from collections.abc import Iterator
from pathlib import Path

import canopen
import pytest

from tests.process.test_faults_process import SimProcess, free_port

ROOT = Path(__file__).resolve().parents[2]
HOST = ROOT / "tests" / "support" / "host_process.py"
WHEELS = "".join(f"[[wheel]]\nnode_id = {n}\ngear_ratio = 16\nencoder_cpr = 4096\n"
                 "wheel_radius = 0.05\n\n" for n in (1, 2, 3))
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}


@pytest.fixture
def port() -> Iterator[int]:
    yield free_port()
    while SimProcess.started:  # no simulator outlives its test
        SimProcess.started.pop().kill()


def robot_toml(tmp_path: Path, port: int) -> Path:
    toml = tmp_path / "robot.toml"
    toml.write_text(f'[bus]\ninterface = "remote"\nchannel = "ws://127.0.0.1:{port}/"\n\n'
                    f'[chassis]\nlayout = "b21"\nbase_radius = 0.19\n\n{WHEELS}')
    return toml


def firmware(toml: Path, image: Path, *more: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "omnican", "firmware", "--config", str(toml), "--image",
         str(image), "--sdo-timeout", "10", *more],  # generous: a loaded machine
        check=False, capture_output=True, text=True, env=ENV, timeout=120)


def identification(port: int, node_id: int) -> int:
    """1F56h of a node, read over the simulator's hub by this process."""
    network = canopen.Network()
    network.connect(interface="remote", channel=f"ws://127.0.0.1:{port}/")
    try:
        node = canopen.RemoteNode(node_id, canopen.ObjectDictionary())
        node.sdo.RESPONSE_TIMEOUT = 3.0
        network.add_node(node)
        return int.from_bytes(node.sdo.upload(0x1F56, 1)[:4], "little")
    finally:
        network.disconnect()


def test_an_image_goes_into_another_processes_drives(port: int, tmp_path: Path) -> None:
    toml = robot_toml(tmp_path, port)
    image = tmp_path / "drive.bin"
    image.write_bytes(bytes(range(256)) * 1024)  # 256 KiB
    SimProcess(port, "--config", str(toml))
    done = firmware(toml, image)
    assert done.returncode == 0, (done.stdout, done.stderr)
    crc = f"0x{zlib.crc32(image.read_bytes()):08X}"
    lines = done.stdout.splitlines()
    assert len(lines) == 4 and lines[3] == "3 of 3 drives run the image"
    for n, line in zip((1, 2, 3), lines, strict=False):
        assert line.startswith(f"node {n}: program of 262144 bytes downloaded in ")
        assert line.endswith(f"started; flash: program valid; identification {crc}")
    assert identification(port, 2) == zlib.crc32(image.read_bytes())


def test_refused_while_another_process_drives_the_base(port: int, tmp_path: Path) -> None:
    toml = robot_toml(tmp_path, port)
    old, new = tmp_path / "old.bin", tmp_path / "new.bin"
    old.write_bytes(b"old program " * 100)
    new.write_bytes(b"new program " * 100)
    SimProcess(port, "--config", str(toml))
    assert firmware(toml, old, "--node", "1").returncode == 0
    host = subprocess.Popen([sys.executable, str(HOST), str(toml)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=ENV)
    try:
        assert host.stdout is not None
        assert host.stdout.readline().strip() == "ready"
        refused = firmware(toml, new, "--node", "1")
    finally:
        host.send_signal(signal.SIGTERM)
        host.communicate(timeout=30)
    assert refused.returncode == 1 and refused.stdout == ""
    err = refused.stderr.strip()
    assert err.startswith("omnican: error: firmware refused: ") and "\n" not in err
    assert err.endswith("stop it first; nothing was written")
    assert identification(port, 1) == zlib.crc32(old.read_bytes())  # the old one, untouched
    done = firmware(toml, new, "--node", "1")  # the base stopped: now it goes in
    assert done.returncode == 0, done.stderr
    assert identification(port, 1) == zlib.crc32(new.read_bytes())
