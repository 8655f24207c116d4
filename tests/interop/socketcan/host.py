"""A host program on the Chassis API, steered by the SocketCAN tests through stdin.

``python host.py ROBOT.toml`` opens the base (bus from the config) and prints one JSON
line: ``{"ready": true, ...}`` (or ``{"ready": false, "error": ...}`` and exit 1). Then
it reads one command a line and answers each with one JSON line:

    drive VX VY WZ   command this body velocity every 20 ms from now on
    hold             stop commanding (the process stays alive: the watchdog's case)
    status           pose, twist, command, status, wheels, frames dropped by the bus
    recover          base.recover(); {"ok": true} or {"ok": false, "error": ...}
    watch            start collecting what the status says, every 20 ms
    seen             what the status said since ``watch`` (and start over)
    close            close the base (stop, disable, release the bus); the process stays
    quit             leave the ``with`` block: stop, disable every drive, exit 0
"""

from __future__ import annotations

import enum
import json
import sys
import threading
from dataclasses import asdict
from typing import Any

from omnican import Chassis, load_config
from omnican.errors import OmnicanError

PERIOD_S = 0.02


def plain(value: Any) -> Any:
    """JSON-ready: enums by name, tuples as lists, dataclass fields as they are."""
    if isinstance(value, enum.Enum):
        return str(value)
    if isinstance(value, dict):
        return {k: plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    return value


def snapshot(base: Chassis) -> dict[str, Any]:
    return {
        "pose": asdict(base.pose),
        "twist": asdict(base.twist),
        "command": asdict(base.command),
        "status": plain(asdict(base.status)),
        "wheels": [plain(asdict(w)) for w in base.wheels],
        "dropped_frames": getattr(base.bus, "dropped_frames", None),
        "send_errors": base.bus.send_errors,
        # For diagnosis when a test fails: which SYNC each wheel's last sample was
        # filed under, against the last SYNC sent (private; read-only).
        "sync_epoch": base.bus.sync_epoch,
        "sample_epochs": [a.epoch for a in base._loop.axes],
        # Who sends SYNC, and whether the loop runs woken by the kernel's (private).
        "sync_mode": base.bus.sync_mode,
        "kernel_sync": getattr(base._runner, "kernel", False),
        "sync_hold": base.bus.kernel_sync.hold if base.bus.kernel_sync else None,
    }


class Commander:
    """Commands the velocity every 20 ms (as a teleop would) and watches the status."""

    def __init__(self, base: Chassis) -> None:
        self.base = base
        self.velocity: tuple[float, float, float] | None = None
        self._lock = threading.Lock()
        self._seen: dict[str, Any] = {}
        self._watching = False
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="host-commander", daemon=True)
        self._thread.start()

    def watch(self) -> None:
        with self._lock:
            self._seen = {"bus_errors": [], "stopped_reasons": [], "bus_up": [],
                          "first_cycles": None, "last_cycles": None, "samples": 0}
            self._watching = True

    def seen(self) -> dict[str, Any]:
        with self._lock:
            out = self._seen
        self.watch()
        return out

    def _sample(self) -> None:
        st = self.base.status
        with self._lock:
            if not self._watching:
                return
            seen = self._seen
            for key, value in (("bus_errors", st.bus_error),
                               ("stopped_reasons", st.stopped_reason),
                               ("bus_up", getattr(st, "bus_up", None))):
                if value not in seen[key]:
                    seen[key].append(value)
            if seen["first_cycles"] is None:
                seen["first_cycles"] = st.cycles
            seen["last_cycles"] = st.cycles
            seen["samples"] += 1

    def _run(self) -> None:
        while not self._stop.wait(PERIOD_S):
            velocity = self.velocity
            if velocity is not None:
                try:
                    self.base.set_velocity(*velocity)
                except OmnicanError:
                    return  # closed
            self._sample()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)


def reply(obj: dict[str, Any]) -> None:
    print(json.dumps(obj, default=str), flush=True)


def serve(base: Chassis) -> None:
    commander = Commander(base)
    try:
        for line in sys.stdin:
            words = line.split()
            if not words:
                continue
            verb = words[0]
            if verb == "quit":
                break
            if verb == "drive":
                vx, vy, wz = (float(w) for w in words[1:4])
                commander.velocity = (vx, vy, wz)
                reply({"ok": True})
            elif verb == "hold":
                commander.velocity = None
                reply({"ok": True})
            elif verb == "status":
                reply(snapshot(base))
            elif verb == "recover":
                try:
                    base.recover()
                    reply({"ok": True})
                except OmnicanError as exc:
                    reply({"ok": False, "error": str(exc)})
            elif verb == "watch":
                commander.watch()
                reply({"ok": True})
            elif verb == "seen":
                reply(commander.seen())
            elif verb == "close":
                commander.velocity = None
                base.close()
                reply({"ok": True})
            else:
                reply({"ok": False, "error": f"unknown command {verb!r}"})
    finally:
        commander.close()


def main() -> int:
    cfg = load_config(sys.argv[1])
    try:
        base = Chassis.open(cfg)
    except OmnicanError as exc:
        reply({"ready": False, "error": str(exc)})
        return 1
    with base:
        reply({"ready": True, "warnings": list(base.warnings)})
        serve(base)
    return 0


if __name__ == "__main__":
    sys.exit(main())
