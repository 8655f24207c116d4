"""What a base offers the layers above it, and how they attach: the chassis knows
nothing of them.

The control cycle hands every n-th snapshot to one :class:`SnapshotSink` (the telemetry
feed, :func:`omnican.telemetry.attach.feed_of`, fans it out to every front end); what a
layer above attaches to a base (that feed, a recording) is an :class:`Attachment`, kept
in the base's :class:`Attachments` and closed with it; a :class:`Recording` (made by
:class:`omnican.record.recording.FileRecording`) is given to ``Chassis.open`` and records
the bus from its first frame on.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any, Protocol, TypeVar

from omnican.chassis.state import Snapshot
from omnican.config import ChassisConfig
from omnican.io.bus import Recorder

logger = logging.getLogger("omnican.chassis")


class SnapshotSink(Protocol):
    """What the control cycle hands a snapshot to, on the loop thread: queue it and
    return (the cycle runs at up to 1 kHz)."""

    def offer(self, snapshot: Snapshot) -> None: ...


class Attachment(Protocol):
    """What a layer above attached to a base: closed with it, once the drives are
    stopped and before the bus closes, with the base's last snapshot."""

    def close(self, last: Snapshot | None = None) -> None: ...


#: The base a recording attaches to (:class:`omnican.chassis.base.Chassis`).
B_contra = TypeVar("B_contra", contravariant=True)


class Recording(Attachment, Protocol[B_contra]):
    """A recording of a base from its bus's first frame on, given to ``Chassis.open``
    (``Recording[Chassis]``). The base opens it once the config passed its checks
    (nothing is written for a base that cannot be made), attaches it before the drives
    are configured and closes it with itself (``last`` None: the base could not be
    opened)."""

    def open(self, cfg: ChassisConfig) -> Recorder | None:
        """Open the file: what the bus hands every frame, received and sent (None: the
        recording takes them another way, through the telemetry)."""
        ...

    def attach(self, base: B_contra) -> None:
        """The base is made and its bus open; its drives are not configured yet."""
        ...


A = TypeVar("A", bound=Attachment)


class Attachments:
    """What layers above attached to one base, by name; closed with the base, the last
    attached first (what a recording attached for itself, the telemetry it records,
    closes before the recording). Any thread."""

    def __init__(self) -> None:
        self._attached: dict[str, Any] = {}
        self._lock = threading.Lock()
        self._closed = False

    def get(self, name: str) -> Any:
        """The attachment called ``name``, or None."""
        return self._attached.get(name)

    def setdefault(self, name: str, make: Callable[[], A]) -> A:
        """The attachment called ``name``; made by ``make`` (under the lock: once) if
        there is none. Raises RuntimeError once the base is closed."""
        with self._lock:
            if self._closed:
                raise RuntimeError("the base is closed")
            found = self._attached.get(name)
            if found is None:
                found = self._attached[name] = make()
            return found  # what make() made, by name

    def add(self, name: str, attachment: Attachment) -> None:
        """Attach ``attachment`` as ``name`` (a name is taken once)."""
        with self._lock:
            if self._closed:
                raise RuntimeError("the base is closed")
            if name in self._attached:
                raise ValueError(f"{name!r} is attached to the base already")
            self._attached[name] = attachment

    def close(self, last: Snapshot | None) -> None:
        """Close every attachment, the last attached first. Idempotent."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            attached = list(self._attached.values())
        for attachment in reversed(attached):
            try:
                attachment.close(last)
            except Exception:  # one that fails must not keep the others (or the bus) open
                logger.exception("closing %s failed", type(attachment).__name__)
