"""What the DDS tests share: a private network namespace that has only loopback, the
cached venv of real ROS 2 wheels, and line-oriented child processes.

Every DDS process of a test runs inside the namespace (``unshare -n`` as root; then
``nsenter`` into it), so nothing can leave the machine whatever DDS decides, and tests
running side by side cannot see each other. Where no such namespace can be made the
tests are skipped: they cannot guarantee loopback-only traffic otherwise.
"""

from __future__ import annotations

import hashlib
import json
import os
import select
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import IO, Any

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[2]
FASTDDS_PROFILE = HERE / "fastdds_loopback.xml"

#: The ROS 2 wheels per distribution: rclpy with Fast DDS and the message packages.
#: Kilted's Fast DDS 3 announces XTypes type information (the case omnican's Cyclone
#: settings are for); Jazzy, the LTS most nav stacks run, has Fast DDS 2, which does not.
ROS_PACKAGES: dict[str, tuple[str, ...]] = {
    distro: (f"ros-{distro}-rclpy[fastrtps]=={rclpy}",
             *(f"ros-{distro}-{pkg}-msgs=={msgs}"
               for pkg in ("std", "geometry", "nav", "sensor", "diagnostic")))
    for distro, rclpy, msgs in (("kilted", "9.1.2", "5.5.1"), ("jazzy", "7.1.6", "5.3.6"))
}
INSTALL_TIMEOUT_S = 900


def netns_unavailable() -> str | None:
    """Why a loopback-only namespace cannot be made here (None: it can)."""
    if not sys.platform.startswith("linux"):
        return "DDS tests need a Linux network namespace to stay on loopback"
    missing = [t for t in ("unshare", "nsenter", "ip") if shutil.which(t) is None]
    if missing:
        return f"DDS tests need {', '.join(missing)} (util-linux, iproute2) for a " \
               "loopback-only network namespace"
    if os.geteuid() != 0:
        return "DDS tests need root for 'unshare -n' (a network namespace with only loopback)"
    return None


