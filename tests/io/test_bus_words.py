"""The words for a bus that does not open, does not send or does not receive: what a
user can act on (the kernel module, the interface to make, the hub that went away),
never the interface's own words alone (issue 36, item 11)."""

from __future__ import annotations

import errno
import os

import can
import pytest
from hypothesis import given
from hypothesis import strategies as st

from omnican.io.bus_watch import (
    bus_where,
    describe_open_error,
    describe_receive_error,
    describe_send_error,
)

SOCKETCAN = {"interface": "socketcan", "channel": "vcan0"}
HUB = {"interface": "remote", "channel": "ws://127.0.0.1:54701/"}


def oserror(code: int) -> OSError:
    return OSError(code, os.strerror(code))


def test_no_socketcan_in_the_kernel_names_the_modules() -> None:
    text = describe_open_error(SOCKETCAN, oserror(errno.EAFNOSUPPORT))
    assert text == ("cannot open CAN bus (interface=socketcan, channel=vcan0): this kernel has "
                    "no SocketCAN (no CAN address family): load the kernel modules can and "
                    "can_raw (sudo modprobe can_raw), and vcan for a virtual interface like "
                    "vcan0 (sudo modprobe vcan)")
    on_can0 = describe_open_error({"interface": "socketcan", "channel": "can0"},
                                  oserror(errno.EAFNOSUPPORT))
    assert on_can0.endswith("(sudo modprobe can_raw)")  # no vcan for a real interface


def test_no_raw_sockets_names_can_raw() -> None:
    text = describe_open_error(SOCKETCAN, oserror(errno.EPROTONOSUPPORT))
    assert "no raw CAN sockets: load the kernel module can_raw (sudo modprobe can_raw)" in text


def test_a_missing_interface_says_how_to_make_it() -> None:
    text = describe_open_error(SOCKETCAN, oserror(errno.ENODEV))
    assert text.endswith("there is no network interface vcan0: create it: sudo modprobe vcan "
                         "&& sudo ip link add dev vcan0 type vcan && sudo ip link set vcan0 up")
    can0 = describe_open_error({"interface": "socketcan", "channel": "can0"},
                               oserror(errno.ENODEV))
    assert can0.endswith("there is no network interface can0: see 'ip link show' for the CAN "
                         "interfaces there are")


def test_python_can_s_own_error_is_read_through() -> None:
    """python-can raises CanOperationError carrying the errno (or raised from it)."""
    wrapped = can.CanOperationError("Error receiving: Network is down", errno.ENETDOWN)
    assert describe_receive_error(SOCKETCAN, wrapped) == ("receive failed: the CAN "
                                                          "interface is down")
    try:
        raise can.CanInitializationError("init failed") from oserror(errno.EAFNOSUPPORT)
    except can.CanInitializationError as exc:
        assert "no SocketCAN" in describe_open_error(SOCKETCAN, exc)


def test_the_hub_going_away() -> None:
    closed = ValueError("file descriptor cannot be a negative integer (-1)")
    assert describe_receive_error(HUB, closed) == (
        "the hub at ws://127.0.0.1:54701/ went away: did omnican sim stop?")
    assert describe_send_error(0x80, oserror(errno.EPIPE), HUB) == (
        "send 0x080 failed: the hub at ws://127.0.0.1:54701/ went away: did omnican sim stop?")
    assert describe_open_error(HUB, ConnectionRefusedError(errno.ECONNREFUSED, "refused")) == (
        "cannot open CAN bus (interface=remote, channel=ws://127.0.0.1:54701/): nothing "
        "answers at ws://127.0.0.1:54701/ (is omnican sim serving there?)")


def test_other_errors_keep_their_words() -> None:
    assert describe_open_error({}, RuntimeError("odd")) == (
        "cannot open CAN bus (python-can's configuration): odd")
    assert describe_receive_error(SOCKETCAN, RuntimeError("odd")) == "receive failed: odd"
    assert describe_send_error(0x181, oserror(errno.ENOBUFS)).startswith(
        "send 0x181 failed: transmit queue full")


@given(st.dictionaries(st.sampled_from(["interface", "channel", "bitrate"]),
                       st.sampled_from(["socketcan", "remote", "virtual", "vcan0", "can0",
                                        "ws://127.0.0.1:1/", 500000]), max_size=3),
       st.sampled_from([errno.EAFNOSUPPORT, errno.EPROTONOSUPPORT, errno.ENODEV, errno.EPIPE,
                        errno.ECONNREFUSED, errno.ENETDOWN, errno.EIO]),
       st.sampled_from(["", "x\ny"]))
def test_every_text_is_one_line_naming_the_bus(bus: dict[str, object], code: int,
                                              words: str) -> None:
    exc = OSError(code, words) if words else oserror(code)
    opened = describe_open_error(bus, exc)
    assert opened.startswith(f"cannot open CAN bus ({bus_where(bus)}): ")
    assert describe_send_error(0x80, exc, bus).startswith("send 0x080 failed: ")
    for text in (opened, describe_receive_error(bus, exc), describe_send_error(0x80, exc, bus)):
        assert "\n" not in text and text.strip() == text


@pytest.mark.parametrize("bus", [SOCKETCAN, HUB, {}])
def test_where_is_the_bus_arguments_in_order(bus: dict[str, object]) -> None:
    assert bus_where(bus) == (", ".join(f"{k}={v}" for k, v in bus.items())
                              or "python-can's configuration")
