"""A gamepad through Linux evdev (``pip install 'omnican[gamepad]'``), read without a
thread: :meth:`Gamepad.poll` waits for events on the device's file descriptor, feeds them
to the pure :class:`omnican.command.gamepad.PadState`, and notices an unplugged pad (the
kernel answers ``ENODEV``), which zeroes the command at once.

Any object with evdev's ``InputDevice`` reading interface works as the device (``name``,
``path``, ``fd``, ``read()``, ``capabilities(absinfo=True)``, ``close()``): tests feed
``evdev.InputEvent`` objects through one, down the same path as a real pad.

The pad drives through :class:`omnican.command.teleop.TeleopModel`, the model the keyboard
teleop uses (:func:`drive_step`): the same speed limits and speed keys, the same stop.
"""

from __future__ import annotations

import errno
import logging
import select
import time
from collections.abc import Mapping
from typing import Any

from omnican.command.gamepad import (
    ABS_CODES,
    EV_ABS,
    PadMapping,
    PadState,
    mapping_from_table,
)
from omnican.command.teleop import TeleopModel
from omnican.core.kinematics import Twist
from omnican.errors import ConfigError, GamepadError

logger = logging.getLogger(__name__)

REOPEN_EVERY_S = 1.0


def _evdev() -> Any:
    try:
        import evdev
    except ImportError:
        from omnican.extras import install_hint

        raise ConfigError(f"--gamepad needs evdev (Linux): {install_hint('gamepad')}") from None
    return evdev


def find_device(path: str | None = None) -> Any:
    """Open ``path``, or the first input device with sticks and a shoulder button."""
    evdev = _evdev()
    if path:
        try:
            return evdev.InputDevice(path)
        except OSError as exc:
            raise GamepadError(f"cannot open gamepad {path}: {exc.strerror or exc}") from None
    for candidate in evdev.list_devices():
        try:
            dev = evdev.InputDevice(candidate)
        except OSError:
            continue
        caps = dev.capabilities()
        axes = {a if isinstance(a, int) else a[0] for a in caps.get(EV_ABS, [])}
        if {ABS_CODES["ABS_X"], ABS_CODES["ABS_Y"]} <= axes and caps.get(1):
            return dev
        dev.close()
    raise GamepadError("no gamepad found under /dev/input (plug one in, check permissions: "
                       "the user needs read access, usually the 'input' group, or name "
                       "the device: --gamepad /dev/input/eventN)")


def axis_ranges(device: Any) -> tuple[dict[int, tuple[int, int]], dict[int, int]]:
    """(code -> (min, max), code -> current value) of the device's absolute axes."""
    ranges: dict[int, tuple[int, int]] = {}
    values: dict[int, int] = {}
    for code, info in device.capabilities(absinfo=True).get(EV_ABS, []):
        ranges[code] = (info.min, info.max)
        values[code] = info.value
    return ranges, values


