"""Foxglove's own client library (``@foxglove/ws-protocol`` from npm, on Node.js) against
omnican as a separate process: the install (once, cached), the client (client.cjs, JSON
lines both ways) and omnican's process with its output read as it comes.

The npm packages are pinned by package.json and package-lock.json beside this file and
installed with ``npm ci`` into ~/.cache/omnican/foxglove-node/<key>/ (keyed by both
files and Node's major version), never into the repository.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import queue
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

from tests.support.helpers import locked

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[2]
CLIENT = HERE / "client.cjs"
INSTALL_TIMEOUT_S = 300
NODE_MAJOR_MIN = 18


def cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "omnican" / "foxglove-node"


def node_modules(packages: Path = HERE) -> tuple[Path | None, str]:
    """The node_modules holding the packages pinned in ``packages`` (a folder with a
    package.json and package-lock.json: the client's, or app/ for the app's own code),
    installed on first use; (None, why) where Node.js or npm is missing or the install
    fails. Returns (path, a note on what it did)."""
    node, npm = shutil.which("node"), shutil.which("npm")
    if node is None or npm is None:
        return None, f"needs Node.js {NODE_MAJOR_MIN}+ and npm ({'node' if node is None else 'npm'} " \
                     "not found on PATH)"
    try:
        version = subprocess.run([node, "--version"], capture_output=True, text=True,
                                 timeout=30, check=True).stdout.strip()
        major = int(version.lstrip("v").split(".")[0])
    except (subprocess.SubprocessError, OSError, ValueError) as exc:
        return None, f"cannot run node: {exc}"
    if major < NODE_MAJOR_MIN:
        return None, f"needs Node.js {NODE_MAJOR_MIN} or later, found {version}"
    files = [packages / "package.json", packages / "package-lock.json"]
    key = hashlib.sha256(b"".join(f.read_bytes() for f in files) + str(major).encode()
                         ).hexdigest()[:16]
    target = cache_dir() / f"node{major}-{key}"
    modules = target / "node_modules"
    if (target / "omnican-ok").is_file():
        return modules, f"cached {target}"
    with locked(cache_dir() / f".{key}.lock"):
        if (target / "omnican-ok").is_file():
            return modules, f"cached {target}"
        tmp = target.with_name(target.name + f".tmp{os.getpid()}")
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir(parents=True)
        for f in files:
            shutil.copy(f, tmp / f.name)
        t0 = time.monotonic()
        try:
            done = subprocess.run([npm, "ci", "--no-audit", "--no-fund", "--loglevel=error"],
                                  cwd=tmp, capture_output=True, text=True, check=False,
                                  timeout=INSTALL_TIMEOUT_S)
        except (subprocess.SubprocessError, OSError) as exc:
            shutil.rmtree(tmp, ignore_errors=True)
            return None, f"npm ci failed: {exc}"
        if done.returncode != 0:
            shutil.rmtree(tmp, ignore_errors=True)
            tail = " | ".join((done.stderr or done.stdout).strip().splitlines()[-3:])
            return None, f"cannot install the Foxglove packages of {packages.name}/ from npm: {tail}"
        seconds = time.monotonic() - t0
        (tmp / "omnican-ok").write_text(json.dumps({"install_s": round(seconds, 1)}))
        shutil.rmtree(target, ignore_errors=True)
        tmp.rename(target)
    return modules, f"installed the Foxglove packages of {packages.name}/ in {seconds:.0f} s"


class _Lines:
    """A pipe's lines, read as they come by a thread of its own (joined on close)."""

    def __init__(self, stream: IO[str], name: str) -> None:
        self.lines: queue.Queue[str | None] = queue.Queue()
        self.seen: list[str] = []
        self._thread = threading.Thread(target=self._read, args=(stream,), name=name,
                                        daemon=True)
        self._thread.start()

    def _read(self, stream: IO[str]) -> None:
        for line in stream:
            self.lines.put(line.rstrip("\n"))
        self.lines.put(None)

    def next(self, deadline: float) -> str | None:
        """The next line, or None at the end or the deadline."""
        try:
            line = self.lines.get(timeout=max(0.0, deadline - time.monotonic()))
        except queue.Empty:
            return None
        if line is not None:
            self.seen.append(line)
        return line

    def join(self) -> None:
        self._thread.join(10.0)


