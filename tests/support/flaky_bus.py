"""A python-can virtual bus that can be made to fail, to test a bus going down:
sends that fail (with a chosen errno), receives that fail, and a slow reopening."""

from __future__ import annotations

import errno
import threading
import time
from typing import Any, ClassVar

import can
from can.interfaces.virtual import VirtualBus


class FlakyBus(VirtualBus):
    failing: ClassVar[bool] = False
    failing_errno: ClassVar[int] = errno.ENETDOWN
    rx_failing: ClassVar[bool] = False
    open_delay_s: ClassVar[float] = 0.0
    opened: ClassVar[int] = 0
    opening: ClassVar[threading.Event] = threading.Event()  # set while a reopen waits

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        if type(self).opened and type(self).open_delay_s:
            type(self).opening.set()
            time.sleep(type(self).open_delay_s)
            type(self).opening.clear()
        super().__init__(*args, **kwargs)
        type(self).opened += 1

    @classmethod
    def reset(cls) -> None:
        cls.failing, cls.failing_errno, cls.rx_failing = False, errno.ENETDOWN, False
        cls.open_delay_s, cls.opened = 0.0, 0
        cls.opening.clear()

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if type(self).failing:
            code = type(self).failing_errno
            raise can.CanOperationError(f"Failed to transmit: {errno.errorcode[code]}", code)
        super().send(msg, timeout)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if type(self).rx_failing:
            time.sleep(0.01)
            raise can.CanOperationError("Failed to receive: Network is down", errno.ENETDOWN)
        return super()._recv_internal(timeout)


def register() -> str:
    """Make ``interface="omnican_test_flaky"`` known to python-can (as a plugin would)."""
    name = "omnican_test_flaky"
    can.interfaces.BACKENDS[name] = ("tests.support.flaky_bus", "FlakyBus")
    valid = frozenset({*can.interfaces.VALID_INTERFACES, name})
    can.interfaces.VALID_INTERFACES = valid
    can.util.VALID_INTERFACES = valid  # type: ignore[attr-defined]
    return name
