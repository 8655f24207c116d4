"""The CAN controller's state from SocketCAN error frames, on a real kernel CAN stack: a
host process on vcan0 (against ``omnican sim`` in another) hears the error frames that
``cansend`` puts on the interface, as a controller's driver would deliver them, and shows
them in its status; bus-off stops the base, recover() refuses until the controller says
it was restarted (what the interface's restart-ms does).

vcan has no controller of its own: it carries the error frames, it never goes bus-off;
what a real controller does with its error counters is the unit tests' (tests/
test_canstate.py)."""

from __future__ import annotations

import shutil
import subprocess
from typing import Any

import pytest

from tests.interop.socketcan.support import REPLY_S, HostProcess, SimProcess, wait_until

pytestmark = pytest.mark.socketcan

CHANNEL = "vcan0"
SOON_S = 30.0
# Error frames as cansend writes them: an 8-digit id with the error flag (0x20000000) and
# the error class; data[1] the controller's state, data[6] and data[7] its counters.
TX_WARNING = "20000204#0008000000006000"  # CRTL | CNT: tx warning, tx 96, rx 0
RX_PASSIVE = "20000204#0010000000006083"  # CRTL | CNT: rx passive, tx 96, rx 131
BUS_OFF = "20000040#0000000000000000"
RESTARTED = "20000100#0000000000000000"


def cansend(frame: str) -> None:
    if shutil.which("cansend") is None:
        pytest.skip("needs cansend (can-utils; tools/socketcan-tests installs it as root)")
    done = subprocess.run(["cansend", CHANNEL, frame], capture_output=True, text=True,
                          timeout=REPLY_S, check=False)
    assert done.returncode == 0, done.stderr


def status(host: HostProcess) -> dict[str, Any]:
    st: dict[str, Any] = host.status()["status"]
    return st


def test_error_frames_show_in_the_status_and_bus_off_is_a_stop(sim: SimProcess,
                                                              host: HostProcess) -> None:
    assert host.request("drive 0.15 0 0")["ok"]
    assert wait_until(sim.moving, SOON_S)
    cansend(TX_WARNING)
    assert wait_until(lambda: status(host)["can_state"] == "error-warning", SOON_S)
    st = status(host)
    assert (st["can_tx_errors"], st["can_rx_errors"]) == (96, 0)
    assert st["stopped_reason"] is None  # error-warning: the controller still talks
    cansend(RX_PASSIVE)
    assert wait_until(lambda: status(host)["can_state"] == "error-passive", SOON_S)
    assert status(host)["can_rx_errors"] == 131
    cansend(BUS_OFF)
    assert wait_until(lambda: "CAN bus-off" in (status(host)["stopped_reason"] or ""), SOON_S)
    assert wait_until(sim.still, SOON_S)
    refused = host.request("recover")
    assert not refused["ok"] and "the CAN controller is bus-off" in refused["error"]
    cansend(RESTARTED)
    assert wait_until(lambda: status(host)["can_state"] == "error-active", SOON_S)
    assert host.request("recover")["ok"]
    assert wait_until(sim.moving, SOON_S)  # the host still commands 0.15 m/s
    assert host.request("hold")["ok"]
    assert status(host)["can_error_frames"] == 4
