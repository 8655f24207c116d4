"""A python-can virtual bus whose sends can be made to fail, to test a bus going down."""

from __future__ import annotations

from typing import Any, ClassVar

import can
from can.interfaces.virtual import VirtualBus


class FlakyBus(VirtualBus):
    failing: ClassVar[bool] = False
    opened: ClassVar[int] = 0

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        type(self).opened += 1

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if type(self).failing:
            raise can.CanOperationError("Network is down [Error Code 100]")
        super().send(msg, timeout)


def register() -> str:
    """Make ``interface="omnican_test_flaky"`` known to python-can (as a plugin would)."""
    name = "omnican_test_flaky"
    can.interfaces.BACKENDS[name] = ("tests.flaky_bus", "FlakyBus")
    valid = frozenset({*can.interfaces.VALID_INTERFACES, name})
    can.interfaces.VALID_INTERFACES = valid
    can.util.VALID_INTERFACES = valid  # type: ignore[attr-defined]
    return name