class NodeClient:
    """client.cjs connected to ``url``, offering ``protocols`` (comma-separated), as if
    opened by a web page at ``origin`` (None: not a browser)."""

    def __init__(self, modules: Path, url: str, protocols: str,
                 origin: str | None = None) -> None:
        env = {**os.environ, "NODE_PATH": str(modules)}
        self.proc = subprocess.Popen(["node", str(CLIENT), url, protocols,
                                      *([origin] if origin else [])],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True, env=env)
        assert self.proc.stdout is not None
        self._out = _Lines(self.proc.stdout, "node-client-stdout")
        self.events: list[dict[str, Any]] = []
        self._unread: list[dict[str, Any]] = []

    def send(self, op: str, **fields: Any) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(json.dumps({"op": op, **fields}) + "\n")
        self.proc.stdin.flush()

    def wait(self, event: str, where: Callable[[dict[str, Any]], bool] = lambda e: True,
             timeout: float = 20.0) -> dict[str, Any]:
        """The first event of that kind (and ``where``) not yet taken, waiting for it."""
        for i, e in enumerate(self._unread):
            if e["event"] == event and where(e):
                return self._unread.pop(i)
        deadline = time.monotonic() + timeout
        while True:
            line = self._out.next(deadline)
            if line is None:
                raise AssertionError(f"no {event!r} event from the Node client; it said:\n"
                                     + "\n".join(self._out.seen[-30:]))
            try:
                e = json.loads(line)
            except json.JSONDecodeError:
                continue  # Node's own words (a warning): kept in seen
            self.events.append(e)
            if e["event"] == event and where(e):
                return e
            self._unread.append(e)

    def connected(self) -> dict[str, Any]:
        """Waits for the connection and the server's info, services and channels."""
        opened = self.wait("open")
        self.server_info = self.wait("serverInfo")
        self.wait("advertise")
        return opened

    def statuses(self) -> list[str]:
        """Every status message seen so far (the unread ones too)."""
        self._drain()
        return [e["message"] for e in self.events if e["event"] == "status"]

    def _drain(self) -> None:
        while True:
            try:
                line = self._out.lines.get_nowait()
            except queue.Empty:
                return
            if line is None:
                self._out.lines.put(None)
                return
            self._out.seen.append(line)
            try:
                e = json.loads(line)
            except json.JSONDecodeError:
                continue
            self.events.append(e)
            self._unread.append(e)

    def forget(self, event: str, drain: bool = True) -> None:
        """Drop the unread events of that kind (with ``drain``, also those read so far but
        not yet looked at): what comes next is newer."""
        if drain:
            self._drain()
        self._unread = [e for e in self._unread if e["event"] != event]

    def vanish(self) -> None:
        """kill -9: the client is gone without a word (a closed laptop, a dead battery)."""
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(10)

    def close(self) -> None:
        if self.proc.poll() is None:
            try:
                self.send("close")
                self.proc.wait(5)
            except (OSError, subprocess.TimeoutExpired):
                self.proc.kill()
                self.proc.wait(10)
        if self.proc.stdin is not None:
            self.proc.stdin.close()
        self._out.join()
        assert self.proc.stdout is not None
        self.proc.stdout.close()


class Omnican:
    """``python -m omnican ARGS``, its stdout and stderr one stream, read as it comes."""

    def __init__(self, *args: str) -> None:
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        self.proc = subprocess.Popen([sys.executable, "-m", "omnican", *args],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True, env=env)
        assert self.proc.stdout is not None
        self._out = _Lines(self.proc.stdout, "omnican-output")
        self._done: tuple[int, str] | None = None

    def wait_line(self, text: str, timeout: float = 30.0) -> str:
        """The first line of its output with ``text`` in it."""
        deadline = time.monotonic() + timeout
        for line in self._out.seen:
            if text in line:
                return line
        while (line := self._out.next(deadline)) is not None:
            if text in line:
                return line
        raise AssertionError(f"{text!r} not in omnican's output:\n" + "\n".join(self._out.seen))

    def url(self) -> str:
        line = self.wait_line("Foxglove: open a connection to ")
        return line.split("open a connection to ", 1)[1].split()[0]

    def finish(self, timeout: float = 30.0, interrupt: bool = False) -> tuple[int, str]:
        """Waits for the end (after a Ctrl-C with ``interrupt``): (status, output)."""
        if self._done is not None:
            return self._done
        if interrupt and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
        try:
            self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(10)
        while self._out.next(time.monotonic() + 5.0) is not None:
            pass
        self._out.join()
        for pipe in (self.proc.stdin, self.proc.stdout):
            if pipe is not None:
                pipe.close()
        self._done = (self.proc.returncode, "\n".join(self._out.seen))
        return self._done

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.finish(10.0)


def json_line(output: str) -> dict[str, Any]:
    """The JSON object ``omnican drive --json`` printed (its stderr lines around it)."""
    for line in output.splitlines():
        if line.startswith("{"):
            result: dict[str, Any] = json.loads(line)
            return result
    raise AssertionError(f"no JSON in:\n{output}")


def listening_ports(pid: int) -> set[int]:
    """The TCP ports process ``pid`` listens on at 127.0.0.1 (Linux /proc; empty
    elsewhere): the relay's and the SDK server's own, behind it."""
    inodes = set()
    try:
        for fd in Path(f"/proc/{pid}/fd").iterdir():
            with contextlib.suppress(OSError):
                target = os.readlink(fd)
                if target.startswith("socket:["):
                    inodes.add(target[8:-1])
        lines = Path("/proc/net/tcp").read_text().splitlines()[1:]
    except OSError:
        return set()
    ports = set()
    for line in lines:
        fields = line.split()
        local, state, inode = fields[1], fields[3], fields[9]
        if state == "0A" and inode in inodes and local.startswith("0100007F:"):
            ports.add(int(local.split(":")[1], 16))
    return ports