class Gamepad:
    """One pad and what it commands. ``table``: the config's ``[gamepad]`` table.

    A context manager; closes the device."""

    def __init__(self, device: Any, table: Mapping[str, Any] | None = None,
                 opener: Any = None) -> None:
        self.table = dict(table or {})
        self.mapping: PadMapping = mapping_from_table(self.table, device.name)
        self._opener = opener  # reopens the same device after an unplug
        self._next_reopen = 0.0
        self.device: Any = None
        self.state = PadState(self.mapping, {})
        self._attach(device)

    @classmethod
    def open(cls, path: str | None = None, table: Mapping[str, Any] | None = None) -> Gamepad:
        device = find_device(path)
        where = device.path
        return cls(device, table, opener=lambda: find_device(where))

    def _attach(self, device: Any) -> None:
        self.device = device
        ranges, values = axis_ranges(device)
        self.state = PadState(self.mapping, ranges)
        for code, value in values.items():  # where the sticks rest now
            self.state.feed(EV_ABS, code, value)

    @property
    def name(self) -> str:
        return str(self.device.name) if self.device is not None else "?"

    @property
    def connected(self) -> bool:
        return self.state.connected

    def _lost(self, exc: OSError) -> None:
        if self.state.connected:
            logger.warning("gamepad %s lost (%s): stopping", self.name,
                           exc.strerror or errno.errorcode.get(exc.errno or 0, exc))
        self.state.unplugged()
        try:
            self.device.close()
        except OSError:
            pass
        self._next_reopen = time.monotonic() + REOPEN_EVERY_S

    def _reopen(self) -> None:
        if self._opener is None or time.monotonic() < self._next_reopen:
            return
        self._next_reopen = time.monotonic() + REOPEN_EVERY_S
        try:
            device = self._opener()
        except (GamepadError, OSError):
            return
        self._attach(device)
        logger.warning("gamepad %s is back: hold the deadman to drive", self.name)

    def poll(self, timeout: float) -> bool:
        """Wait up to ``timeout`` s for events and apply them; False if the pad is gone."""
        if not self.state.connected:
            self._reopen()
            if not self.state.connected:
                time.sleep(timeout)
                return False
        try:
            ready, _, _ = select.select([self.device.fd], [], [], timeout)
            if not ready:
                return True
            for event in self.device.read():
                self.state.feed(event.type, event.code, event.value)
        except BlockingIOError:  # woken without events
            return True
        except OSError as exc:  # ENODEV: unplugged; EBADF & co: as good as unplugged
            self._lost(exc)
            return False
        return True

    def command(self) -> Twist:
        return self.state.command()

    def status_text(self) -> str:
        if not self.state.connected:
            return f"gamepad {self.name} UNPLUGGED - base stopped"
        held = "HELD" if self.state.deadman else "released (hold to drive)"
        turbo = "  turbo" if self.state.turbo else ""
        return f"gamepad {self.name} ({self.mapping.name})  deadman {held}{turbo}"

    def close(self) -> None:
        if self.device is not None:
            try:
                self.device.close()
            except OSError:
                pass

    def __enter__(self) -> Gamepad:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def teleop_model_for(cfg: Any, mapping: PadMapping) -> TeleopModel:
    """The shared teleop model for a pad: its speeds are the pad's fastest (turbo) scales,
    within what ``cfg``'s base can reach; no input timeout (a pad held still sends no
    events, and its own deadman and unplug rules stop the base)."""
    linear = max(abs(a.scale) for a in (mapping.vx, mapping.vy)) or 1.0
    turbo = max(abs(a.turbo_scale) for a in (mapping.vx, mapping.vy))
    turn = max(abs(mapping.wz.scale), abs(mapping.wz.turbo_scale)) or 1.0
    return TeleopModel.for_config(cfg, max(linear, turbo), turn, 0.0)


def apply(pad: Gamepad, model: TeleopModel, now: float) -> None:
    """Hand the pad's state to the shared teleop model: move while the deadman is held
    (the pad's twist as fractions of the model's speeds, so the keyboard's speed keys
    scale it too), release it otherwise (let go, or unplugged)."""
    if not pad.state.deadman:
        model.release()
        return
    t = pad.command()
    d = (t.vx / model.speed, t.vy / model.speed, t.wz / model.turn)
    biggest = max(1.0, *(abs(v) for v in d))  # at the base's limits: keep the direction
    label = "pad turbo" if pad.state.turbo else "pad"
    model.move((d[0] / biggest, d[1] / biggest, d[2] / biggest), now, label)


def pad_command(pad: Gamepad, model: TeleopModel, timeout: float) -> Twist:
    """Read the pad for up to ``timeout`` s and pass it through the teleop model: the
    command it asks for (zero when the deadman is released or the pad is gone)."""
    pad.poll(timeout)
    now = time.monotonic()
    apply(pad, model, now)
    return model.command(now)


def drive_step(base: Any, pad: Gamepad, model: TeleopModel, timeout: float) -> Twist:
    """One step of gamepad teleop: :func:`pad_command`, sent to the base. Returns the
    command."""
    command = pad_command(pad, model, timeout)
    base.set_velocity(command.vx, command.vy, command.wz)
    return command


def config_table(path: str | None) -> dict[str, Any]:
    """The ``[gamepad]`` table of a config file (empty without one)."""
    if not path:
        return {}
    import sys

    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover
        import tomli as tomllib  # type: ignore[import-not-found,unused-ignore]
    try:
        with open(path, "rb") as f:
            data = tomllib.load(f)
    except (OSError, ValueError) as exc:  # load_config reported it already, normally
        raise ConfigError(f"cannot read config {path}: {exc}") from None
    table = data.get("gamepad", {})
    if not isinstance(table, dict):
        raise ConfigError(f"{path}: gamepad: must be a table")
    return table
