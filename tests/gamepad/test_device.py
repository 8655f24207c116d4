"""Gamepad teleop against the simulated base: evdev InputEvents go through a device with
evdev's reading interface into omnican.gamepad.device, the path a real pad takes (there is no
/dev/uinput to make a real one). Includes unplugging the pad mid-drive."""

from __future__ import annotations

import errno
import os
import time
import weakref
from collections import deque
from collections.abc import Iterator
from typing import Any, NamedTuple

import pytest

from omnican import Chassis, default_config
from omnican.command.teleop import TeleopModel
from omnican.gamepad.device import Gamepad, drive_step, pad_command, teleop_model_for
from omnican.sim import SimulatedBase
from tests.support.helpers import wait_for

evdev = pytest.importorskip("evdev", reason="evdev not installed "
                            "(pip install 'omnican[gamepad]')")
e = evdev.ecodes


class AbsInfo(NamedTuple):  # the fields of evdev.AbsInfo that matter here
    value: int
    min: int
    max: int
    fuzz: int = 16
    flat: int = 128
    resolution: int = 0


class FakePad:
    """An Xbox pad as xpad presents it, with evdev.InputDevice's reading interface: a real
    file descriptor that select() waits on, read() yielding evdev.InputEvent objects,
    OSError(ENODEV) once unplugged."""

    name = "Microsoft X-Box 360 pad"
    path = "/dev/input/event-fake"

    def __init__(self) -> None:
        self._r, self._w = os.pipe()
        os.set_blocking(self._r, False)
        self.fd = self._r
        self._events: deque[Any] = deque()
        self.unplugged = False
        self.closed = False

    def capabilities(self, absinfo: bool = True) -> dict[int, list[Any]]:
        sticks = [(code, AbsInfo(0, -32768, 32767)) for code in
                  (e.ABS_X, e.ABS_Y, e.ABS_RX, e.ABS_RY)]
        return {e.EV_KEY: [e.BTN_SOUTH, e.BTN_TL, e.BTN_TR], e.EV_ABS: sticks}

    def send(self, *events: tuple[int, int, int]) -> None:
        now = time.time()
        sec, usec = int(now), int((now % 1) * 1e6)
        for type_, code, value in (*events, (e.EV_SYN, e.SYN_REPORT, 0)):
            self._events.append(evdev.InputEvent(sec, usec, type_, code, value))
        os.write(self._w, b"!")

    def unplug(self) -> None:
        self.unplugged = True
        os.write(self._w, b"!")  # the kernel wakes the reader, whose read then fails

    def read(self) -> Iterator[Any]:
        if self.unplugged:
            raise OSError(errno.ENODEV, os.strerror(errno.ENODEV))
        try:
            os.read(self._r, 4096)
        except BlockingIOError:
            pass
        if not self._events:
            raise BlockingIOError(errno.EAGAIN, "no events")
        while self._events:
            yield self._events.popleft()

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            os.close(self._r)
            os.close(self._w)


def drive(base: Chassis, pad: Gamepad, seconds: float) -> None:
    model = model_of(base, pad)
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        drive_step(base, pad, model, 0.02)


models: weakref.WeakKeyDictionary[Gamepad, TeleopModel] = weakref.WeakKeyDictionary()


def model_of(base: Chassis, pad: Gamepad) -> TeleopModel:
    """The teleop model of a pad: one per pad, kept across steps, as the command keeps one."""
    if pad not in models:
        models[pad] = teleop_model_for(base.cfg, pad.mapping)
    return models[pad]


def step(base: Chassis, pad: Gamepad) -> Any:
    return drive_step(base, pad, model_of(base, pad), 0.02)


@pytest.fixture
def rig(channel: str) -> Iterator[tuple[SimulatedBase, Chassis, FakePad, Gamepad]]:
    cfg = default_config(bus={"interface": "virtual", "channel": channel})
    device = FakePad()
    with SimulatedBase.from_config(cfg) as sim, Chassis.open(cfg) as base, \
            Gamepad(device) as pad:
        sim.reset_truth()
        base.reset_pose()
        yield sim, base, device, pad
    device.close()


def test_deadman_held_drives_released_stops(rig: Any) -> None:
    sim, base, device, pad = rig
    assert pad.mapping.name == "xbox"
    device.send((e.EV_ABS, e.ABS_Y, -32768))  # stick fully forward, deadman not held
    drive(base, pad, 0.3)
    assert sim.true_pose.distance_to(type(sim.true_pose)()) < 0.001
    device.send((e.EV_KEY, e.BTN_TL, 1))  # hold LB
    drive(base, pad, 1.0)
    assert base.twist.vx == pytest.approx(0.3, abs=0.03)
    assert abs(base.twist.vy) < 0.02
    device.send((e.EV_KEY, e.BTN_TL, 0))  # let go, stick still forward
    assert step(base, pad).is_zero()
    assert wait_for(lambda: abs(sim.true_twist.vx) < 0.005, timeout=1.0)
    x = sim.true_pose.x
    drive(base, pad, 0.3)
    assert sim.true_pose.x == pytest.approx(x, abs=0.002)  # stays stopped
    assert base.pose.x == pytest.approx(sim.true_pose.x, abs=0.005)