class NetNs:
    """A network namespace with only the loopback interface, up. Use as a context manager;
    :meth:`wrap` turns a command line into one that runs inside it."""

    def __init__(self) -> None:
        self._holder = subprocess.Popen(
            ["unshare", "-n", "sh", "-c", "ip link set lo up && echo up && exec sleep 3600"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        assert self._holder.stdout is not None
        line = self._holder.stdout.readline().strip()
        if line != "up":
            err = self._holder.stderr.read() if self._holder.stderr else ""
            self.close()
            raise RuntimeError(f"cannot make a network namespace: {err.strip() or line!r}")
        links = subprocess.run(self.wrap(["ip", "-o", "link"]), capture_output=True, text=True,
                               check=True).stdout.splitlines()
        names = [ln.split(":")[1].strip() for ln in links]
        if names != ["lo"]:
            self.close()
            raise RuntimeError(f"namespace has other interfaces than lo: {names}")

    def wrap(self, argv: Sequence[str]) -> list[str]:
        return ["nsenter", f"--net=/proc/{self._holder.pid}/ns/net", "--", *argv]

    def close(self) -> None:
        if self._holder.poll() is None:
            self._holder.kill()
        self._holder.wait()
        for stream in (self._holder.stdout, self._holder.stderr):
            if stream is not None:
                stream.close()

    def __enter__(self) -> NetNs:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def clean_env(**extra: str) -> dict[str, str]:
    """The environment without DDS or ROS settings of the person running the tests."""
    env = {k: v for k, v in os.environ.items()
           if not k.startswith(("ROS_", "RMW_", "CYCLONEDDS", "FASTRTPS", "FASTDDS",
                                "AMENT_", "_ROS_WHEELS"))
           and k not in ("LD_LIBRARY_PATH", "PYTHONPATH")}
    env.update(extra)
    return env


class Proc:
    """A child process with stdin for commands and stdout read line by line."""

    def __init__(self, argv: Sequence[str], env: dict[str, str], cwd: Path | None = None,
                 stderr: IO[str] | None = None) -> None:
        self.argv = list(argv)
        self.p = subprocess.Popen(argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                  stderr=stderr if stderr is not None else subprocess.STDOUT,
                                  env=env, cwd=cwd)
        self.lines: list[str] = []
        self._buf = b""
        self._eof = False

    def send(self, line: str) -> None:
        assert self.p.stdin is not None
        self.p.stdin.write(line.encode() + b"\n")
        self.p.stdin.flush()

    def read_until(self, pred: Any, timeout: float) -> str | None:
        """Read lines until one satisfies ``pred``; returns it (None on timeout or EOF)."""
        assert self.p.stdout is not None
        fd = self.p.stdout.fileno()
        end = time.monotonic() + timeout
        while True:
            while b"\n" in self._buf:
                raw, _, self._buf = self._buf.partition(b"\n")
                line = raw.decode(errors="replace")
                self.lines.append(line)
                if pred(line):
                    return line
            left = end - time.monotonic()
            if left <= 0 or self._eof:
                return None
            ready, _, _ = select.select([fd], [], [], left)
            if ready:
                chunk = os.read(fd, 65536)  # unbuffered: select() sees all that is unread
                if not chunk:
                    self._eof = True
                self._buf += chunk

    def read_json(self, event: str, timeout: float) -> dict[str, Any] | None:
        def is_event(line: str) -> bool:
            try:
                return bool(json.loads(line).get("event") == event)
            except (ValueError, AttributeError):
                return False
        line = self.read_until(is_event, timeout)
        return None if line is None else dict(json.loads(line))

    def finish(self, timeout: float = 15.0) -> tuple[int, str]:
        """Close stdin, collect the rest of the output, wait; kill if it hangs."""
        try:
            rest, _ = self.p.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.p.kill()
            rest, _ = self.p.communicate()
        text = (self._buf + (rest or b"")).decode(errors="replace")
        self._buf = b""
        self.lines += text.splitlines()
        return self.p.returncode, "\n".join(self.lines)

    def interrupt(self) -> None:
        self.p.send_signal(signal.SIGINT)  # as Ctrl-C

    def kill(self) -> None:
        """End it if it still runs and release its pipes."""
        if self.p.returncode is None:
            self.p.kill()
            try:
                self.finish(timeout=10.0)
            except (OSError, ValueError):
                pass
        for stream in (self.p.stdin, self.p.stdout):
            if stream is not None and not stream.closed:
                try:
                    stream.close()
                except OSError:
                    pass


# ------------------------------------------------------------ the ROS 2 venv

def cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "omnican" / "ros2-interop"


def ros_venv(distro: str) -> tuple[Path | None, str]:
    """The python of a venv holding the distribution's :data:`ROS_PACKAGES`, made once and
    cached under ~/.cache/omnican (keyed by the pins and this Python); (None, why) if it
    cannot be installed. Returns (python, a note on what it did)."""
    packages = ROS_PACKAGES[distro]
    key = hashlib.sha256(json.dumps([sys.version_info[:2], packages]).encode()
                         ).hexdigest()[:16]
    venv = cache_dir() / f"{distro}-py{sys.version_info[0]}{sys.version_info[1]}-{key}"
    python = venv / "bin" / "python"
    if (venv / "omnican-ok").is_file() and python.is_file():
        return python, f"cached venv {venv}"
    tmp = venv.with_name(venv.name + f".tmp{os.getpid()}")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    try:
        subprocess.run([sys.executable, "-m", "venv", str(tmp)], check=True,
                       capture_output=True, timeout=120)
        done = subprocess.run([str(tmp / "bin" / "python"), "-m", "pip", "install",
                               "--disable-pip-version-check", "-q", *packages],
                              check=False, capture_output=True, text=True,
                              timeout=INSTALL_TIMEOUT_S,
                              env=clean_env())
    except (subprocess.SubprocessError, OSError) as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        return None, f"cannot make a venv for the ROS 2 wheels: {exc}"
    if done.returncode != 0:
        shutil.rmtree(tmp, ignore_errors=True)
        tail = " | ".join((done.stderr or done.stdout).strip().splitlines()[-3:])
        return None, f"cannot install the ROS 2 {distro} wheels from PyPI: {tail}"
    (tmp / "omnican-ok").write_text(json.dumps({"packages": packages,
                                                "install_s": time.monotonic() - t0}))
    try:
        tmp.rename(venv)
    except OSError:  # another run made it meanwhile
        shutil.rmtree(tmp, ignore_errors=True)
    if not python.is_file():
        return None, f"the ROS 2 venv at {venv} has no python"
    return python, f"installed the ROS 2 {distro} wheels in {time.monotonic() - t0:.0f} s"
