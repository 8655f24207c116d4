"""The fusion's stops across processes: the simulated drives in this process, the host in
another (tests/support/imu_host_process.py) with a gyro fed from here, a third party to
both. A slipping wheel stops the base where ``fusion.stop_on_slip`` says so; a silent IMU
warns and the base keeps driving, and stops it only with ``fusion.stop_on_imu_stale``."""

from __future__ import annotations

import os
import queue
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from omnican.sim import SimulatedBase
from omnican.sim.slip import SimSlip, set_slip
from tests.support.helpers import still, wait_for

HOST = Path(__file__).resolve().parents[1] / "support" / "imu_host_process.py"
ROOT = Path(__file__).resolve().parents[2]
BIAS = 0.008  # rad/s (0.46 deg/s)
TIMEOUT_S = 20.0  # a loaded machine: generous


class Host:
    """The host process, its stdout lines in a queue, and a gyro thread writing the
    simulator's true yaw rate (plus a bias) to its stdin at 100 Hz while ``gyro`` is set."""

    def __init__(self, sim: SimulatedBase, toml: Path) -> None:
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        self.proc = subprocess.Popen([sys.executable, str(HOST), str(toml)],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True, env=env)
        self.lines: queue.Queue[str] = queue.Queue()
        self.gyro = threading.Event()
        self.gyro.set()
        self._done = threading.Event()
        self._threads = [threading.Thread(target=self._read, daemon=True),
                         threading.Thread(target=self._write, args=(sim,), daemon=True)]
        for t in self._threads:
            t.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.put(line.strip())

    def _write(self, sim: SimulatedBase) -> None:
        assert self.proc.stdin is not None
        while not self._done.is_set():
            if self.gyro.is_set():
                try:
                    self.proc.stdin.write(f"{sim.true_twist.wz + BIAS}\n")
                    self.proc.stdin.flush()
                except (BrokenPipeError, ValueError):
                    return
            time.sleep(0.01)

    def expect(self, start: str, timeout: float = TIMEOUT_S) -> str:
        """The first line from now on starting with ``start``."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            try:
                line = self.lines.get(timeout=0.1)
            except queue.Empty:
                continue
            if line.startswith(start):
                return line
        raise AssertionError(f"no line starting {start!r} within {timeout} s")

    def seen(self, start: str) -> bool:
        out = False
        while not self.lines.empty():
            out = out or self.lines.get().startswith(start)
        return out

    def close(self) -> str:
        self._done.set()
        self.proc.send_signal(2)  # SIGINT: the host's controlled stop
        try:
            _, err = self.proc.communicate(timeout=15)
        finally:
            if self.proc.poll() is None:
                self.proc.kill()
                self.proc.communicate(timeout=5)
        return err


@contextmanager
def host(served: tuple[SimulatedBase, Path], fusion: str) -> Iterator[tuple[SimulatedBase, Host]]:
    sim, toml = served
    toml.write_text(toml.read_text() + f"[fusion]\n{fusion}\n")
    h = Host(sim, toml)
    try:
        assert h.expect("ready") == "ready"
        assert wait_for(lambda: sim.true_twist.vx > 0.2, TIMEOUT_S)
        yield sim, h
    finally:
        err = h.close()
        assert "Traceback" not in err, err


def test_a_slipping_wheel_stops_the_base_of_another_process(
        served: tuple[SimulatedBase, Path]) -> None:
    with host(served, "stop_on_slip = true\nslip_warn_s = 0.3") as (sim, h):
        time.sleep(0.5)
        assert not h.seen("stopped")
        set_slip(sim, SimSlip(ratios=(0.0, 0.2, 0.0)))
        assert "slipping" in h.expect("stopped: ")
        assert wait_for(lambda: still(sim), TIMEOUT_S)


def test_a_silent_imu_warns_and_the_base_drives_on(served: tuple[SimulatedBase, Path]) -> None:
    with host(served, "slip_warn_s = 0.5") as (sim, h):
        h.gyro.clear()
        assert "IMU silent" in h.expect("warning: IMU silent")
        time.sleep(0.5)
        assert not h.seen("stopped")
        assert sim.true_twist.vx > 0.2  # still driving, on the wheels alone


def test_a_silent_imu_stops_the_base_when_configured(served: tuple[SimulatedBase, Path]) -> None:
    with host(served, "stop_on_imu_stale = true") as (sim, h):
        time.sleep(0.3)
        assert not h.seen("stopped")
        h.gyro.clear()
        assert "IMU went silent" in h.expect("stopped: ")
        assert wait_for(lambda: still(sim), TIMEOUT_S)