def test_strafe_turn_and_turbo(rig: Any) -> None:
    _, base, device, pad = rig
    device.send((e.EV_KEY, e.BTN_TL, 1), (e.EV_ABS, e.ABS_X, -32768))  # stick left
    drive(base, pad, 1.0)
    assert base.twist.vy == pytest.approx(0.3, abs=0.03)  # holonomic: straight left
    device.send((e.EV_ABS, e.ABS_X, 0), (e.EV_ABS, e.ABS_RX, -32768))  # right stick left
    drive(base, pad, 1.0)
    assert base.twist.wz == pytest.approx(1.0, abs=0.1)  # counter-clockwise
    device.send((e.EV_ABS, e.ABS_RX, 0), (e.EV_ABS, e.ABS_Y, -32768),
                (e.EV_KEY, e.BTN_TR, 1))  # forward with turbo
    drive(base, pad, 1.5)
    assert base.twist.vx == pytest.approx(0.8, abs=0.05)


def test_unplugged_mid_drive_stops_at_once(rig: Any) -> None:
    sim, base, device, pad = rig
    device.send((e.EV_KEY, e.BTN_TL, 1), (e.EV_ABS, e.ABS_Y, -32768))
    drive(base, pad, 1.0)
    assert sim.true_twist.vx > 0.25
    device.unplug()
    assert step(base, pad).is_zero()  # the first read after the unplug
    assert not pad.connected
    assert "UNPLUGGED" in pad.status_text()
    assert wait_for(lambda: abs(sim.true_twist.vx) < 0.005, timeout=1.0)
    assert base.status.stopped_reason is None  # a stop, not a fault: a pad can come back


def test_a_replugged_pad_needs_the_deadman_again(channel: str) -> None:
    cfg = default_config(bus={"interface": "virtual", "channel": channel})
    first, second = FakePad(), FakePad()
    with SimulatedBase.from_config(cfg) as sim, Chassis.open(cfg) as base, \
            Gamepad(first, opener=lambda: second) as pad:
        first.send((e.EV_KEY, e.BTN_TL, 1), (e.EV_ABS, e.ABS_Y, -32768))
        drive(base, pad, 0.5)
        first.unplug()
        drive(base, pad, 1.5)  # stopped; reopened after REOPEN_EVERY_S
        assert pad.connected and pad.device is second
        assert abs(sim.true_twist.vx) < 0.005
        second.send((e.EV_ABS, e.ABS_Y, -32768))  # stick forward, deadman not yet held
        drive(base, pad, 0.3)
        assert abs(sim.true_twist.vx) < 0.005
        second.send((e.EV_KEY, e.BTN_TL, 1))
        drive(base, pad, 0.8)
        assert base.twist.vx == pytest.approx(0.3, abs=0.03)
    first.close()
    second.close()


def test_teleop_command_drives_with_the_gamepad(monkeypatch: pytest.MonkeyPatch,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    """``omnican teleop --sim --gamepad``, in this process: the pad's events reach the base
    through the command's own loop; Esc on the terminal quits with the pose."""
    import re
    import sys
    import threading

    from omnican.cli import main
    from omnican.cli import teleop as teleop_cli

    device = FakePad()
    driving = threading.Event()  # the command's loop runs (the drives are up)

    def first_step(pad: Gamepad, model: TeleopModel, timeout: float) -> Any:
        driving.set()
        return pad_command(pad, model, timeout)

    monkeypatch.setattr(teleop_cli, "pad_command", first_step)
    monkeypatch.setattr(Gamepad, "open", classmethod(
        lambda cls, path=None, table=None: Gamepad(device, table)))
    master, slave = os.openpty()
    terminal = os.fdopen(slave, "r")
    monkeypatch.setattr(sys, "stdin", terminal)
    done = threading.Event()

    def operator() -> None:
        if not driving.wait(60.0):
            return
        device.send((e.EV_KEY, e.BTN_TL, 1), (e.EV_ABS, e.ABS_Y, -32768))  # hold LB, forward
        done.wait(1.5)
        device.send((e.EV_KEY, e.BTN_TL, 0))  # let go
        done.wait(1.0)
        os.write(master, b"\x1b")  # Esc

    thread = threading.Thread(target=operator, name="test-operator")
    thread.start()
    try:
        assert main(["teleop", "--sim", "--gamepad"]) == 0
    finally:
        done.set()
        thread.join()
        terminal.close()
        os.close(master)
        device.close()
    out = capsys.readouterr().out
    assert "gamepad Microsoft X-Box 360 pad" in " ".join(out.split())
    match = re.search(r"pose x=(\S+) y=(\S+) theta=(\S+)\s*$", out)
    assert match is not None, out[-500:]
    assert float(match[1]) > 0.2  # ~1.5 s at 0.3 m/s, less the ramps
    assert abs(float(match[2])) < 0.01 and abs(float(match[3])) < 0.01
