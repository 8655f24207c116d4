"""Who sends SYNC off SocketCAN (issue 41): the loop, as before, with the SYNC counter
(1019h) when ``[bus] sync_counter`` asks for one; the [bus] keys that choose it are
omnican's, never python-can's; a bad value is one line and exit 2."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import can
import pytest

from omnican import Chassis
from omnican.chassis.runner import SyncRunner, ThreadRunner
from omnican.config import load_config
from omnican.errors import ConfigError
from omnican.io.bus import CanBus
from omnican.protocol.cia301 import SYNC_COB_ID
from omnican.sim import SimulatedBase
from tests.support.helpers import sim_config, wait_for


def test_the_loop_sends_the_counter_1_to_n_on_a_virtual_bus(channel: str) -> None:
    with CanBus({"interface": "virtual", "channel": channel, "sync": "auto",
                 "sync_counter": 3}) as bus, \
            can.Bus(interface="virtual", channel=channel) as peer:
        assert bus.sync_mode == "loop"
        assert "sync" not in bus.bus_kwargs and "sync_counter" not in bus.bus_kwargs
        for _ in range(7):
            assert bus.sync()
        got = []
        while (msg := peer.recv(1.0)) is not None and len(got) < 7:
            if msg.arbitration_id == SYNC_COB_ID:
                got.append(bytes(msg.data))
        assert got == [b"\x01", b"\x02", b"\x03", b"\x01", b"\x02", b"\x03", b"\x01"]
        assert bus.sync_epoch == bus.settled_epoch == 7


def test_without_a_counter_sync_is_empty_and_kernel_falls_back_to_the_loop(
        channel: str) -> None:
    with CanBus({"interface": "virtual", "channel": channel, "sync": "kernel"}) as bus, \
            can.Bus(interface="virtual", channel=channel) as peer:
        assert bus.sync_mode == "loop"  # no broadcast manager off SocketCAN
        assert not bus.start_kernel_sync(0.01)
        assert bus.sync()
        msg = peer.recv(1.0)
        assert msg is not None and msg.arbitration_id == SYNC_COB_ID and msg.dlc == 0


def test_a_base_on_a_virtual_bus_keeps_its_own_timer(channel: str) -> None:
    cfg = sim_config(channel)
    cfg = replace(cfg, bus={**(cfg.bus or {}), "sync": "auto"})
    with SimulatedBase.from_config(cfg), Chassis.open(cfg) as base:
        runner = base._runner
        assert type(runner) is ThreadRunner and not isinstance(runner, SyncRunner)
        assert wait_for(lambda: base.status.cycles > 5, 30.0)
        assert base.bus.kernel_sync is None


GOOD = """[bus]
interface = "virtual"
channel = "x"
{extra}
[chassis]
layout = "b21"
base_radius = 0.19

[[wheel]]
node_id = 1
velocity_scale = 1000.0
position_scale = 1000.0

[[wheel]]
node_id = 2
velocity_scale = 1000.0
position_scale = 1000.0

[[wheel]]
node_id = 3
velocity_scale = 1000.0
position_scale = 1000.0
"""


@pytest.mark.parametrize(("line", "words"), [
    ('sync = "bcm"', "bus.sync: must be one of 'auto', 'kernel', 'loop', got"),
    ("sync = 1", "bus.sync: must be one of"),
    ("sync_counter = 1", "bus.sync_counter: must be 0 (no counter) or 2-240, got 1"),
    ("sync_counter = 241", "bus.sync_counter: "),
    ('sync_counter = "4"', "bus.sync_counter: must be an integer, 0 or 2-240"),
    ("sync_counter = true", "bus.sync_counter: must be an integer"),
])
def test_a_bad_sync_setting_is_one_line_and_exit_2(tmp_path: Path, line: str,
                                                    words: str) -> None:
    path = tmp_path / "robot.toml"
    path.write_text(GOOD.format(extra=line + "\n"))
    with pytest.raises(ConfigError, match=r"bus\.sync"):
        load_config(path)
    proc = subprocess.run([sys.executable, "-m", "omnican", "check-config", str(path)],
                          capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 2 and proc.stdout == ""
    [out] = proc.stderr.strip().splitlines()
    assert out.startswith(f"omnican: error: {path}: {words}"), out


def test_good_sync_settings_load(tmp_path: Path) -> None:
    path = tmp_path / "robot.toml"
    path.write_text(GOOD.format(extra='sync = "loop"\nsync_counter = 240\n'))
    assert load_config(path).bus == {"interface": "virtual", "channel": "x", "sync": "loop",
                                     "sync_counter": 240}


def _frame(can_id: int, data: bytes = b"") -> can.Message:
    return can.Message(arbitration_id=can_id, data=data, is_extended_id=False)


def test_the_kernel_timed_wait_hands_on_frames_up_to_the_newest_sync(channel: str) -> None:
    """What the loop woken by the kernel's SYNC reads: after falling two SYNCs behind, it
    is handed everything up to the newest SYNC (the settled SYNC's answers complete, none
    of the newest's), and the frames after it on the next wait."""
    seen: list[int] = []
    with CanBus({"interface": "virtual", "channel": channel}) as bus, \
            can.Bus(interface="virtual", channel=channel) as peer:
        bus.start_polling()
        bus.network.subscribe(SYNC_COB_ID, bus._on_sync)  # what start_kernel_sync does
        bus.add_listener(_Ids(seen))
        for msg in (_frame(0x181, b"\x01"), _frame(SYNC_COB_ID), _frame(0x181, b"\x02"),
                    _frame(SYNC_COB_ID), _frame(0x181, b"\x03"), _frame(0x701, b"\x05")):
            peer.send(msg)
        assert bus.wait_sync(10.0)  # the frames are queued already (virtual bus)
        assert seen == [0x181, SYNC_COB_ID, 0x181, SYNC_COB_ID]
        assert (bus.sync_epoch, bus.settled_epoch) == (2, 1)
        peer.send(_frame(SYNC_COB_ID))
        assert bus.wait_sync(10.0)  # the frames are queued already (virtual bus)
        assert seen[4:] == [0x181, 0x701, SYNC_COB_ID]
        assert (bus.sync_epoch, bus.settled_epoch) == (3, 2)
        assert not bus.wait_sync(0.05)  # no SYNC: nothing, and it says so


class _Ids(can.Listener):
    def __init__(self, out: list[int]) -> None:
        self.out = out

    def on_message_received(self, msg: can.Message) -> None:
        self.out.append(msg.arbitration_id)
